//! From pair outcomes to the scene graph: one edge per registered pair, in a
//! local frame near the data (UTM coordinates are ~10^6 m), with the edge
//! weights. The weight fallback (information weights need every edge's
//! standard errors; the paper's are used when one has none) is decided here,
//! once, and carried to the report as [`WeightsUsed`].

use nalgebra::{Isometry3, Matrix3, Matrix4, Vector3};

use super::{AlignConfig, AlignError};
use crate::averaging::EdgeInformation;
use crate::fit::Model;
use crate::graph::{information_weights, paper_weights, Edge, EdgeSigma, PoseGraph, Weighting};
use crate::icp::IcpConfig;
use crate::pipeline::{IcpFit, PairOutcome, PairTask};
use crate::poses::rigid::to_local;
use crate::store::Store;

/// The weights the averaging got, and why they differ from the requested ones.
#[derive(Clone, Debug, PartialEq)]
pub struct WeightsUsed {
    pub requested: Weighting,
    pub used: Weighting,
    /// Why the paper's weights replaced the information weights.
    pub fallback: Option<String>,
}

/// The scene graph of one run.
#[derive(Clone, Debug)]
pub struct SceneGraph {
    /// Edges in the local frame, weighted.
    pub graph: PoseGraph,
    /// For edge k, the index of its pair in the outcome list.
    pub outcome_of_edge: Vec<usize>,
    /// World position of the local frame's origin.
    pub origin_world: Vector3<f64>,
    pub weights: WeightsUsed,
    /// What each edge knows (one per edge), when every edge has a covariance or
    /// standard errors, at least one a covariance, and information weights are
    /// used; None otherwise (then the scalar averaging runs).
    pub information: Option<Vec<EdgeInformation>>,
}

/// One edge per registered pair, weighted; an error when no pair registered.
pub fn build_graph(
    store: &Store,
    outcomes: &[PairOutcome],
    config: &AlignConfig,
) -> Result<SceneGraph, AlignError> {
    let origin_world = local_origin(store);
    let mut graph = PoseGraph::new(store.dsms().len());
    let mut outcome_of_edge = Vec::new();
    let mut information = Vec::new();
    for (k, outcome) in outcomes.iter().enumerate() {
        if let PairOutcome::Registered { pair, overlap, fit } = outcome {
            let e = edge(store, *pair, *overlap, fit, &origin_world);
            information.push(edge_information(fit, &e, &config.pipeline.icp));
            graph.edges.push(e);
            outcome_of_edge.push(k);
        }
    }
    if graph.edges.is_empty() {
        return Err(no_edge_error(store, outcomes, config.pipeline.min_overlap));
    }
    let weights = weigh(&mut graph.edges, config.weights);
    // Until some pair reports a covariance (an ICP that computes it), the scalar
    // averaging of the standard errors runs as before.
    let any_covariance = outcome_of_edge.iter().any(|&k| {
        outcomes[k]
            .edge_fit()
            .is_some_and(|f| f.information.is_some())
    });
    let information = information
        .into_iter()
        .collect::<Option<Vec<_>>>()
        .filter(|_| weights.used == Weighting::Information && any_covariance);
    Ok(SceneGraph {
        graph,
        outcome_of_edge,
        origin_world,
        weights,
        information,
    })
}

/// The requested weights, or the paper's when an edge has no standard errors.
fn weigh(edges: &mut [Edge], requested: Weighting) -> WeightsUsed {
    let fallback = match requested {
        Weighting::Information => information_weights(edges).err().map(|e| e.to_string()),
        Weighting::Paper => None,
    };
    let used = if requested == Weighting::Paper || fallback.is_some() {
        paper_weights(edges);
        Weighting::Paper
    } else {
        Weighting::Information
    };
    WeightsUsed {
        requested,
        used,
        fallback,
    }
}

