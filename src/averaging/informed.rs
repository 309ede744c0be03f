//! Averaging that learns from each edge only what it knows: every edge carries a
//! 3x3 rotation and a 3x3 translation information matrix ([`EdgeInformation`],
//! from the pair's [`FitInformation`]), so an edge over a flat field fixes height
//! and tilt but not x, y or yaw. Steps:
//! 1. the scalar averaging ([`super::average`]) with weights 1 / mean variance and
//!    per-axis sigmas 1 / sqrt(Omega_kk) (its robust rounds reject gross outliers),
//!    edges not `reliable` (not converged, ambiguous) at `unreliable_factor` weight;
//! 2. refinement with the full 3x3 information ([`super::block`]): Gauss-Newton on
//!    the rotations (right perturbations), then the linear translation solve;
//! 3. `max_rounds` iteratively reweighted refinements with Cauchy weights
//!    1 / (1 + (d / outlier_sigma)^2) of the Mahalanobis residual
//!    d = sqrt(r^T Omega r) (every edge readmitted); then the re-seeding
//!    ([`reseed`]: a node or group sitting in an outlier's basin moves to the
//!    rigid proposal of one of its boundary edges when that lowers the robust
//!    cost) and the rounds again; then rounds that drop edges whose d exceeds
//!    max(`outlier_sigma`, k x median) (all at once; bridges down-weighted
//!    instead of dropped), readmitting dropped edges that fit again or that no
//!    kept edge opposes ([`reseed::unopposed`]), the rest at full weight;
//! 4. per-node standard errors ([`super::covariance`]) from what the edges'
//!    data say (each pair's rotation prior taken off: [`EdgeInformation::prior_rotation`]),
//!    the shifts' plus what an outlier edge the test could miss would add
//!    ([`super::reliability`]), times the a-posteriori standard deviation of unit weight when it exceeds
//!    one (the edges disagree more than their own sigmas say:
//!    [`variance_factor`]), each rotation then held once by the DSMs' rotation
//!    prior ([`hold_once`]), and status.
//!
//! Frames: both blocks are about the axes of DSM i's frame (the pair's reference),
//! the translation at the edge's centre (`Edge::centre_j`); DSM rotations are tiny,
//! so i's and j's axes agree to first order.

use super::block::BlockEdge;
use super::consistency::{
    active_components, mahalanobis_residuals, unreliable_weight, variance_factor,
};
use super::covariance::{node_sigmas, translation_edge, CovarianceMethod, NodeSigma};
use super::joint::joint_node_sigmas;
use super::reliability::outlier_variances;
use super::{average, AveragingError, AveragingOptions, AveragingResult};
use crate::graph::{EdgeSigma, PoseGraph};
use crate::poses::rigid::{from_parts, rotation, translation};
use decide::decide;
use nalgebra::{Matrix3, Matrix6, Vector3};
use refine::refine;
use reseed::reseed;

/// Poses as rotations and translations, M = [R t].
type Poses<'a> = (&'a mut [Matrix3<f64>], &'a mut [Vector3<f64>]);

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InformedOptions {
    /// The scalar averaging of step 1 (its gauge is overridden: mean).
    pub base: AveragingOptions,
    /// Weight factor of edges not `reliable`: the least it can be; the factor
    /// used is estimated from the data ([`unreliable_weight`]), at most 1.
    pub unreliable_factor: f64,
    /// Mahalanobis residual (in sigmas) above which an edge may be an outlier.
    pub outlier_sigma: f64,
    /// ... and above this times the median Mahalanobis residual.
    pub outlier_k: f64,
    pub max_rounds: usize,
    /// Joint Gauss-Newton steps over rotations and translations after each
    /// decoupled refinement ([`super::joint`]); 0 keeps the decoupled solution.
    pub joint_steps: usize,
    /// Each edge's information is floored at this fraction of the median
    /// information (isotropic), so a node seen only along some axes stays solvable.
    pub floor_of_median: f64,
    pub covariance: CovarianceMethod,
    /// One-sigma prior on each node's rotation about the identity (its
    /// georeferencing), radians per axis; infinite: none. Held in the joint
    /// steps: on a grid of small tiles the pairs' yaws, each known to a few
    /// hundredths of a degree, otherwise add up across the grid.
    pub rotation_prior_rad: f64,
    /// A node whose shift sigma exceeds this (metres) is `Weak`.
    pub weak_sigma_m: f64,
    /// ... or whose rotation sigma exceeds this (degrees).
    pub weak_sigma_deg: f64,
}

