//! Poses from the scene graph, two ways: motion averaging over every edge
//! (`--graph full`, robust: outliers dropped or down-weighted), or the greedy
//! baseline, poses chained along the maximum-overlap spanning tree
//! (`--graph mst`). Both give a [`PoseSolution`] in the graph's local frame.

use nalgebra::Matrix4;

use super::scene::SceneGraph;
use super::AlignError;
use crate::averaging::{
    average, average_informed, edge_residuals, fix_gauge, AveragingOptions, EdgeInformation,
    EdgeResidual, Gauge, InformedOptions, NodeSigma, NodeStatus,
};
use crate::graph::{chain_poses, mst, Weighting};
use crate::poses::{GraphKind, PosesSummary};

/// Poses of every DSM and how each edge agrees with them.
#[derive(Clone, Debug)]
pub struct PoseSolution {
    /// M_k in the graph's local frame, gauge fixed per component.
    pub poses_local: Vec<Matrix4<f64>>,
    /// One per graph edge, against the poses.
    pub residuals: Vec<EdgeResidual>,
    /// Edges the robust averaging rejected (ascending).
    pub dropped: Vec<usize>,
    /// Outlier edges kept at a lower weight (they hold a component together).
    pub downweighted: Vec<usize>,
    /// The spanning tree's edges (`--graph mst`); None for motion averaging.
    pub tree: Option<Vec<usize>>,
    /// Connected components (node indices, each ascending).
    pub components: Vec<Vec<usize>>,
    /// Totals of the averaging (None for the spanning tree).
    pub summary: Option<PosesSummary>,
    /// Standard errors of each pose from the solve (informed averaging only).
    pub sigma: Option<Vec<NodeSigma>>,
    /// How well the kept, reliable edges fix each pose (informed averaging only).
    pub status: Option<Vec<NodeStatus>>,
}

/// Solves the poses of `scene` with the chosen graph and gauge.
/// `rotation_prior_deg`: one-sigma prior on each DSM's rotation about its
/// georeferencing (information averaging only; infinite: none).
pub fn solve(
    scene: &SceneGraph,
    graph: GraphKind,
    anchor: Option<usize>,
    rotation_prior_deg: f64,
) -> Result<PoseSolution, AlignError> {
    match graph {
        GraphKind::Full => solve_full(scene, anchor, rotation_prior_deg),
        GraphKind::Mst => solve_mst(scene, anchor),
    }
}

fn solve_full(
    scene: &SceneGraph,
    anchor: Option<usize>,
    rotation_prior_deg: f64,
) -> Result<PoseSolution, AlignError> {
    if let Some(information) = &scene.information {
        let options = InformedOptions {
            rotation_prior_rad: rotation_prior_deg.to_radians(),
            ..InformedOptions::default()
        };
        return solve_informed(scene, information, anchor, &options);
    }
    let weights = scene.weights.used;
    let options = AveragingOptions {
        gauge: anchor.map_or(Gauge::Mean, Gauge::Anchor),
        // Residuals in sigmas only with the weights that trust the sigmas.
        outlier_by_sigma: weights == Weighting::Information,
        ..AveragingOptions::default()
    };
    let result =
        average(&scene.graph, &options).map_err(|e| AlignError::Averaging(e.to_string()))?;
    let summary = PosesSummary {
        weights: Some(weights),
        ..PosesSummary::from_result(&result)
    };
    Ok(PoseSolution {
        poses_local: result.poses,
        residuals: result.edge_residuals,
        dropped: result.dropped_edges,
        downweighted: result.downweighted_edges,
        tree: None,
        components: result.components,
        summary: Some(summary),
        sigma: None,
        status: None,
    })
}

/// Motion averaging with each edge's 3x3 rotation and translation information
/// ([`average_informed`]); the anchor, if any, is applied afterwards (a rigid
/// motion of each component: residuals and sigmas about the mean gauge).
fn solve_informed(
    scene: &SceneGraph,
    information: &[EdgeInformation],
    anchor: Option<usize>,
    options: &InformedOptions,
) -> Result<PoseSolution, AlignError> {
    let informed = average_informed(&scene.graph, information, options)
        .map_err(|e| AlignError::Averaging(e.to_string()))?;
    let mut result = informed.averaging;
    for members in &result.components {
        fix_gauge(
            &mut result.poses,
            members,
            anchor.filter(|a| members.contains(a)),
        );
    }
    let summary = PosesSummary {
        weights: Some(scene.weights.used),
        variance_factor: informed.variance_factor,
        unreliable_weight: Some(informed.unreliable_weight),
        ..PosesSummary::from_result(&result)
    };
    Ok(PoseSolution {
        poses_local: result.poses,
        residuals: result.edge_residuals,
        dropped: result.dropped_edges,
        downweighted: result.downweighted_edges,
        tree: None,
        components: result.components,
        summary: Some(summary),
        sigma: Some(informed.sigma),
        status: Some(informed.status),
    })
}

fn solve_mst(scene: &SceneGraph, anchor: Option<usize>) -> Result<PoseSolution, AlignError> {
    let graph = &scene.graph;
    let tree = mst(graph);
    let mut poses = chain_poses(graph, &tree, anchor.unwrap_or(0))
        .map_err(|e| AlignError::Averaging(e.to_string()))?;
    let components = graph.components().members;
    for members in &components {
        fix_gauge(&mut poses, members, anchor.filter(|a| members.contains(a)));
    }
    let residuals = edge_residuals(graph, &poses);
    Ok(PoseSolution {
        poses_local: poses,
        residuals,
        dropped: Vec::new(),
        downweighted: Vec::new(),
        tree: Some(tree),
        components,
        summary: None,
        sigma: None,
        status: None,
    })
}