/// Why there is no graph: no pair above `--min-overlap`, or none registered.
fn no_edge_error(store: &Store, outcomes: &[PairOutcome], min_overlap: f64) -> AlignError {
    let root = store.root().display();
    let above: Vec<&PairOutcome> = outcomes
        .iter()
        .filter(|o| !matches!(o, PairOutcome::BelowOverlap { .. }))
        .collect();
    AlignError::Input(match above.first() {
        None => format!("{root}: no pair overlaps by at least --min-overlap {min_overlap}"),
        Some(first) => {
            let pair = first.pair();
            let dsms = store.dsms();
            format!(
                "{root}: none of the {} overlapping pairs registered (first: {}-{}: {})",
                above.len(),
                dsms[pair.reference].id,
                dsms[pair.moving].id,
                first.why_no_edge().unwrap_or_default()
            )
        }
    })
}

/// What the edge of `fit` knows: the fit's covariance blocks when it reported
/// them (with the part its rotation prior gave marked: the poses' sigmas
/// count the prior once per DSM), else diagonal information from its standard
/// errors (journals of older versions); None when it has neither. Not
/// converged (still moving at the last iteration): unreliable, never at full
/// weight. The local frame differs from
/// the world frame by a shift only, so the blocks keep their axes; the
/// translation block is about the fit's centroid, which [`edge`] made the edge's
/// measurement point.
///
/// Under `--model translation` the pair did not estimate its rotation: the
/// model holds it at identity, so the edge says so with the stiffness of
/// [`HELD_ROTATION_SIGMA_RAD`] (a zero covariance would read as "knows
/// nothing" and leave the rotations free to drift).
fn edge_information(fit: &IcpFit, edge: &Edge, icp: &IcpConfig) -> Option<EdgeInformation> {
    let reliable = fit.reliable();
    let mut info = match &fit.information {
        Some(p) => {
            // the prior the pair's fit was given, if any (rigid, finite)
            let at = Isometry3::identity();
            let prior = icp
                .rotation_prior(&at, &at)
                .map_or(f64::INFINITY, |p| p.sigma_rad);
            EdgeInformation::from_covariance(&p.covariance_6x6(), reliable)
                .with_rotation_prior(prior)
        }
        None => EdgeInformation::from_sigma(edge.sigma.as_ref()?, reliable),
    };
    if icp.model == Model::Translation {
        info.rotation = Matrix3::identity() / HELD_ROTATION_SIGMA_RAD.powi(2);
    }
    info.is_valid().then_some(info)
}

/// Under `--model translation`: each pose's rotation (what the held edges
/// left of it, at most a few 1e-6 rad where the pairs' translations do not
/// close) folded into its shift at the DSM's centre, so the poses are pure
/// translations that move each DSM's centre where the solve put it.
pub fn hold_rotations(
    store: &Store,
    origin_world: &Vector3<f64>,
    poses_local: &mut [Matrix4<f64>],
) {
    for (pose, dsm) in poses_local.iter_mut().zip(store.dsms()) {
        let f = dsm.footprint.to_array();
        let centre = Vector3::new(
            (f[0] + f[2]) / 2.0,
            (f[1] + f[3]) / 2.0,
            dsm.height_stats.mean,
        ) - origin_world;
        let moved = pose.fixed_view::<3, 3>(0, 0) * centre + pose.fixed_view::<3, 1>(0, 3);
        let mut pure = Matrix4::identity();
        pure.fixed_view_mut::<3, 1>(0, 3)
            .copy_from(&(moved - centre));
        *pose = pure;
    }
}

/// The rotation sigma of an edge whose model holds the rotation (1e-5 rad,
/// 0.6 mm at 64 m): stiff enough that the poses come out pure translations,
/// soft enough to keep the joint solve well conditioned.
const HELD_ROTATION_SIGMA_RAD: f64 = 1e-5;