impl Default for InformedOptions {
    fn default() -> Self {
        InformedOptions {
            // The scalar averaging only starts the refinement: rotations to 1e-7
            // rad (a thousandth of a pair's rotation sigma) are plenty, and each
            // decade more costs a subspace step per round on large grids (their
            // spectral gap is small).
            base: AveragingOptions {
                rotation_tol_rad: 1e-7,
                ..AveragingOptions::default()
            },
            unreliable_factor: 0.01,
            outlier_sigma: 5.0,
            outlier_k: 5.0,
            max_rounds: 10,
            joint_steps: 2,
            floor_of_median: 1e-6,
            covariance: CovarianceMethod::default(),
            rotation_prior_rad: f64::INFINITY,
            weak_sigma_m: 1.0,
            weak_sigma_deg: 0.5,
        }
    }
}

/// Up to this many nodes the pose sigmas come from the joint normal equations
/// (rotation uncertainty carried into the shifts; exact: a dense inverse up to
/// `CovarianceMethod::exact_max_nodes / 2`, selected inversion of a sparse
/// factor above, sampled when that is over budget); larger graphs use
/// the decoupled covariance (shift given the rotations: an approximation that
/// understates the shift sigmas of tiles far from well-fixed ones).
pub const JOINT_COVARIANCE_MAX_NODES: usize = 2000;

/// How well the graph fixes a node.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum NodeStatus {
    Constrained,
    /// Reliable edges reach it, but its sigma exceeds the weak limits.
    Weak,
    /// No reliable, kept edge touches it: its pose is not learned from the data.
    Unconstrained,
}

#[derive(Clone, Debug, PartialEq)]
pub struct InformedResult {
    /// Poses, dropped and down-weighted edges (steps 1 and 3), residuals.
    pub averaging: AveragingResult,
    /// One per node, about its own axes (translation at its origin, given rotations).
    pub sigma: Vec<NodeSigma>,
    pub status: Vec<NodeStatus>,
    /// Mahalanobis residuals (rotation, translation) of every edge, in sigmas.
    pub mahalanobis: Vec<(f64, f64)>,
    /// Conjugate-gradient iterations of the refinement solves.
    pub refine_iterations: usize,
    /// A-posteriori variance of unit weight of the kept edges (1: they agree as
    /// their sigmas say; None without redundancy). Node sigmas are scaled by its
    /// square root when it exceeds one.
    pub variance_factor: Option<f64>,
    /// The weight factor the edges not `reliable` entered with.
    pub unreliable_weight: f64,
}

