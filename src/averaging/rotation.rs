//! Rotation averaging, spectral form (paper step 4, after Arie-Nachimson et al.).
//!
//! With Y = [R_1^T; ...; R_N^T] (3N x 3), the measurements R_ij = R_i^T R_j give
//! sum_j w_ij R_ij R_j^T = d_i R_i^T, d_i = sum_j w_ij: Y spans the top eigenvectors of
//! G y = mu D y, where G (3N x 3N, never formed) has blocks w_ij R_ij at (i, j) and
//! w_ij R_ij^T at (j, i), and D = diag(d_i I). We use this degree-normalised form (the
//! spectrum of D^-1 G lies in [-1, 1] whatever the degrees) and compute the bottom
//! three eigenvectors of the connection Laplacian L = D - G, L y = lambda D y.
//!
//! Solver: subspace iteration in the D-inner product, each step the Jacobi-Davidson
//! correction with zero shift: solve (P^T L P) E = -P^T L X for E D-orthogonal to
//! X, P = I - X X^T D / S, by conjugate gradient; then X <- X + E, D-orthonormalised.
//! Preconditioner: in the basis u_i = X_i^T p_i the operator is nearly the scalar
//! weighted Laplacian, so M^-1 = P X B X^T with B its Jacobi step or multigrid
//! V-cycle ([`super::multilevel`]); this holds for rotations of any size. With an exact inner solve this
//! is inverse iteration, converging by lambda_3 / lambda_4 (noise level over the
//! spectral gap) per step, so two or three steps suffice; the projected system is
//! well conditioned because the near-null space X is removed. Each CG iteration is
//! one pass over the edges: O(edges) time, O(nodes) memory.
//!
//! X is scaled so that X^T D X = S I per component (S = sum of d_i), which makes each
//! 3x3 block close to a rotation; a block projected onto SO(3) (SVD, det guard) and
//! transposed is R_i up to one global rotation per component (the gauge, fixed later).
//! All components are solved together: the operator is block diagonal over them and
//! the projections and normalisations act per component.
//!
//! Guard: on a sparse, nearly tree-like component (a percolating grid of small tiles:
//! 9824 nodes on 14,226 edges) the spectral gap vanishes, the inner solves stop at their
//! limit and a step can turn weakly held branches by radians. Each step is therefore
//! kept only if it lowers the chordal cost sum_ij w_ij |R_i R_ij - R_j|^2 of the
//! rotations it gives; the first that does not ends the solve with the best so far
//! (start from a spanning-tree chain, which such a step cannot spoil).

use super::cg::{pcg, prefetch, CgTolerance};
use super::multilevel::Multilevel;
use crate::graph::{Components, PoseGraph};
use crate::poses::rigid::project_to_so3;
use nalgebra::{Matrix3, SymmetricEigen};

/// Edges looked ahead when prefetching the randomly accessed blocks.
const PREFETCH_DISTANCE: usize = 16;

/// Relative residual of each inner CG solve (the outer loop checks the result).
const INNER_RELATIVE_TOL: f64 = 1e-8;

/// Most iterations of one inner CG solve, whatever the settings allow: a well-posed
/// graph needs tens (37 a step on a 10^5-node grid); thousands mean the spectral gap
/// is gone, and the cost guard judges the truncated step.
const INNER_MAX_ITER: usize = 1000;

#[derive(Clone, Copy, Debug)]
pub(crate) struct RotationSettings {
    pub max_outer_iter: usize,
    /// Stop when no block of X changes by more than this (radians, Frobenius norm).
    pub tol_rad: f64,
    pub cg_max_iter: usize,
}

#[derive(Clone, Debug)]
pub(crate) struct RotationSolution {
    /// R_i up to one global rotation per component; identity for isolated nodes.
    pub rotations: Vec<Matrix3<f64>>,
    pub iterations: usize,
    pub cg_iterations: usize,
    pub converged: bool,
}