/// The graph edge of a registered pair, in the local frame: M_ij, its standard
/// errors ([`EdgeSigma::from_fit`]), and the point where its translation was
/// measured: the fit's centroid when it reported one, else the centre of the two
/// footprints' intersection at the mean height.
fn edge(
    store: &Store,
    pair: PairTask,
    overlap: f64,
    fit: &IcpFit,
    origin_world: &Vector3<f64>,
) -> Edge {
    let (i, j) = (pair.reference, pair.moving);
    let (a, b) = (&store.dsms()[i], &store.dsms()[j]);
    let (fa, fb) = (a.footprint.to_array(), b.footprint.to_array());
    let centre_world = Vector3::new(
        (fa[0].max(fb[0]) + fa[2].min(fb[2])) / 2.0,
        (fa[1].max(fb[1]) + fa[3].min(fb[3])) / 2.0,
        (a.height_stats.mean + b.height_stats.mean) / 2.0,
    );
    let centre_world = fit
        .information
        .as_ref()
        .map_or(centre_world, |p| p.centroid());
    let m_ij_local = to_local(&fit.t_ref_moving_world, origin_world);
    Edge {
        sigma: fit.sigma.map(|s| EdgeSigma::from_fit(&s, overlap)),
        centre_j: centre_world - origin_world,
        ..Edge::new(i, j, m_ij_local, overlap, fit.rmse_m)
    }
}

/// Centre of all footprints at the mean height: edges and poses are solved
/// relative to it.
fn local_origin(store: &Store) -> Vector3<f64> {
    let n = store.dsms().len() as f64;
    let (mut x, mut y, mut z) = (0.0, 0.0, 0.0);
    for d in store.dsms() {
        x += d.footprint.centre().0 / n;
        y += d.footprint.centre().1 / n;
        z += d.height_stats.mean / n;
    }
    Vector3::new(x.round(), y.round(), z.round())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::{Axis, FitSigma};
    use crate::icp::IcpStatus;
    use crate::pipeline::PairInformation;
    use nalgebra::Matrix4;

    fn fit(status: IcpStatus, information: Option<PairInformation>) -> IcpFit {
        IcpFit {
            status,
            t_ref_moving_world: Matrix4::identity(),
            rmse_m: 0.1,
            inliers: 100,
            iterations: 5,
            sigma: Some(FitSigma {
                rot_deg: [0.01, 0.02, 0.04],
                trans_m: [0.1, 0.2, 0.05],
            }),
            information: information.map(Box::new),
            search: None,
        }
    }

    #[test]
    fn edge_information_follows_the_fit_and_its_status() {
        let rigid = IcpConfig::default();
        let edge = Edge {
            sigma: Some(EdgeSigma::new(
                Vector3::new(1e-4, 2e-4, 4e-4),
                Vector3::new(0.1, 0.2, 0.05),
            )),
            ..Edge::new(0, 1, Matrix4::identity(), 0.5, 0.1)
        };
        // without a covariance: 1 / sigma^2 on the diagonal
        let info = edge_information(&fit(IcpStatus::Converged, None), &edge, &rigid).unwrap();
        assert!(info.reliable);
        assert!((info.translation[(1, 1)] - 25.0).abs() < 1e-3);
        assert!((info.rotation[(2, 2)] - 1.0 / 16e-8).abs() < 1.0);
        // with one, degenerate in x and yaw: nothing learned there
        let mut covariance = [[0.0; 6]; 6];
        for (k, v) in [0.0, 0.01, 0.0004, 1e-8, 1e-8, 0.0].into_iter().enumerate() {
            covariance[k][k] = v;
        }
        let p = PairInformation {
            covariance,
            centroid_world: [1.0, 2.0, 3.0],
            degenerate: vec![Axis::X, Axis::Yaw],
            gridding: None,
        };
        let info =
            edge_information(&fit(IcpStatus::MaxIterations, Some(p)), &edge, &rigid).unwrap();
        assert!(!info.reliable, "not converged: never at full weight");
        assert_eq!(info.translation[(0, 0)], 0.0);
        assert!((info.translation[(1, 1)] - 100.0).abs() < 1e-9);
        assert_eq!(info.rotation[(2, 2)], 0.0);
        // the pair's fit was held by the default rotation prior: its part of
        // roll is marked (the poses' sigmas count it once per DSM); the held
        // yaw has none
        let prior = rigid.rotation_prior_deg.to_radians().powi(-2);
        assert!((info.prior_rotation[(0, 0)] / prior - 1.0).abs() < 1e-9);
        assert_eq!(info.prior_rotation[(2, 2)], 0.0);
        // neither: no information (the scene then falls back)
        let bare = Edge {
            sigma: None,
            ..edge
        };
        assert!(edge_information(&fit(IcpStatus::Converged, None), &bare, &rigid).is_none());
    }
}