/// Averages `graph` with one [`EdgeInformation`] per edge.
pub fn average_informed(
    graph: &PoseGraph,
    information: &[EdgeInformation],
    options: &InformedOptions,
) -> Result<InformedResult, AveragingError> {
    if information.len() != graph.edges.len() {
        return Err(AveragingError::InvalidOptions(format!(
            "{} edge information matrices for {} edges",
            information.len(),
            graph.edges.len()
        )));
    }
    if let Some(k) = information.iter().position(|e| !e.is_valid()) {
        return Err(AveragingError::InvalidOptions(format!(
            "edge {k}: information must be finite, symmetric, positive semi-definite"
        )));
    }
    let omegas = effective_information(information, options);
    let scalar = scalar_graph(graph, &omegas);
    let base = AveragingOptions {
        gauge: super::Gauge::Mean,
        ..options.base
    };
    let mut result = average(&scalar, &base)?;
    let usable: Vec<f64> = (0..graph.edges.len())
        .map(|k| f64::from(scalar.edges[k].weight > 0.0))
        .collect();
    let mut rotations: Vec<Matrix3<f64>> = result.poses.iter().map(rotation).collect();
    let mut translations: Vec<Vector3<f64>> = result.poses.iter().map(translation).collect();
    let mut iterations = 0;
    let mut irls = |omegas: &[Matrix6<f64>], count: usize, poses: Poses| {
        let (rounds, residuals) = reweighted_rounds(graph, omegas, &usable, options, count, poses);
        iterations += rounds;
        residuals
    };
    // Iteratively reweighted (Cauchy, scale `outlier_sigma`) from the scalar
    // solution, every edge readmitted: the scalar rounds may have dropped good ones.
    let poses = (&mut rotations[..], &mut translations[..]);
    let mut mahalanobis = irls(&omegas, options.max_rounds, poses);
    // A node started in an outlier's basin stays there under the Cauchy rounds:
    // move it to the proposal of one of its edges when that fits its edges better.
    let seeded = reseed(
        graph,
        &omegas,
        &usable,
        &mahalanobis,
        options.outlier_sigma,
        (&mut rotations, &mut translations),
    );
    tracing::info!(
        groups = seeded.moves,
        nodes = seeded.nodes_moved,
        sweeps = seeded.sweeps,
        "groups re-seeded"
    );
    if seeded.moves > 0 {
        let poses = (&mut rotations[..], &mut translations[..]);
        mahalanobis = irls(&omegas, options.max_rounds, poses);
    }
    // How far the unreliable edges really are from the reliable ones' solution
    // sets their weight; then the IRLS rounds again at that weight.
    let unreliable = unreliable_weight(information, &mahalanobis, &usable, options);
    let mut omegas = omegas;
    if unreliable != options.unreliable_factor {
        let at = InformedOptions {
            unreliable_factor: unreliable,
            ..*options
        };
        omegas = effective_information(information, &at);
        let poses = (&mut rotations[..], &mut translations[..]);
        mahalanobis = irls(&omegas, options.max_rounds / 2, poses);
    }
    // Then the hard decisions ([`decide`]).
    let poses = (&mut rotations[..], &mut translations[..]);
    let decided = decide(graph, &omegas, &usable, options, mahalanobis, poses);
    iterations += decided.iterations;
    let (active, mahalanobis) = (decided.active, decided.mahalanobis);
    result.dropped_edges = (0..graph.edges.len())
        .filter(|&k| active[k] == 0.0 && usable[k] > 0.0)
        .collect();
    result.downweighted_edges = decided.downweighted;
    result.downweighted_edges.sort_unstable();
    result.downweighted_edges.dedup();
    let mut poses: Vec<_> = rotations
        .iter()
        .zip(&translations)
        .map(|(r, t)| from_parts(r, t))
        .collect();
    let components = active_components(graph, &active);
    for members in &components {
        super::fix_gauge(&mut poses, members, None);
    }
    let rotations: Vec<Matrix3<f64>> = poses.iter().map(rotation).collect();
    // The covariance from what the edges' data say; each DSM is then held by
    // the rotation prior once ([`hold_once`]), where the pairs' fits held
    // every edge with it (k edges: k times the prior on a DSM's rotation).
    let data_only: Vec<EdgeInformation> = information
        .iter()
        .map(EdgeInformation::without_prior)
        .collect();
    let at = InformedOptions {
        unreliable_factor: unreliable,
        ..*options
    };
    let weighted: Vec<Matrix6<f64>> = effective_information(&data_only, &at)
        .iter()
        .zip(&active)
        .map(|(o, &a)| o * a)
        .collect();
    let translations: Vec<Vector3<f64>> = poses.iter().map(translation).collect();
    let mut sigma = if options.joint_steps > 0 && graph.n <= JOINT_COVARIANCE_MAX_NODES {
        joint_node_sigmas(
            graph,
            &weighted,
            &rotations,
            &translations,
            &components,
            options.covariance,
        )
    } else {
        node_sigmas(
            graph,
            &weighted,
            &rotations,
            &components,
            options.covariance,
        )
    };
    add_outlier_variances(
        graph,
        &weighted,
        &rotations,
        &components,
        options,
        &mut sigma,
    );
    let factor = variance_factor(graph, &mahalanobis, &active, &components);
    let scale = factor.unwrap_or(1.0).max(1.0).sqrt();
    for s in &mut sigma {
        s.shift_m.iter_mut().for_each(|v| *v *= scale);
        s.rotation_deg.iter_mut().for_each(|v| *v *= scale);
        hold_once(s, options.rotation_prior_rad);
    }
    let status = node_status(graph, information, &active, &sigma, options);
    result.edge_residuals = super::edge_residuals(graph, &poses);
    result.poses = poses;
    result.components = components;
    Ok(InformedResult {
        averaging: result,
        sigma,
        status,
        mahalanobis,
        refine_iterations: iterations,
        variance_factor: factor,
        unreliable_weight: unreliable,
    })
}