/// The connection Laplacian of the active edges (weight > 0) and its projections.
struct ConnectionLaplacian<'a> {
    graph: &'a PoseGraph,
    weights: &'a [f64],
    component_of: &'a [usize],
    degree: Vec<f64>,
    component_degree: Vec<f64>,
}

impl<'a> ConnectionLaplacian<'a> {
    fn new(graph: &'a PoseGraph, weights: &'a [f64], components: &'a Components) -> Self {
        let mut degree = vec![0.0; graph.n];
        for (e, &w) in graph.edges.iter().zip(weights) {
            degree[e.i] += w;
            degree[e.j] += w;
        }
        let mut component_degree = vec![0.0; components.members.len()];
        for (node, &d) in degree.iter().enumerate() {
            component_degree[components.component_of[node]] += d;
        }
        ConnectionLaplacian {
            graph,
            weights,
            component_of: &components.component_of,
            degree,
            component_degree,
        }
    }

    /// out = L p = D p - G p.
    fn apply(&self, p: &[Matrix3<f64>], out: &mut [Matrix3<f64>]) {
        for ((o, pi), &d) in out.iter_mut().zip(p).zip(&self.degree) {
            *o = pi * d;
        }
        let edges = &self.graph.edges;
        for (k, (e, &w)) in edges.iter().zip(self.weights).enumerate() {
            if let Some(ahead) = edges.get(k + PREFETCH_DISTANCE) {
                prefetch(p, ahead.j);
                prefetch(out, ahead.j);
            }
            if w > 0.0 {
                let r = e.rotation();
                out[e.i] -= (r * p[e.j]) * w;
                out[e.j] -= (r.tr_mul(&p[e.i])) * w;
            }
        }
    }

    /// Per component: sum_i X_i^T v_i (times d_i when `by_degree`).
    fn component_sums(
        &self,
        x: &[Matrix3<f64>],
        v: &[Matrix3<f64>],
        by_degree: bool,
    ) -> Vec<Matrix3<f64>> {
        let mut sums = vec![Matrix3::zeros(); self.component_degree.len()];
        for (node, (xi, vi)) in x.iter().zip(v).enumerate() {
            let d = if by_degree { self.degree[node] } else { 1.0 };
            sums[self.component_of[node]] += xi.tr_mul(vi) * d;
        }
        sums
    }

    /// v <- P v = v - X (X^T D v) / S: removes the D-component along X.
    fn project(&self, x: &[Matrix3<f64>], v: &mut [Matrix3<f64>]) {
        let sums = self.component_sums(x, v, true);
        for (node, (xi, vi)) in x.iter().zip(v.iter_mut()).enumerate() {
            let c = self.component_of[node];
            if self.component_degree[c] > 0.0 {
                *vi -= xi * sums[c] / self.component_degree[c];
            }
        }
    }

    /// y <- P^T y = y - D X (X^T y) / S.
    fn project_transpose(&self, x: &[Matrix3<f64>], y: &mut [Matrix3<f64>]) {
        let sums = self.component_sums(x, y, false);
        for (node, (xi, yi)) in x.iter().zip(y.iter_mut()).enumerate() {
            let c = self.component_of[node];
            if self.component_degree[c] > 0.0 {
                *yi -= xi * sums[c] * (self.degree[node] / self.component_degree[c]);
            }
        }
    }

    /// X <- X (X^T D X / S)^-1/2 per component, so X^T D X = S I; isolated nodes get I.
    fn normalise(&self, x: &mut [Matrix3<f64>]) {
        let gram = self.component_sums(x, x, true);
        let factors: Vec<Matrix3<f64>> = gram
            .iter()
            .zip(&self.component_degree)
            .map(|(g, &s)| {
                if s > 0.0 {
                    inverse_sqrt(&(g / s))
                } else {
                    Matrix3::identity()
                }
            })
            .collect();
        for (node, xi) in x.iter_mut().enumerate() {
            let c = self.component_of[node];
            *xi = if self.component_degree[c] > 0.0 {
                *xi * factors[c]
            } else {
                Matrix3::identity()
            };
        }
    }
}

