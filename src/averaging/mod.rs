//! Motion averaging (paper step 4): from the pairwise relative poses M_ij of the scene
//! graph to one pose M_i per DSM. Rotations first, by the spectral method
//! ([`rotation`]), then translations by weighted linear least squares ([`translation`]),
//! each with its own per-edge weight (`Edge::weight`, `Edge::translation_weight`);
//! optionally robust: edges that disagree with the result are dropped (or, if they
//! hold a component together, down-weighted) and the graph is solved again
//! ([`robust`]). Each connected component is solved on its own gauge ([`gauge`]).
//!
//! The solver works in whatever frame the edges are given in; give it edges in a
//! local frame near the data (`poses::to_local`), not raw UTM coordinates.
//! Memory is O(nodes + edges) (no 3N x 3N matrix), time O(edges) per CG iteration;
//! the multigrid preconditioner ([`multilevel`]) keeps the iteration count nearly
//! flat on tile grids (~45 at 10^6 nodes, where Jacobi needs thousands).

mod block;
mod cg;
mod consistency;
mod covariance;
mod direct;
mod gauge;
mod informed;
mod joint;
mod laplacian;
mod marginals;
mod multilevel;
mod reliability;
mod robust;
mod rotation;
pub mod synthetic;
mod translation;

pub use covariance::{CovarianceMethod, NodeSigma};
pub use gauge::fix_gauge;
pub use informed::{
    average_informed, EdgeInformation, InformedOptions, InformedResult, NodeStatus,
};
pub use robust::edge_residuals;

use crate::graph::{chain_poses, max_spanning_forest, Components, GraphError, PoseGraph};
use crate::poses::rigid::{from_parts, rotation};
use cg::CgTolerance;
use laplacian::Laplacian;
use multilevel::Multilevel;
use nalgebra::{Matrix3, Matrix4, Vector3};
use robust::{residuals_of_parts, select_outliers, OutlierRule, OutlierTest};
use rotation::{solve_rotations, RotationSettings};
use std::time::Instant;
use translation::solve_translations;

/// How the conjugate-gradient solves are preconditioned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preconditioner {
    /// D^-1: cheapest per iteration; iterations grow with the graph diameter.
    Jacobi,
    /// Aggregation multigrid V-cycle: nearly constant iterations on tile grids.
    Multigrid,
}

/// Which rigid motion of each component is fixed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gauge {
    /// Mean rotation (SO(3) projection of the sum) is the identity, translations sum to 0.
    Mean,
    /// This node's pose is the identity; components without it use `Mean`.
    Anchor(usize),
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AveragingOptions {
    pub gauge: Gauge,
    /// Reject outlier edges and solve again.
    pub robust: bool,
    /// Most subspace steps of the rotation solver (two or three are typical).
    pub rotation_max_iter: usize,
    /// The rotation solver stops when no rotation changes by more than this, radians.
    pub rotation_tol_rad: f64,
    pub preconditioner: Preconditioner,
    /// Most iterations of each conjugate-gradient solve.
    pub cg_max_iter: usize,
    /// Relative residual |r| / |b| at which the translation solve stops.
    pub cg_tol: f64,
    /// Outlier when a normalised residual exceeds max(outlier_k * median, floor),
    /// the median taken at the first round (see [`robust`]).
    pub outlier_k: f64,
    /// Floors when residuals are judged in metres and degrees.
    pub outlier_floor_m: f64,
    pub outlier_floor_deg: f64,
    /// Judge residuals in units of each edge's standard errors when every edge has them.
    pub outlier_by_sigma: bool,
    /// Floor when residuals are judged in sigmas.
    pub outlier_floor_sigma: f64,
    /// Most reject-and-solve-again rounds.
    pub robust_max_rounds: usize,
}