/// Each node's shift variance plus what an outlier edge the graph's test
/// could miss would add ([`super::reliability`]), from the translation blocks
/// of the edges as weighted for the covariance; unchanged where the graph's
/// factor is over the direct budget (logged).
fn add_outlier_variances(
    graph: &PoseGraph,
    weighted: &[Matrix6<f64>],
    rotations: &[Matrix3<f64>],
    components: &[Vec<usize>],
    options: &InformedOptions,
    sigma: &mut [NodeSigma],
) {
    let edges: Vec<BlockEdge> = graph
        .edges
        .iter()
        .zip(weighted)
        .filter(|(_, o)| o.fixed_view::<3, 3>(3, 3).amax() > 0.0)
        .map(|(e, o)| {
            let om_t = o.fixed_view::<3, 3>(3, 3).into_owned();
            translation_edge(e.i, e.j, &om_t, &rotations[e.i])
        })
        .collect();
    let Some(extra) = outlier_variances(graph.n, &edges, components, options.outlier_sigma) else {
        tracing::info!(
            nodes = graph.n,
            edges = edges.len(),
            "pose sigmas without the undetected-outlier term (the factor is over its budget)"
        );
        return;
    };
    for (s, v) in sigma.iter_mut().zip(&extra) {
        for (a, x) in s.shift_m.iter_mut().enumerate() {
            if x.is_finite() {
                *x = (*x * *x + v[a]).sqrt();
            }
        }
    }
}

/// A DSM's rotation sigmas from its edges' data combined, axis by axis, with
/// the rotation prior of one-sigma `prior_rad` that the solve holds each DSM
/// with (1 / v = 1 / v_data + 1 / sigma^2; an approximation where the axes
/// correlate). An infinite prior changes nothing.
fn hold_once(sigma: &mut NodeSigma, prior_rad: f64) {
    if !(prior_rad > 0.0 && prior_rad.is_finite()) {
        return;
    }
    let prior_deg = prior_rad.to_degrees();
    for s in &mut sigma.rotation_deg {
        if s.is_finite() && *s > 0.0 {
            *s = 1.0 / (s.powi(-2) + prior_deg.powi(-2)).sqrt();
        }
    }
}

/// `rounds` refinements with Cauchy weights (scale `outlier_sigma`) of the
/// residuals at the poses each starts from: CG iterations and the residuals at
/// the final poses.
fn reweighted_rounds(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    usable: &[f64],
    options: &InformedOptions,
    rounds: usize,
    (rotations, translations): Poses,
) -> (usize, Vec<(f64, f64)>) {
    let mut iterations = 0;
    let mut mahalanobis = mahalanobis_residuals(graph, omegas, rotations, translations);
    for _ in 0..rounds {
        let weights = cauchy_weights(&mahalanobis, usable, options.outlier_sigma);
        iterations += refine(graph, omegas, &weights, options, rotations, translations);
        mahalanobis = mahalanobis_residuals(graph, omegas, rotations, translations);
    }
    (iterations, mahalanobis)
}

/// active / (1 + (d / scale)^2), d the larger Mahalanobis residual of the edge.
fn cauchy_weights(mahalanobis: &[(f64, f64)], active: &[f64], scale: f64) -> Vec<f64> {
    mahalanobis
        .iter()
        .zip(active)
        .map(|(&(r, t), &a)| a / (1.0 + (r.max(t) / scale).powi(2)))
        .collect()
}

/// Each edge's information as one 6x6 block-diagonal (rotation top-left), times the
/// reliability factor, floored at `floor_of_median` of the median (per block).
fn effective_information(
    information: &[EdgeInformation],
    options: &InformedOptions,
) -> Vec<Matrix6<f64>> {
    let median_trace = |f: &dyn Fn(&EdgeInformation) -> f64| {
        let mut v: Vec<f64> = information.iter().map(f).collect();
        if v.is_empty() {
            return 0.0;
        }
        crate::coarse::cost::median_in_place(&mut v) / 3.0
    };
    let floor_r = options.floor_of_median * median_trace(&|e| e.rotation.trace());
    let floor_t = options.floor_of_median * median_trace(&|e| e.translation.trace());
    information
        .iter()
        .map(|e| {
            let f = if e.reliable {
                1.0
            } else {
                options.unreliable_factor
            };
            let mut m = Matrix6::zeros();
            m.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(e.rotation * f + Matrix3::identity() * floor_r));
            m.fixed_view_mut::<3, 3>(3, 3)
                .copy_from(&(e.translation * f + Matrix3::identity() * floor_t));
            m
        })
        .collect()
}

