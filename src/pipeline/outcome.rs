//! What a worker sends for one pair: [`PairOutcome`], keyed by DSM indices.
//! Ids appear only where outcomes are journaled (crate::journal).

use nalgebra::{Matrix4, Matrix6, Vector3};
use serde::{Deserialize, Serialize};

use crate::fit::{Axis, FitInformation, FitSigma};
use crate::icp::{IcpStatus, SearchReach};

/// A candidate pair by DSM index (reference < moving).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PairTask {
    pub reference: usize,
    pub moving: usize,
}

/// What DSM-ICP returned for a pair (usable or not).
#[derive(Clone, Debug, PartialEq)]
pub struct IcpFit {
    pub status: IcpStatus,
    /// T_ref_moving in world coordinates: p_reference = T p_moving.
    pub t_ref_moving_world: Matrix4<f64>,
    /// RMSE of the final iteration, metres.
    pub rmse_m: f64,
    pub inliers: usize,
    pub iterations: usize,
    /// One-sigma standard errors of the last fit (local frame at the overlap);
    /// None for pairs journaled before they were reported.
    pub sigma: Option<FitSigma>,
    /// The final fit's covariance and degenerate axes; None for pairs journaled
    /// before it was reported, or when the ICP did not compute it.
    pub information: Option<Box<PairInformation>>,
    /// How far the global search looked; None for pairs journaled before it
    /// was reported, or registered without a search.
    pub search: Option<Box<SearchReach>>,
}

/// What a pair's fit knows, as journaled: the 6x6 covariance of (x, y, z [m],
/// roll, pitch, yaw [rad]) about the world axes, the translation taken at
/// `centroid_world`; zero along degenerate directions (nothing learned there).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PairInformation {
    /// Row-major covariance on the constrained subspace.
    pub covariance: [[f64; 6]; 6],
    /// Where the translation was measured (world coordinates, metres).
    pub centroid_world: [f64; 3],
    /// Axes along which the fit learned nothing (held at their initial value).
    #[serde(default)]
    pub degenerate: Vec<Axis>,
    /// The gridding floor the reported sigmas add (row-major, same units;
    /// see [`crate::icp::floor`]); absent in journals written before it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gridding: Option<[[f64; 6]; 6]>,
}

impl PairInformation {
    pub fn from_fit(info: &FitInformation) -> Self {
        PairInformation {
            covariance: rows(&info.covariance_6x6),
            centroid_world: [info.centroid.x, info.centroid.y, info.centroid.z],
            degenerate: info.degenerate.clone(),
            gridding: (info.gridding_6x6.amax() > 0.0).then(|| rows(&info.gridding_6x6)),
        }
    }

    pub fn covariance_6x6(&self) -> Matrix6<f64> {
        matrix(&self.covariance)
    }

    /// The covariance as reported: the fit's plus the gridding floor.
    pub fn reported_covariance_6x6(&self) -> Matrix6<f64> {
        let g = self.gridding.as_ref().map_or_else(Matrix6::zeros, matrix);
        self.covariance_6x6() + g
    }

    pub fn centroid(&self) -> Vector3<f64> {
        Vector3::from(self.centroid_world)
    }

    /// Finite numbers, a symmetric covariance with no negative variance.
    pub fn is_valid(&self) -> bool {
        let valid = |c: Matrix6<f64>| {
            c.iter().all(|v| v.is_finite())
                && (c - c.transpose()).amax() <= 1e-9 * c.amax().max(1e-300)
                && (0..6).all(|k| c[(k, k)] >= 0.0)
        };
        self.centroid_world.iter().all(|v| v.is_finite())
            && valid(self.covariance_6x6())
            && valid(self.reported_covariance_6x6())
    }
}

/// A 6x6 as journaled (row-major).
fn rows(m: &Matrix6<f64>) -> [[f64; 6]; 6] {
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

/// A journaled row-major 6x6.
fn matrix(rows: &[[f64; 6]; 6]) -> Matrix6<f64> {
    Matrix6::from_fn(|r, c| rows[r][c])
}

impl IcpFit {
    /// Converged, still improving at the last iteration, or one of several
    /// equally good fits: the graph can use it (only converged at full weight).
    pub fn usable(&self) -> bool {
        matches!(
            self.status,
            IcpStatus::Converged | IcpStatus::MaxIterations | IcpStatus::Ambiguous
        )
    }

    /// The graph may trust this fit at full weight: it converged (its degenerate
    /// directions, if any, carry no information already).
    pub fn reliable(&self) -> bool {
        self.status == IcpStatus::Converged
    }
}

/// Why a pair that should have given an edge did not.
#[derive(Clone, Debug, PartialEq)]
// An ended fit is kept whole for the journal and the report; failures are
// few, so their size does not matter.
#[allow(clippy::large_enum_variant)]
pub enum Failure {
    /// Reading or scoring failed, or ICP returned an error: the message.
    Error(String),
    /// ICP ran and ended diverged, degenerate or with too few inliers.
    Ended(IcpFit),
}

/// The outcome of one pair.
#[derive(Clone, Debug, PartialEq)]
pub enum PairOutcome {
    /// Registered with a usable fit: an edge of the graph.
    Registered {
        pair: PairTask,
        /// s_ij measured on the overviews.
        overlap: f64,
        fit: IcpFit,
    },
    /// Scored below `--min-overlap`: no edge, by design.
    BelowOverlap { pair: PairTask, overlap: f64 },
    /// Should have given an edge and did not.
    Failed {
        pair: PairTask,
        /// NaN when the scoring itself failed.
        overlap: f64,
        failure: Failure,
    },
}

impl PairOutcome {
    pub fn pair(&self) -> PairTask {
        match self {
            PairOutcome::Registered { pair, .. }
            | PairOutcome::BelowOverlap { pair, .. }
            | PairOutcome::Failed { pair, .. } => *pair,
        }
    }

    pub fn overlap(&self) -> f64 {
        match self {
            PairOutcome::Registered { overlap, .. }
            | PairOutcome::BelowOverlap { overlap, .. }
            | PairOutcome::Failed { overlap, .. } => *overlap,
        }
    }

    /// The fit ICP returned, usable or not; None when it did not run.
    pub fn fit(&self) -> Option<&IcpFit> {
        match self {
            PairOutcome::Registered { fit, .. } => Some(fit),
            PairOutcome::Failed {
                failure: Failure::Ended(fit),
                ..
            } => Some(fit),
            _ => None,
        }
    }

    /// The fit the graph can use, if any.
    pub fn edge_fit(&self) -> Option<&IcpFit> {
        match self {
            PairOutcome::Registered { fit, .. } => Some(fit),
            _ => None,
        }
    }

    /// Why the pair gave no edge; None for a registered pair.
    pub fn why_no_edge(&self) -> Option<String> {
        match self {
            PairOutcome::Registered { .. } => None,
            PairOutcome::BelowOverlap { overlap, .. } => Some(below_overlap_note(*overlap)),
            PairOutcome::Failed { failure, .. } => Some(match failure {
                Failure::Error(message) => message.clone(),
                Failure::Ended(fit) => format!("ICP ended {:?}", fit.status),
            }),
        }
    }
}

/// The note of a pair scored below `--min-overlap` (as journaled).
pub fn below_overlap_note(overlap: f64) -> String {
    format!("overlap {overlap:.3} below --min-overlap")
}