impl Default for AveragingOptions {
    fn default() -> Self {
        AveragingOptions {
            gauge: Gauge::Mean,
            robust: true,
            rotation_max_iter: 20,
            rotation_tol_rad: 1e-9,
            preconditioner: Preconditioner::Multigrid,
            cg_max_iter: 20_000,
            cg_tol: 1e-12,
            outlier_k: 5.0,
            outlier_floor_m: 0.05,
            outlier_floor_deg: 0.005,
            outlier_by_sigma: true,
            outlier_floor_sigma: 4.0,
            robust_max_rounds: 10,
        }
    }
}

/// Disagreement of the averaged poses with one edge: M_i^-1 M_j against M_ij, the
/// translation part at the edge's centre.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeResidual {
    pub rotation_deg: f64,
    pub translation_m: f64,
    /// Rotation vector of R_ij^T (R_i^T R_j), radians, about the axes of j's frame
    /// (f32: for the outlier test only, and an edge list of 6 x 10^6 holds
    /// 0.14 GB less).
    pub rotation_rad: Vector3<f32>,
    /// M_i^-1 M_j c - M_ij c for the edge's centre c, in i's frame.
    pub offset_m: Vector3<f32>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AveragingTimings {
    /// Building the Laplacian and its preconditioner.
    pub setup_s: f64,
    pub rotation_s: f64,
    pub translation_s: f64,
    pub total_s: f64,
}