/// The sigma of an axis an edge does not see (no information at all: the
/// rotations under `--model translation`): finite, so that it survives the
/// graph's f32 sigmas and its validation.
const UNSEEN_SIGMA: f64 = 1e30;

/// Most ratio of a scalar-start weight to the median (either way).
const SCALAR_WEIGHT_SPAN: f64 = 100.0;

/// The graph with scalar weights 1 / (mean variance), variance_k = 1 / Omega_kk
/// (an axis an edge does not see makes the whole edge weak: a scalar cannot say
/// "x only"), and per-axis sigmas 1 / sqrt(Omega_kk).
fn scalar_graph(graph: &PoseGraph, omegas: &[Matrix6<f64>]) -> PoseGraph {
    let weight = |o: &Matrix6<f64>, at: usize| {
        3.0 / (at..at + 3)
            .map(|k| 1.0 / o[(k, k)].max(f64::MIN_POSITIVE))
            .sum::<f64>()
    };
    let mean = |at: usize| {
        (omegas.iter().map(|o| weight(o, at)).sum::<f64>() / omegas.len().max(1) as f64)
            .max(f64::MIN_POSITIVE)
    };
    let (mr, mt) = (mean(0), mean(3));
    // The weights only start the refinement: kept within SCALAR_WEIGHT_SPAN of their
    // median, so that a few stiff edges (10^4 x the median on a grid of 32 m tiles) and
    // floored ones do not make its solves crawl.
    let median = |at: usize, scale: f64| {
        let mut w: Vec<f64> = omegas
            .iter()
            .map(|o| weight(o, at) / scale)
            .filter(|&w| w > 0.0)
            .collect();
        if w.is_empty() {
            1.0
        } else {
            crate::coarse::cost::median_in_place(&mut w)
        }
    };
    let (qr, qt) = (median(0, mr), median(3, mt));
    // (an edge of weight 0 stays out)
    let squeeze = |w: f64, q: f64| {
        if w > 0.0 {
            w.clamp(q / SCALAR_WEIGHT_SPAN, q * SCALAR_WEIGHT_SPAN)
        } else {
            0.0
        }
    };
    let mut out = graph.clone();
    for (e, o) in out.edges.iter_mut().zip(omegas) {
        e.weight = squeeze(weight(o, 0) / mr, qr);
        e.translation_weight = squeeze(weight(o, 3) / mt, qt);
        let sd = |k: usize| (1.0 / o[(k, k)].max(f64::MIN_POSITIVE).sqrt()).min(UNSEEN_SIGMA);
        e.sigma = Some(EdgeSigma::new(
            Vector3::new(sd(0), sd(1), sd(2)),
            Vector3::new(sd(3), sd(4), sd(5)),
        ));
    }
    out
}

fn node_status(
    graph: &PoseGraph,
    information: &[EdgeInformation],
    active: &[f64],
    sigma: &[NodeSigma],
    options: &InformedOptions,
) -> Vec<NodeStatus> {
    let mut reached = vec![false; graph.n];
    for ((e, info), &a) in graph.edges.iter().zip(information).zip(active) {
        if info.reliable && a >= 0.999 {
            reached[e.i] = true;
            reached[e.j] = true;
        }
    }
    reached
        .iter()
        .zip(sigma)
        .map(|(&r, s)| {
            if !r {
                NodeStatus::Unconstrained
            } else if s.shift_m.iter().any(|&v| v > options.weak_sigma_m)
                || s.rotation_deg.iter().any(|&v| v > options.weak_sigma_deg)
            {
                NodeStatus::Weak
            } else {
                NodeStatus::Constrained
            }
        })
        .collect()
}

mod decide;
mod edge;
#[cfg(test)]
use edge::block_inverse;
pub use edge::EdgeInformation;
#[cfg(test)]
use edge::MOST_PRIOR_SHARE;
mod refine;
mod reseed;
#[cfg(test)]
mod tests;