/// The inverse square root of a symmetric positive definite 3x3 matrix.
fn inverse_sqrt(m: &Matrix3<f64>) -> Matrix3<f64> {
    let eigen = SymmetricEigen::new(*m);
    let inv_sqrt = eigen
        .eigenvalues
        .map(|v| 1.0 / v.max(f64::MIN_POSITIVE).sqrt());
    eigen.eigenvectors * Matrix3::from_diagonal(&inv_sqrt) * eigen.eigenvectors.transpose()
}

/// Averages the rotations of every component, starting from `initial` (R_i estimates,
/// e.g. chained along a spanning tree, or the previous solution).
pub(crate) fn solve_rotations(
    graph: &PoseGraph,
    weights: &[f64],
    components: &Components,
    hierarchy: &Multilevel,
    initial: Vec<Matrix3<f64>>,
    settings: RotationSettings,
) -> RotationSolution {
    let laplacian = ConnectionLaplacian::new(graph, weights, components);
    let mut x = initial;
    x.iter_mut().for_each(|r| r.transpose_mut());
    laplacian.normalise(&mut x);
    // Residuals below this are round-off of a consistent X (columns of D X have this norm).
    let absolute = 1e-14 * laplacian.degree.iter().map(|d| d * d).sum::<f64>().sqrt();
    let tolerance = CgTolerance {
        relative: INNER_RELATIVE_TOL,
        absolute,
        max_iter: settings.cg_max_iter.min(INNER_MAX_ITER),
    };
    let mut best = extract_rotations(&laplacian, x.clone());
    let mut best_cost = chordal_cost(graph, weights, &best);
    // Cost rises below this are round-off, not a spoiled step.
    let round_off = |cost: f64| 1e-9 * cost + 1e-24 * weights.iter().sum::<f64>();
    let (mut iterations, mut cg_iterations, mut converged) = (0, 0, false);
    let mut work = hierarchy.workspace();
    while iterations < settings.max_outer_iter && !converged {
        iterations += 1;
        let mut rhs = vec![Matrix3::zeros(); graph.n];
        laplacian.apply(&x, &mut rhs);
        laplacian.project_transpose(&x, &mut rhs);
        rhs.iter_mut().for_each(|b| *b = -*b);
        let mut correction = vec![Matrix3::zeros(); graph.n];
        let apply = |p: &[Matrix3<f64>], out: &mut [Matrix3<f64>]| {
            laplacian.apply(p, out);
            laplacian.project_transpose(&x, out);
        };
        // In the basis u_i = X_i^T p_i the connection Laplacian is close to the scalar
        // Laplacian (X_i^T R_ij X_j ~ I), so M^-1 = P X B X^T with B the scalar
        // preconditioner (Jacobi or multigrid) applied to every entry.
        let precondition = |r: &[Matrix3<f64>], out: &mut [Matrix3<f64>]| {
            hierarchy.apply(&|k| x[k].tr_mul(&r[k]), out, &mut work);
            for (o, xi) in out.iter_mut().zip(&x) {
                *o = xi * *o;
            }
            laplacian.project(&x, out);
        };
        let report = pcg(apply, precondition, rhs, &mut correction, tolerance);
        cg_iterations += report.iterations;
        let change_rad = correction.iter().map(|e| e.norm()).fold(0.0, f64::max);
        for (xi, e) in x.iter_mut().zip(&correction) {
            *xi += e;
        }
        laplacian.normalise(&mut x);
        let rotations = extract_rotations(&laplacian, x.clone());
        let cost = chordal_cost(graph, weights, &rotations);
        tracing::debug!(
            iterations,
            cg = report.iterations,
            change_rad,
            cost,
            "rotation step solved"
        );
        if cost > best_cost + round_off(best_cost) {
            tracing::debug!(best_cost, cost, "rotation step rejected: the cost rose");
            break;
        }
        converged = change_rad <= settings.tol_rad;
        (best, best_cost) = (rotations, cost.min(best_cost));
    }
    RotationSolution {
        rotations: best,
        iterations,
        cg_iterations,
        converged,
    }
}

