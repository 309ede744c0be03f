//! The result of `align` for the user: the poses.json model in world
//! coordinates (each edge joined to its pair's ICP statistics by index), the
//! pairs without edge, and the counts the summary prints ([`EdgeCounts`]).

use std::collections::HashSet;

use super::scene::{SceneGraph, WeightsUsed};
use super::solve::PoseSolution;
use super::AlignConfig;
use crate::averaging::{NodeSigma, NodeStatus};
use crate::icp::IcpStatus;
use crate::pipeline::PairOutcome;
use crate::poses::rigid::to_world;
use crate::poses::{EdgeEntry, GaugeLabel, PoseEntry, PosesFile};
use crate::store::Store;

/// A pair that should have given an edge and did not.
#[derive(Clone, Debug, PartialEq)]
pub struct FailedPair {
    pub reference: String,
    pub moving: String,
    pub why: String,
}

/// How many edges the graph had and what the solve did with them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeCounts {
    /// Registered pairs: the edges of the full graph.
    pub edges: usize,
    /// Edges of the spanning tree (`--graph mst`), None for motion averaging.
    pub tree_edges: Option<usize>,
    /// Rejected as outliers by the robust averaging.
    pub dropped: usize,
    /// Kept at a lower weight by the robust averaging.
    pub downweighted: usize,
    /// Edges whose pair did not converge or is ambiguous: in the information
    /// averaging at `unreliable_weight` of their weight, never counted as
    /// constraining.
    pub unreliable: usize,
    pub unreliable_weight: Option<f64>,
    /// A-posteriori variance of unit weight (information averaging).
    pub variance_factor: Option<f64>,
}

/// Everything the report is built from.
pub struct Parts<'a> {
    pub store: &'a Store,
    pub config: &'a AlignConfig,
    pub anchor: Option<usize>,
    pub outcomes: &'a [PairOutcome],
    pub scene: &'a SceneGraph,
    pub solution: &'a PoseSolution,
}

/// The poses file of a solved run.
pub fn poses_file(parts: &Parts<'_>) -> PosesFile {
    let dsms = parts.store.dsms();
    let (scene, solution) = (parts.scene, parts.solution);
    let poses = solution
        .poses_local
        .iter()
        .enumerate()
        .map(|(k, m)| PoseEntry {
            id: dsms[k].id.clone(),
            matrix_world: to_world(m, &scene.origin_world),
            sigma: solution
                .sigma
                .as_ref()
                .map(|s| with_gridding_floor(s[k], &dsms[k], parts.config))
                .filter(|s| {
                    s.shift_m
                        .iter()
                        .chain(&s.rotation_deg)
                        .all(|v| v.is_finite())
                }),
            status: solution
                .status
                .as_ref()
                .map(|s| s[k])
                .filter(|s| *s != NodeStatus::Constrained),
        })
        .collect();
    let dropped: HashSet<usize> = solution.dropped.iter().copied().collect();
    let downweighted: HashSet<usize> = solution.downweighted.iter().copied().collect();
    let edges = scene
        .graph
        .edges
        .iter()
        .enumerate()
        .map(|(k, e)| {
            let fit = parts.outcomes[scene.outcome_of_edge[k]]
                .edge_fit()
                .expect("graph edges come from registered pairs");
            EdgeEntry {
                i: dsms[e.i].id.clone(),
                j: dsms[e.j].id.clone(),
                overlap: e.overlap,
                rmse_m: e.rmse_m,
                weight: e.weight,
                translation_weight: Some(e.translation_weight),
                iterations: fit.iterations as u32,
                inliers: fit.inliers as u64,
                residual_m: solution.residuals[k].translation_m,
                residual_deg: solution.residuals[k].rotation_deg,
                dropped: dropped.contains(&k),
                downweighted: downweighted.contains(&k),
                converged: fit.status == IcpStatus::Converged,
            }
        })
        .collect();
    let components = component_ids(parts.store, solution);
    PosesFile {
        crs: parts.store.crs().map(|c| c.label()).unwrap_or_default(),
        poses,
        edges,
        graph: parts.config.graph,
        gauge: parts
            .anchor
            .map_or(GaugeLabel::Mean, |a| GaugeLabel::Anchor(dsms[a].id.clone())),
        components: (components.len() > 1).then_some(components),
        summary: solution.summary.clone(),
    }
}

