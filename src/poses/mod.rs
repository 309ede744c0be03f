//! poses.json, the result file other tools read (DESIGN.md "poses.json"): one
//! `matrix_world` per DSM (row-major 4x4, p_corrected = M p in the DSM's own CRS
//! coordinates), the edges with their ICP statistics and averaging residuals, the
//! graph mode and the gauge. Written atomically (temp file in the same folder, then
//! rename) with full f64 precision (shortest round-trip digits: reading back is bit
//! exact); read with validation (4x4 shape, last row 0 0 0 1, rigid rotation, unique
//! ids, edges naming known ids), every error naming the file and the pose.
//!
//! Layout: `"crs"`, `"poses"` (one per line), `"edges"` (one per line), `"graph"`
//! (`"full"` | `"mst"`), `"gauge"` (`"mean"` | `"anchor:<id>"`), then optional
//! `"components"` (lists of ids) and `"summary"`.

mod json;
mod list;
/// Rigid-transform helpers, now in [`crate::geo::rigid`].
pub use crate::geo::rigid;
pub use list::PoseList;

pub use rigid::{inverse_rigid, rotation_angle_deg, to_local, to_world};

use crate::averaging::AveragingResult;
use nalgebra::Matrix4;
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::PathBuf;

/// Largest |R^T R - I| entry accepted for a `matrix_world` read from a file.
pub const RIGIDITY_TOLERANCE: f64 = 1e-6;

impl PosesFile {
    /// The pose of a DSM by id.
    pub fn pose(&self, id: &str) -> Option<&Matrix4<f64>> {
        self.poses
            .iter()
            .find(|p| p.id == id)
            .map(|p| &p.matrix_world)
    }
}

/// The whole poses.json file.
#[derive(Clone, Debug, PartialEq)]
pub struct PosesFile {
    /// CRS label of the collection, e.g. "EPSG:32617".
    pub crs: String,
    pub poses: Vec<PoseEntry>,
    pub edges: Vec<EdgeEntry>,
    pub graph: GraphKind,
    pub gauge: GaugeLabel,
    /// Connected components of the graph used, as lists of pose ids.
    pub components: Option<Vec<Vec<String>>>,
    pub summary: Option<PosesSummary>,
}

/// One DSM's correction.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseEntry {
    /// The input file's stem.
    pub id: String,
    /// Maps the DSM's points (x, y, height in its CRS) to their corrected position.
    pub matrix_world: Matrix4<f64>,
    /// One-sigma standard errors of the correction from the solve (optional;
    /// absent when not computed or infinite).
    pub sigma: Option<crate::averaging::NodeSigma>,
    /// How well the graph fixes this pose: "weak" or "unconstrained" (optional;
    /// absent for a constrained pose).
    pub status: Option<crate::averaging::NodeStatus>,
}

/// One registered pair as reported in poses.json.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EdgeEntry {
    pub i: String,
    pub j: String,
    pub overlap: f64,
    #[serde(rename = "rmse")]
    pub rmse_m: f64,
    /// Weight of the rotation in the averaging (and of the translation with the
    /// paper's weights).
    pub weight: f64,
    /// Weight of the translation in the averaging (absent in older files).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation_weight: Option<f64>,
    pub iterations: u32,
    pub inliers: u64,
    /// Translation disagreement of the averaged poses with this edge, metres.
    pub residual_m: f64,
    /// Rotation disagreement of the averaged poses with this edge, degrees.
    pub residual_deg: f64,
    /// Rejected as an outlier by the robust averaging.
    pub dropped: bool,
    /// Kept at a lower weight by the robust averaging (an outlier that holds a
    /// component together); absent in older files.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub downweighted: bool,
    /// The pairwise ICP converged.
    pub converged: bool,
}

/// Which graph produced the poses: every edge, or the maximum-overlap spanning tree.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GraphKind {
    Full,
    Mst,
}

/// The gauge: `"mean"` or `"anchor:<id>"` (that pose is the identity).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum GaugeLabel {
    Mean,
    Anchor(String),
}

impl GaugeLabel {
    pub fn label(&self) -> String {
        match self {
            GaugeLabel::Mean => "mean".to_string(),
            GaugeLabel::Anchor(id) => format!("anchor:{id}"),
        }
    }

    pub fn parse(text: &str) -> Option<GaugeLabel> {
        match text {
            "mean" => Some(GaugeLabel::Mean),
            _ => text
                .strip_prefix("anchor:")
                .filter(|id| !id.is_empty())
                .map(|id| GaugeLabel::Anchor(id.to_string())),
        }
    }
}

/// Totals of an averaging run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PosesSummary {
    pub nodes: usize,
    pub edges: usize,
    pub edges_dropped: usize,
    pub edges_downweighted: usize,
    pub components: usize,
    pub median_residual_m: f64,
    pub max_residual_m: f64,
    pub median_residual_deg: f64,
    pub max_residual_deg: f64,
    pub rotation_iterations: usize,
    pub cg_iterations: usize,
    /// The edge weights used (absent in older files).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights: Option<crate::graph::Weighting>,
    /// A-posteriori variance of unit weight of the kept edges (information
    /// averaging with redundancy): above 1 the pairs disagree more than their
    /// sigmas say, and the poses' sigmas were scaled by its square root.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub variance_factor: Option<f64>,
    /// The weight factor (0.01-1) of the edges whose pair did not converge or is
    /// ambiguous, estimated from how far they are from the reliable ones.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unreliable_weight: Option<f64>,
}

impl PosesSummary {
    /// Totals of `result`; residual statistics over the edges that were not dropped.
    pub fn from_result(result: &AveragingResult) -> Self {
        let dropped: HashSet<usize> = result.dropped_edges.iter().copied().collect();
        let kept = || {
            result
                .edge_residuals
                .iter()
                .enumerate()
                .filter(|(k, _)| !dropped.contains(k))
                .map(|(_, r)| r)
        };
        let translation: Vec<f64> = kept().map(|r| r.translation_m).collect();
        let rotation: Vec<f64> = kept().map(|r| r.rotation_deg).collect();
        PosesSummary {
            nodes: result.poses.len(),
            edges: result.edge_residuals.len(),
            edges_dropped: result.dropped_edges.len(),
            edges_downweighted: result.downweighted_edges.len(),
            components: result.components.len(),
            median_residual_m: median(translation.clone()),
            max_residual_m: translation.iter().copied().fold(0.0, f64::max),
            median_residual_deg: median(rotation.clone()),
            max_residual_deg: rotation.iter().copied().fold(0.0, f64::max),
            rotation_iterations: result.rotation_iterations,
            cg_iterations: result.cg_iterations,
            weights: None,
            variance_factor: None,
            unreliable_weight: None,
        }
    }
}

/// Median (upper median for even counts); 0 for an empty list.
fn median(mut values: Vec<f64>) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f64::total_cmp).1
}

#[derive(Debug, thiserror::Error)]
pub enum PosesError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: not a valid poses file: {message}", path.display())]
    Parse { path: PathBuf, message: String },
    #[error("{}: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
}

impl PosesError {
    /// True when the file itself is wrong (not an I/O failure).
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, PosesError::Io { .. })
    }
}