#[derive(Clone, Debug, PartialEq)]
pub struct AveragingResult {
    /// M_i in the frame of the edges, gauge fixed per component.
    pub poses: Vec<Matrix4<f64>>,
    /// One per edge of the graph (dropped edges included), against the final poses.
    pub edge_residuals: Vec<EdgeResidual>,
    /// Edges rejected as outliers (ascending).
    pub dropped_edges: Vec<usize>,
    /// Outlier edges kept at a lower weight because they hold a component together.
    pub downweighted_edges: Vec<usize>,
    /// Connected components (over edges of positive weight), each ascending.
    pub components: Vec<Vec<usize>>,
    /// Subspace steps of the rotation solver, summed over robust rounds.
    pub rotation_iterations: usize,
    /// Inner conjugate-gradient iterations of the rotation solver.
    pub rotation_cg_iterations: usize,
    /// Conjugate-gradient iterations of the translation solves.
    pub cg_iterations: usize,
    /// Solves done: 1 + robust rounds that changed something.
    pub solves: usize,
    /// Every solve met its tolerance.
    pub converged: bool,
    pub timings: AveragingTimings,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum AveragingError {
    #[error("pose graph: {0}")]
    Graph(#[from] GraphError),
    #[error("anchor node {anchor} out of range (graph has {n} nodes)")]
    AnchorOutOfRange { anchor: usize, n: usize },
    #[error("averaging options: {0}")]
    InvalidOptions(String),
}

/// Averages the poses of every connected component of `graph`.
pub fn average(
    graph: &PoseGraph,
    options: &AveragingOptions,
) -> Result<AveragingResult, AveragingError> {
    let started = Instant::now();
    graph.validate()?;
    check_options(graph, options)?;
    let _span =
        tracing::info_span!("averaging", nodes = graph.n, edges = graph.edges.len()).entered();
    let components = graph.components();
    let mut weights = Weights {
        rotation: graph.edges.iter().map(|e| e.weight).collect(),
        translation: graph
            .edges
            .iter()
            .map(|e| {
                if e.weight > 0.0 {
                    e.translation_weight
                } else {
                    0.0
                }
            })
            .collect(),
    };
    let mut solver = Solver::new(graph, &components, options);
    // Start from the rotations chained along a maximum-weight spanning forest: the
    // spectral solver is global on a well-connected graph, and on a nearly tree-like
    // one (where it cannot improve much) its cost guard keeps this start.
    let tree = max_spanning_forest(graph, |e| e.weight);
    let mut rotations: Vec<Matrix3<f64>> = match chain_poses(graph, &tree, 0) {
        Ok(poses) => poses.iter().map(rotation).collect(),
        Err(_) => vec![Matrix3::identity(); graph.n],
    };
    let mut translations = vec![Vector3::zeros(); graph.n];
    solver.solve(&weights, &mut rotations, &mut translations);
    let (mut dropped, mut downweighted) = (Vec::new(), Vec::new());
    let mut protected = vec![false; graph.edges.len()];
    let rule = OutlierRule {
        k: options.outlier_k,
        floor_m: options.outlier_floor_m,
        floor_deg: options.outlier_floor_deg,
        floor_sigma: options.outlier_floor_sigma,
        by_sigma: options.outlier_by_sigma,
    };
    // Residuals do not depend on the gauge: the last ones computed stay valid.
    let mut residuals = None;
    let mut test = None;
    for _ in 0..if options.robust {
        options.robust_max_rounds
    } else {
        0
    } {
        let current = residuals_of_parts(graph, |k| (rotations[k], translations[k]));
        let test =
            test.get_or_insert_with(|| OutlierTest::new(graph, &weights.rotation, &current, rule));
        let round = select_outliers(graph, &weights.rotation, &current, &protected, test, rule);
        residuals = Some(current);
        if round.dropped.is_empty() && round.downweighted.is_empty() {
            break;
        }
        residuals = None;
        tracing::info!(
            dropped = round.dropped.len(),
            downweighted = round.downweighted.len(),
            "outlier edges rejected"
        );
        for &k in &round.dropped {
            weights.rotation[k] = 0.0;
            weights.translation[k] = 0.0;
            dropped.push(k);
        }
        for &(k, factor) in &round.downweighted {
            weights.rotation[k] *= factor;
            weights.translation[k] *= factor;
            protected[k] = true;
            downweighted.push(k);
        }
        solver.solve(&weights, &mut rotations, &mut translations);
    }
    let mut poses = assemble(&rotations, &translations);
    drop((rotations, translations));
    for members in &components.members {
        let anchor = match options.gauge {
            Gauge::Anchor(k) if members.binary_search(&k).is_ok() => Some(k),
            _ => None,
        };
        fix_gauge(&mut poses, members, anchor);
    }
    dropped.sort_unstable();
    downweighted.sort_unstable();
    let mut timings = solver.timings;
    timings.total_s = started.elapsed().as_secs_f64();
    tracing::info!(
        solves = solver.solves,
        dropped = dropped.len(),
        rotation_s = timings.rotation_s,
        translation_s = timings.translation_s,
        "poses averaged"
    );
    let result = AveragingResult {
        edge_residuals: residuals.unwrap_or_else(|| edge_residuals(graph, &poses)),
        poses,
        dropped_edges: dropped,
        downweighted_edges: downweighted,
        components: Vec::new(),
        rotation_iterations: solver.rotation_iterations,
        rotation_cg_iterations: solver.rotation_cg_iterations,
        cg_iterations: solver.cg_iterations,
        solves: solver.solves,
        converged: solver.converged,
        timings,
    };
    Ok(AveragingResult {
        components: components.members,
        ..result
    })
}

fn check_options(graph: &PoseGraph, options: &AveragingOptions) -> Result<(), AveragingError> {
    if let Gauge::Anchor(anchor) = options.gauge {
        if anchor >= graph.n {
            return Err(AveragingError::AnchorOutOfRange { anchor, n: graph.n });
        }
    }
    let positive = [
        ("rotation_tol_rad", options.rotation_tol_rad),
        ("cg_tol", options.cg_tol),
        ("outlier_k", options.outlier_k),
        ("outlier_floor_m", options.outlier_floor_m),
        ("outlier_floor_deg", options.outlier_floor_deg),
        ("outlier_floor_sigma", options.outlier_floor_sigma),
    ];
    if let Some((name, value)) = positive.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        return Err(AveragingError::InvalidOptions(format!(
            "{name} must be a positive number, not {value}"
        )));
    }
    if options.rotation_max_iter == 0 || options.cg_max_iter == 0 {
        return Err(AveragingError::InvalidOptions(
            "iteration limits must be positive".into(),
        ));
    }
    Ok(())
}

/// The weighted Laplacian of the edges with a positive weight.
fn active_laplacian(graph: &PoseGraph, weights: &[f64]) -> Laplacian {
    let edges = graph
        .edges
        .iter()
        .zip(weights)
        .filter(|(_, &w)| w > 0.0)
        .map(|(e, &w)| (e.i as u32, e.j as u32, w))
        .collect();
    Laplacian::new(graph.n, edges)
}

/// The current per-edge weights of the two solves (0: edge inactive).
struct Weights {
    rotation: Vec<f64>,
    translation: Vec<f64>,
}

fn assemble(rotations: &[Matrix3<f64>], translations: &[Vector3<f64>]) -> Vec<Matrix4<f64>> {
    rotations
        .iter()
        .zip(translations)
        .map(|(r, t)| from_parts(r, t))
        .collect()
}

/// One rotation + translation solve, with counters across robust rounds.
struct Solver<'a> {
    graph: &'a PoseGraph,
    components: &'a Components,
    options: &'a AveragingOptions,
    rotation_iterations: usize,
    rotation_cg_iterations: usize,
    cg_iterations: usize,
    solves: usize,
    converged: bool,
    timings: AveragingTimings,
}