/// sum over active edges of w_ij |R_i R_ij - R_j|_F^2, R_ij = R_i^T R_j measured.
fn chordal_cost(graph: &PoseGraph, weights: &[f64], rotations: &[Matrix3<f64>]) -> f64 {
    graph
        .edges
        .iter()
        .zip(weights)
        .filter(|(_, &w)| w > 0.0)
        .map(|(e, &w)| w * (rotations[e.i] * e.rotation() - rotations[e.j]).norm_squared())
        .sum()
}

/// R_i = proj_SO(3)(X_i^T), after choosing each component's sign so that det > 0 on
/// the whole (an eigen-subspace basis may come out as a reflection).
fn extract_rotations(
    laplacian: &ConnectionLaplacian,
    mut x: Vec<Matrix3<f64>>,
) -> Vec<Matrix3<f64>> {
    let mut det_sum = vec![0.0; laplacian.component_degree.len()];
    for (node, xi) in x.iter().enumerate() {
        det_sum[laplacian.component_of[node]] += laplacian.degree[node] * xi.determinant();
    }
    for (node, xi) in x.iter_mut().enumerate() {
        let sign = if det_sum[laplacian.component_of[node]] < 0.0 {
            -1.0
        } else {
            1.0
        };
        *xi = project_to_so3(&(xi.transpose() * sign));
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::averaging::active_laplacian;
    use crate::averaging::synthetic::{generate, SyntheticSpec, Topology};
    use crate::poses::rigid::{rotation, rotation_between_deg};

    fn settings() -> RotationSettings {
        RotationSettings {
            max_outer_iter: 20,
            tol_rad: 1e-12,
            cg_max_iter: 1000,
        }
    }

    /// Largest angle between estimated and true relative rotations over all node pairs
    /// to node 0 (gauge free).
    fn worst_relative_error_deg(estimate: &[Matrix3<f64>], truth: &[Matrix3<f64>]) -> f64 {
        (1..truth.len())
            .map(|k| {
                let est = estimate[0].transpose() * estimate[k];
                let tru = truth[0].transpose() * truth[k];
                rotation_between_deg(&est, &tru)
            })
            .fold(0.0, f64::max)
    }

    fn solve(
        synthetic: &crate::averaging::synthetic::SyntheticGraph,
        multigrid: bool,
    ) -> RotationSolution {
        let weights: Vec<f64> = synthetic.graph.edges.iter().map(|e| e.weight).collect();
        let components = synthetic.graph.components();
        let hierarchy = Multilevel::new(active_laplacian(&synthetic.graph, &weights), multigrid);
        let start = vec![Matrix3::identity(); synthetic.graph.n];
        solve_rotations(
            &synthetic.graph,
            &weights,
            &components,
            &hierarchy,
            start,
            settings(),
        )
    }

    #[test]
    fn recovers_large_rotations_from_an_identity_start() {
        // Rotations of tens of degrees, identity start: the spectral method is global,
        // and the preconditioners work in the rotated basis.
        let cases = [
            (300, Topology::Random { edges_per_node: 6 }, false),
            (2000, Topology::Grid { width: 50 }, true),
            (2000, Topology::Grid { width: 50 }, false),
        ];
        for (nodes, topology, multigrid) in cases {
            let spec = SyntheticSpec {
                rotation_spread_deg: 30.0,
                ..SyntheticSpec::exact(nodes, topology, 3)
            };
            let synthetic = generate(&spec);
            let solution = solve(&synthetic, multigrid);
            let truth: Vec<_> = synthetic.truth.iter().map(rotation).collect();
            assert!(solution.converged, "{topology:?} {multigrid}: {solution:?}");
            let err = worst_relative_error_deg(&solution.rotations, &truth);
            assert!(err < 1e-9, "{topology:?} {multigrid}: {err}");
        }
    }

    /// A grid with most edges gone (the percolating graph of small tiles whose pairs
    /// mostly fail) and weights spread over 10^4: the spectral gap is nearly nil. The
    /// solve must not turn branches away from the chained start: its rotations are no
    /// costlier and no farther from the truth than the start's.
    #[test]
    fn a_nearly_tree_like_graph_keeps_its_chained_start_or_improves_it() {
        use crate::graph::{chain_poses, max_spanning_forest};
        use crate::rng::SplitMix64;
        let spec = SyntheticSpec {
            noise_scale_spread: 30.0,
            ..SyntheticSpec::noisy(3600, Topology::Grid { width: 60 }, 11, 0.01, 0.02)
        };
        let mut synthetic = generate(&spec);
        let mut rng = SplitMix64::new(5);
        for e in &mut synthetic.graph.edges {
            e.weight = if rng.next_f64() < 0.6 {
                0.0
            } else {
                10f64.powf(4.0 * rng.next_f64() - 2.0)
            };
            // 3 % gross outliers of 5-30 degrees, as the robust rounds first see them
            if rng.next_f64() < 0.03 {
                let axis = nalgebra::Vector3::new(rng.next_f64(), rng.next_f64(), 1.0).normalize();
                let angle = (5.0 + 25.0 * rng.next_f64()).to_radians();
                e.q_ij *= nalgebra::UnitQuaternion::from_scaled_axis(axis * angle);
            }
        }
        let graph = &synthetic.graph;
        let weights: Vec<f64> = graph.edges.iter().map(|e| e.weight).collect();
        let components = graph.components();
        let hierarchy = Multilevel::new(active_laplacian(graph, &weights), true);
        let tree = max_spanning_forest(graph, |e| e.weight);
        let start: Vec<Matrix3<f64>> = chain_poses(graph, &tree, 0)
            .unwrap()
            .iter()
            .map(rotation)
            .collect();
        let solution = solve_rotations(
            graph,
            &weights,
            &components,
            &hierarchy,
            start.clone(),
            RotationSettings {
                max_outer_iter: 20,
                tol_rad: 1e-9,
                cg_max_iter: 20_000,
            },
        );
        let (before, after) = (
            chordal_cost(graph, &weights, &start),
            chordal_cost(graph, &weights, &solution.rotations),
        );
        assert!(after <= before * (1.0 + 1e-9), "{after} > {before}");
        // Within each component, relative to its first node.
        let worst = |r: &[Matrix3<f64>]| {
            components
                .members
                .iter()
                .flat_map(|m| m.iter().map(move |&k| (m[0], k)))
                .map(|(a, k)| {
                    let est = r[a].transpose() * r[k];
                    let tru =
                        rotation(&synthetic.truth[a]).transpose() * rotation(&synthetic.truth[k]);
                    rotation_between_deg(&est, &tru)
                })
                .fold(0.0, f64::max)
        };
        let (w_start, w_after) = (worst(&start), worst(&solution.rotations));
        assert!(
            w_after <= w_start * 1.01 + 1e-6,
            "{w_after} deg vs start {w_start} deg"
        );
        // Without the guard: 20 steps, 16,121 CG iterations; with it 3 and 911.
        assert!(
            solution.iterations <= 5,
            "{} steps, {} CG",
            solution.iterations,
            solution.cg_iterations
        );
    }

    #[test]
    fn the_gauge_is_one_rotation_and_proper() {
        let synthetic = generate(&SyntheticSpec::exact(50, Topology::Grid { width: 10 }, 4));
        let solution = solve(&synthetic, true);
        let global = solution.rotations[0] * rotation(&synthetic.truth[0]).transpose();
        for (est, tru) in solution.rotations.iter().zip(&synthetic.truth) {
            assert!((est.determinant() - 1.0).abs() < 1e-12);
            assert!((global * rotation(tru) - est).abs().max() < 1e-10);
        }
    }
}