/// The connected components as lists of ids.
pub fn component_ids(store: &Store, solution: &PoseSolution) -> Vec<Vec<String>> {
    let dsms = store.dsms();
    solution
        .components
        .iter()
        .map(|c| c.iter().map(|&k| dsms[k].id.clone()).collect())
        .collect()
}

/// Ids of the DSMs no reliable, kept edge constrains (informed averaging only).
pub fn unconstrained_ids(store: &Store, solution: &PoseSolution) -> Vec<String> {
    let dsms = store.dsms();
    solution
        .status
        .iter()
        .flatten()
        .enumerate()
        .filter(|(_, s)| **s == NodeStatus::Unconstrained)
        .map(|(k, _)| dsms[k].id.clone())
        .collect()
}

/// Pairs that failed (not the ones below `--min-overlap`), with the reason.
pub fn failed_pairs(store: &Store, outcomes: &[PairOutcome]) -> Vec<FailedPair> {
    let dsms = store.dsms();
    outcomes
        .iter()
        .filter(|o| matches!(o, PairOutcome::Failed { .. }))
        .map(|o| FailedPair {
            reference: dsms[o.pair().reference].id.clone(),
            moving: dsms[o.pair().moving].id.clone(),
            why: o.why_no_edge().unwrap_or_default(),
        })
        .collect()
}

/// The edge counts of a solve.
pub fn edge_counts(scene: &SceneGraph, solution: &PoseSolution) -> EdgeCounts {
    EdgeCounts {
        edges: scene.graph.edges.len(),
        tree_edges: solution.tree.as_ref().map(Vec::len),
        dropped: solution.dropped.len(),
        downweighted: solution.downweighted.len(),
        unreliable: scene
            .information
            .as_ref()
            .map_or(0, |info| info.iter().filter(|e| !e.reliable).count()),
        variance_factor: solution.summary.as_ref().and_then(|s| s.variance_factor),
        unreliable_weight: solution.summary.as_ref().and_then(|s| s.unreliable_weight),
    }
}

/// One warning when the weights are not the requested ones (motion averaging
/// only: the spanning tree does not use them).
pub fn weights_warning(weights: &WeightsUsed, tree: bool) -> Option<String> {
    weights.fallback.as_ref().filter(|_| !tree)?;
    Some(
        "some pairs have no standard errors (journaled by an older version, or --metric point-to-point): paper weights used".into(),
    )
}

/// A pose's sigma with its DSM's share of the gridding floor on its shift
/// and rotation ([`crate::icp::floor::pose_floor_m`],
/// [`crate::icp::floor::pose_floor_rad`]): the graph weighs the fits' own
/// covariances, and each DSM's placement error is shared by all its pairs.
fn with_gridding_floor(
    mut sigma: NodeSigma,
    dsm: &crate::store::catalog::DsmMeta,
    config: &AlignConfig,
) -> NodeSigma {
    use crate::icp::floor::{footprint_radius_m, pose_floor_m, pose_floor_rad};
    let pixel_m = dsm.geotransform.pixel_m();
    let k_px = config.pipeline.icp.sigma_floor_px;
    for (s, f) in sigma.shift_m.iter_mut().zip(pose_floor_m(pixel_m, k_px)) {
        *s = s.hypot(f);
    }
    let radius_m = footprint_radius_m(dsm.footprint.width(), dsm.footprint.height());
    let turn = pose_floor_rad(pixel_m, k_px, radius_m);
    for (s, f) in sigma.rotation_deg.iter_mut().zip(turn) {
        *s = s.hypot(f.to_degrees());
    }
    sigma
}