impl<'a> Solver<'a> {
    fn new(
        graph: &'a PoseGraph,
        components: &'a Components,
        options: &'a AveragingOptions,
    ) -> Self {
        Solver {
            graph,
            components,
            options,
            rotation_iterations: 0,
            rotation_cg_iterations: 0,
            cg_iterations: 0,
            solves: 0,
            converged: true,
            timings: AveragingTimings::default(),
        }
    }

    /// Refines `rotations` and `translations` (used as starting points) for `weights`.
    /// The translation solve has its own Laplacian (and preconditioner) when its
    /// weights are not those of the rotations.
    fn solve(
        &mut self,
        weights: &Weights,
        rotations: &mut Vec<Matrix3<f64>>,
        translations: &mut Vec<Vector3<f64>>,
    ) {
        let started = Instant::now();
        let coarsen = self.options.preconditioner == Preconditioner::Multigrid;
        let hierarchy = Multilevel::new(active_laplacian(self.graph, &weights.rotation), coarsen);
        let set_up = Instant::now();
        self.timings.setup_s += (set_up - started).as_secs_f64();
        let settings = RotationSettings {
            max_outer_iter: self.options.rotation_max_iter,
            tol_rad: self.options.rotation_tol_rad,
            cg_max_iter: self.options.cg_max_iter,
        };
        let solution = solve_rotations(
            self.graph,
            &weights.rotation,
            self.components,
            &hierarchy,
            std::mem::take(rotations),
            settings,
        );
        self.rotation_iterations += solution.iterations;
        self.rotation_cg_iterations += solution.cg_iterations;
        self.converged &= solution.converged;
        *rotations = solution.rotations;
        self.timings.rotation_s += set_up.elapsed().as_secs_f64();
        // Own translation weights: a hierarchy of their own, built only once the
        // rotations' is gone (two at once are 0.4 GB at 6 x 10^6 edges).
        let hierarchy = if weights.translation != weights.rotation {
            drop(hierarchy);
            let started = Instant::now();
            let own = Multilevel::new(active_laplacian(self.graph, &weights.translation), coarsen);
            self.timings.setup_s += started.elapsed().as_secs_f64();
            own
        } else {
            hierarchy
        };
        let rotated = Instant::now();
        let tolerance = CgTolerance {
            relative: self.options.cg_tol,
            absolute: 0.0,
            max_iter: self.options.cg_max_iter,
        };
        let start = std::mem::take(translations);
        let solution = solve_translations(
            self.graph,
            &weights.translation,
            self.components,
            rotations,
            &hierarchy,
            start,
            tolerance,
        );
        self.cg_iterations += solution.report.iterations;
        self.converged &= solution.report.converged;
        *translations = solution.translations;
        self.timings.translation_s += rotated.elapsed().as_secs_f64();
        self.solves += 1;
    }
}

#[cfg(test)]
mod tests;
