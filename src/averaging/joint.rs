//! Joint Gauss-Newton over rotations and translations together: one 6-vector
//! per node (a world-frame rotation w_k about the node's pivot p_k, then a shift
//! tau_k: y -> exp(w_k) (y - p_k) + p_k + tau_k), each edge's
//! 6x6 information, and the coupling the decoupled steps ([`super::block`])
//! leave out: an edge's translation residual is measured at its centre, so a
//! node's rotation moves the centres of all its edges by lever arms of tens of
//! metres. On a grid of small tiles that is most of what fixes a tile's yaw: a
//! strip of overlap gives a yaw of ~0.1 deg, while the cm-level shifts of its
//! four neighbours' edge centres, 50 m apart, give ~0.05 deg. Without it,
//! blocks of tiles keep rotation errors of a degree that no translation solve
//! can repair (measured on a 20 x 20 grid of 128 m tiles: docs/measurements.md).
//!
//! Edge (i, j) with relative pose Z (rotation Z_R), centre c (in j's frame),
//! y_j = M_j c and y_i = M_i Z c (the same point seen from both DSMs):
//! - rotation: r = log(Z_R^T R_i^T R_j) + R_j^T (w_j - w_i);
//! - translation (world): r = y_j - y_i + tau_j - tau_i - [y - p_j]x w_j
//!   + [y - p_i]x w_i, y the midpoint of y_i and y_j;
//!
//! with information Omega_rot and R_i Omega_t R_i^T (Omega_t about i's axes).
//!
//! The normal equations are solved by conjugate gradients with a block-Jacobi
//! preconditioner (each node's 6x6 block inverted); the decoupled solution is
//! the starting point, so few Gauss-Newton steps are needed.

use nalgebra::{Matrix3, Matrix6, Vector3, Vector6};

mod banded;
mod covariance;
use banded::{reverse_cuthill_mckee, Banded};
pub(crate) use covariance::joint_node_sigmas;

use super::cg::StepTolerance;
use super::direct::{solve_within_budget, BlockMatrix};
use super::robust::rotation_vector;
use crate::geo::rigid::rotation_from_axis_angle;
use crate::graph::PoseGraph;

/// One edge's linearisation: r = r0 + a_i x_i + a_j x_j, information `omega`.
struct JointEdge {
    i: usize,
    j: usize,
    a_i: Matrix6<f64>,
    a_j: Matrix6<f64>,
    omega: Matrix6<f64>,
    r0: Vector6<f64>,
}

/// The joint normal equations over `n` nodes.
struct JointSystem {
    n: usize,
    edges: Vec<JointEdge>,
    /// Added to each node's diagonal (rotation part, translation part).
    prior: (f64, f64),
    /// Node pivots (world), for the coarse space.
    pivots: Vec<Vector3<f64>>,
    /// The rotation prior's weight (rad^-2, 0: none) and each node's rotation
    /// vector: a pseudo-observation that each rotation is the identity.
    anchor: (f64, Vec<Vector3<f64>>),
}

/// The coarse space of the preconditioner: nodes grouped into aggregates of
/// neighbours (consecutive in the Morton order of their pivots), each moving
/// rigidly about its centre; the Galerkin operator P^T H P is factored as a
/// banded matrix ([`banded`]). It carries the smooth, long-range modes (a block
/// of tiles turning with its shifts) that the block-Jacobi part cannot.
struct Coarse {
    /// Aggregate of each node.
    of: Vec<usize>,
    /// Each aggregate's place in the banded coarse matrix.
    rank: Vec<usize>,
    centres: Vec<Vector3<f64>>,
    factor: Banded,
}

/// Nodes per aggregate at least this many ...
const MIN_AGGREGATE_NODES: usize = 8;
/// ... and aggregates at most the larger of this and [`AGGREGATES_PER_SQRT_NODE`]
/// x sqrt(nodes): the banded factorisation costs about aggregates^2 x 108 flops,
/// and each aggregate of a large graph holds sqrt(nodes) / 4 tiles.
const MAX_AGGREGATES: usize = 400;
const AGGREGATES_PER_SQRT_NODE: f64 = 4.0;

fn aggregate_count(n: usize) -> usize {
    let cap = MAX_AGGREGATES.max((AGGREGATES_PER_SQRT_NODE * (n as f64).sqrt()) as usize);
    (n / MIN_AGGREGATE_NODES).min(cap)
}

fn dot(a: &[Vector6<f64>], b: &[Vector6<f64>]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x.dot(y)).sum::<f64>()
}

/// What the Gauss-Newton steps did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct JointReport {
    pub cg_iterations: usize,
    /// Every CG solve reached its tolerance.
    pub converged: bool,
}

/// How [`joint_refine`] steps: `steps` Gauss-Newton steps, each solved to
/// `tolerance`, each node's rotation held near the identity (its
/// georeferencing) with one-sigma `rotation_prior_rad` per axis (infinite: free).
#[derive(Clone, Copy, Debug)]
pub(crate) struct JointSteps {
    pub steps: usize,
    pub tolerance: StepTolerance,
    pub rotation_prior_rad: f64,
}

/// Gauss-Newton steps on all poses at once ([`JointSteps`]), edges weighted
/// by `active` (0: left out). Poses change in place.
pub(crate) fn joint_refine(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    active: &[f64],
    rotations: &mut [Matrix3<f64>],
    translations: &mut [Vector3<f64>],
    settings: JointSteps,
) -> JointReport {
    let JointSteps {
        steps,
        tolerance,
        rotation_prior_rad,
    } = settings;
    let mut report = JointReport {
        cg_iterations: 0,
        converged: true,
    };
    for _ in 0..steps {
        let pivots = pivots(graph, active, rotations, translations);
        let mut system = linearise(graph, omegas, active, rotations, translations, &pivots);
        system.hold_rotations(rotations, rotation_prior_rad);
        let rhs = system.gradient();
        let (delta, iterations, converged) = system.solve(&rhs, tolerance);
        report.cg_iterations += iterations;
        tracing::debug!(
            nodes = graph.n,
            iterations,
            converged,
            "joint Gauss-Newton step"
        );
        report.converged &= converged;
        if !converged || !delta.iter().all(|d| d.iter().all(|v| v.is_finite())) {
            break;
        }
        for k in 0..graph.n {
            // World-frame motion about the pivot: y -> R_w (y - p) + p + tau.
            let turn = rotation_from_axis_angle(&delta[k].fixed_rows::<3>(0).into_owned());
            rotations[k] = turn * rotations[k];
            translations[k] =
                turn * (translations[k] - pivots[k]) + pivots[k] + delta[k].fixed_rows::<3>(3);
        }
    }
    report
}

/// Each node's pivot: the mean world position of its edges' centres (its own
/// side of each edge), so a node's rotation turns it about itself and the lever
/// arms in the Jacobians are tile-sized, not the size of the whole mosaic.
fn pivots(
    graph: &PoseGraph,
    active: &[f64],
    rotations: &[Matrix3<f64>],
    translations: &[Vector3<f64>],
) -> Vec<Vector3<f64>> {
    let mut sum = vec![(Vector3::zeros(), 0usize); graph.n];
    for (e, &a) in graph.edges.iter().zip(active) {
        if a <= 0.0 {
            continue;
        }
        let y_j = rotations[e.j] * e.centre_j + translations[e.j];
        let y_i = rotations[e.i] * e.apply(&e.centre_j) + translations[e.i];
        for (k, y) in [(e.i, y_i), (e.j, y_j)] {
            sum[k].0 += y;
            sum[k].1 += 1;
        }
    }
    sum.into_iter()
        .zip(translations)
        .map(|((s, c), t)| if c > 0 { s / c as f64 } else { *t })
        .collect()
}

fn linearise(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    active: &[f64],
    rotations: &[Matrix3<f64>],
    translations: &[Vector3<f64>],
    pivots: &[Vector3<f64>],
) -> JointSystem {
    let edges: Vec<JointEdge> = graph
        .edges
        .iter()
        .zip(omegas)
        .zip(active)
        .filter(|(_, &a)| a > 0.0)
        .map(|((e, o), &a)| {
            let (r_i, r_j) = (rotations[e.i], rotations[e.j]);
            let r_rel = r_i.tr_mul(&r_j);
            let y_j = r_j * e.centre_j + translations[e.j];
            let y_i = r_i * e.apply(&e.centre_j) + translations[e.i];
            let mut r0 = Vector6::zeros();
            r0.fixed_rows_mut::<3>(0)
                .copy_from(&rotation_vector(&e.rotation().tr_mul(&r_rel)));
            r0.fixed_rows_mut::<3>(3).copy_from(&(y_j - y_i));
            let mut a_i = Matrix6::zeros();
            let mut a_j = Matrix6::zeros();
            a_i.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(-r_j.transpose()));
            a_j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_j.transpose());
            // Lever arms to the midpoint of y_i and y_j, not to each: then a rigid
            // turn of the whole graph about any point changes no residual (with
            // y_i, y_j it would turn the residual vector itself, and the solve would
            // take that near-free motion as a step of degrees).
            let y = (y_i + y_j) / 2.0;
            a_i.fixed_view_mut::<3, 3>(3, 0)
                .copy_from(&(y - pivots[e.i]).cross_matrix());
            a_j.fixed_view_mut::<3, 3>(3, 0)
                .copy_from(&(-(y - pivots[e.j]).cross_matrix()));
            a_i.fixed_view_mut::<3, 3>(3, 3)
                .copy_from(&(-Matrix3::identity()));
            a_j.fixed_view_mut::<3, 3>(3, 3)
                .copy_from(&Matrix3::identity());
            let mut omega = Matrix6::zeros();
            omega
                .fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(o.fixed_view::<3, 3>(0, 0) * a));
            omega
                .fixed_view_mut::<3, 3>(3, 3)
                .copy_from(&(r_i * o.fixed_view::<3, 3>(3, 3) * r_i.transpose() * a));
            JointEdge {
                i: e.i,
                j: e.j,
                a_i,
                a_j,
                omega,
                r0,
            }
        })
        .collect();
    let mean = |at: usize| {
        edges
            .iter()
            .map(|e| (at..at + 3).map(|k| e.omega[(k, k)]).sum::<f64>() / 3.0)
            .sum::<f64>()
            / edges.len().max(1) as f64
    };
    // 1e-9 of the mean information: fixes the free motions of each component
    // without biasing the rest (the gauge is set afterwards).
    let prior = (
        (1e-9 * mean(0)).max(f64::MIN_POSITIVE),
        (1e-9 * mean(3)).max(f64::MIN_POSITIVE),
    );
    JointSystem {
        n: graph.n,
        edges,
        prior,
        pivots: pivots.to_vec(),
        anchor: (0.0, Vec::new()),
    }
}

/// P_k: node k's (rotation, shift) from its aggregate's rigid motion about `centre`.
fn prolongation(pivot: &Vector3<f64>, centre: &Vector3<f64>) -> Matrix6<f64> {
    let mut p = Matrix6::identity();
    p.fixed_view_mut::<3, 3>(3, 0)
        .copy_from(&(-(pivot - centre).cross_matrix()));
    p
}

/// Morton code of a point's (x, y) on a 2^16 grid over `lo..hi`.
fn morton(v: &Vector3<f64>, lo: &Vector3<f64>, hi: &Vector3<f64>) -> u64 {
    let cell = |k: usize| {
        let span = (hi[k] - lo[k]).max(1e-9);
        (((v[k] - lo[k]) / span * 65535.0).clamp(0.0, 65535.0)) as u64
    };
    let spread = |mut x: u64| {
        x &= 0xffff;
        x = (x | (x << 8)) & 0x00ff_00ff;
        x = (x | (x << 4)) & 0x0f0f_0f0f;
        x = (x | (x << 2)) & 0x3333_3333;
        (x | (x << 1)) & 0x5555_5555
    };
    spread(cell(0)) | (spread(cell(1)) << 1)
}

impl JointSystem {
    /// Adds the rotation prior (see [`joint_refine`]) at `rotations`; an
    /// infinite or non-positive sigma adds nothing.
    fn hold_rotations(&mut self, rotations: &[Matrix3<f64>], sigma_rad: f64) {
        if !(sigma_rad > 0.0 && sigma_rad.is_finite()) {
            return;
        }
        let weight = sigma_rad.powi(-2);
        self.prior.0 += weight;
        self.anchor = (weight, rotations.iter().map(rotation_vector).collect());
    }

    fn prior_of(&self) -> Vector6<f64> {
        let (r, t) = self.prior;
        Vector6::new(r, r, r, t, t, t)
    }

    /// out = H p.
    fn apply(&self, p: &[Vector6<f64>], out: &mut [Vector6<f64>]) {
        let prior = self.prior_of();
        for (o, pi) in out.iter_mut().zip(p) {
            *o = pi.component_mul(&prior);
        }
        for e in &self.edges {
            let w = e.omega * (e.a_i * p[e.i] + e.a_j * p[e.j]);
            out[e.i] += e.a_i.tr_mul(&w);
            out[e.j] += e.a_j.tr_mul(&w);
        }
    }

    /// -J^T Omega r0: the right-hand side of the Gauss-Newton step.
    fn gradient(&self) -> Vec<Vector6<f64>> {
        let mut out = vec![Vector6::zeros(); self.n];
        let (weight, held) = &self.anchor;
        for (o, w) in out.iter_mut().zip(held) {
            o.fixed_rows_mut::<3>(0).copy_from(&(-w * *weight));
        }
        for e in &self.edges {
            let w = e.omega * e.r0;
            out[e.i] -= e.a_i.tr_mul(&w);
            out[e.j] -= e.a_j.tr_mul(&w);
        }
        out
    }

    /// Each node's 6x6 diagonal block of H.
    fn diagonal_blocks(&self) -> Vec<Matrix6<f64>> {
        let mut blocks = vec![Matrix6::from_diagonal(&self.prior_of()); self.n];
        for e in &self.edges {
            blocks[e.i] += e.a_i.transpose() * e.omega * e.a_i;
            blocks[e.j] += e.a_j.transpose() * e.omega * e.a_j;
        }
        blocks
    }

    /// Each node's 6x6 diagonal block of H, inverted (identity when singular).
    fn block_jacobi(&self) -> Vec<Matrix6<f64>> {
        self.diagonal_blocks()
            .into_iter()
            .map(|b| {
                b.try_inverse()
                    .filter(|m| m.iter().all(|v| v.is_finite()))
                    .unwrap_or_else(Matrix6::identity)
            })
            .collect()
    }

    /// The coarse space, or None for tiny graphs or a failed factorisation.
    fn coarse(&self) -> Option<Coarse> {
        let aggregates = aggregate_count(self.n);
        if aggregates < 2 {
            return None;
        }
        let lo = self
            .pivots
            .iter()
            .fold(Vector3::repeat(f64::INFINITY), |a, p| a.inf(p));
        let hi = self
            .pivots
            .iter()
            .fold(Vector3::repeat(f64::NEG_INFINITY), |a, p| a.sup(p));
        let mut order: Vec<usize> = (0..self.n).collect();
        order.sort_by_key(|&k| (morton(&self.pivots[k], &lo, &hi), k));
        let mut of = vec![0; self.n];
        for (rank, &k) in order.iter().enumerate() {
            of[k] = rank * aggregates / self.n;
        }
        let mut centres = vec![(Vector3::zeros(), 0usize); aggregates];
        for (k, &a) in of.iter().enumerate() {
            centres[a].0 += self.pivots[k];
            centres[a].1 += 1;
        }
        let centres: Vec<Vector3<f64>> = centres
            .into_iter()
            .map(|(s, c)| s / c.max(1) as f64)
            .collect();
        let links: Vec<(usize, usize)> = self.edges.iter().map(|e| (of[e.i], of[e.j])).collect();
        let rank = reverse_cuthill_mckee(aggregates, &links);
        let band = links
            .iter()
            .map(|&(a, b)| rank[a].abs_diff(rank[b]))
            .max()
            .unwrap_or(0);
        let mut a = Banded::zeros(6 * aggregates, 6 * band + 5);
        // The lower triangle of each block: (r, c) and (c, r) are both added
        // for r != c, so each off-diagonal entry arrives once.
        let mut add = |r: usize, c: usize, block: &Matrix6<f64>| {
            let (r, c) = (6 * rank[r], 6 * rank[c]);
            for p in 0..6 {
                for q in 0..6 {
                    if r + p >= c + q {
                        a.add(r + p, c + q, block[(p, q)]);
                    }
                }
            }
        };
        let p = |k: usize| prolongation(&self.pivots[k], &centres[of[k]]);
        let prior = Matrix6::from_diagonal(&self.prior_of());
        for (k, &a) in of.iter().enumerate() {
            add(a, a, &(p(k).transpose() * prior * p(k)));
        }
        for e in &self.edges {
            let (b_i, b_j) = (e.a_i * p(e.i), e.a_j * p(e.j));
            let (oi, oj) = (e.omega * b_i, e.omega * b_j);
            add(of[e.i], of[e.i], &b_i.tr_mul(&oi));
            add(of[e.j], of[e.j], &b_j.tr_mul(&oj));
            add(of[e.i], of[e.j], &b_i.tr_mul(&oj));
            add(of[e.j], of[e.i], &b_j.tr_mul(&oi));
        }
        let factor = a.cholesky()?;
        Some(Coarse {
            of,
            rank,
            centres,
            factor,
        })
    }

    /// H x = rhs by a sparse block Cholesky factor when the graph allows
    /// ([`solve_within_budget`]).
    fn solve_direct(
        &self,
        rhs: &[Vector6<f64>],
        tolerance: StepTolerance,
    ) -> Option<Vec<Vector6<f64>>> {
        let off = self
            .edges
            .iter()
            .map(|e| (e.i, e.j, e.a_i.transpose() * e.omega * e.a_j));
        let apply = |p: &[Vector6<f64>], out: &mut [Vector6<f64>]| self.apply(p, out);
        let h = BlockMatrix {
            diagonal: self.diagonal_blocks(),
            off,
            apply: &apply,
        };
        solve_within_budget(h, rhs, tolerance)
    }

    /// Solves H x = rhs from zero to `tolerance`: (x, CG iterations, converged);
    /// directly when the graph allows ([`Self::solve_direct`]: 0 iterations).
    fn solve(
        &self,
        rhs: &[Vector6<f64>],
        tolerance: StepTolerance,
    ) -> (Vec<Vector6<f64>>, usize, bool) {
        match self.solve_direct(rhs, tolerance) {
            Some(x) => (x, 0, true),
            None => self.solve_cg(rhs, tolerance),
        }
    }

    /// Solves H x = rhs from zero to `tolerance` by preconditioned CG (block
    /// Jacobi plus the coarse space): (x, iterations, converged).
    fn solve_cg(
        &self,
        rhs: &[Vector6<f64>],
        tolerance: StepTolerance,
    ) -> (Vec<Vector6<f64>>, usize, bool) {
        let n = self.n;
        let mut x = vec![Vector6::zeros(); n];
        let mut r = rhs.to_vec();
        let b_norm = dot(&r, &r).sqrt();
        if b_norm == 0.0 {
            return (x, 0, true);
        }
        let inverse = self.block_jacobi();
        let coarse = self.coarse();
        // Additive two-level: block Jacobi plus the coarse correction P A_c^-1 P^T r.
        let mut rc = vec![0.0; coarse.as_ref().map_or(0, |c| 6 * c.centres.len())];
        let mut precondition = |r: &[Vector6<f64>], z: &mut [Vector6<f64>]| {
            for ((z, r), m) in z.iter_mut().zip(r).zip(&inverse) {
                *z = m * r;
            }
            if let Some(c) = &coarse {
                rc.iter_mut().for_each(|v| *v = 0.0);
                for ((pivot, &a), r) in self.pivots.iter().zip(&c.of).zip(r) {
                    let at = 6 * c.rank[a];
                    let v = prolongation(pivot, &c.centres[a]).tr_mul(r);
                    rc[at..at + 6].iter_mut().zip(&v).for_each(|(s, v)| *s += v);
                }
                c.factor.solve(&mut rc);
                for ((pivot, &a), z) in self.pivots.iter().zip(&c.of).zip(z.iter_mut()) {
                    let at = 6 * c.rank[a];
                    *z += prolongation(pivot, &c.centres[a])
                        * Vector6::from_column_slice(&rc[at..at + 6]);
                }
            }
        };
        let mut z = vec![Vector6::zeros(); n];
        precondition(&r, &mut z);
        let mut rz = dot(&r, &z);
        if tolerance.met(b_norm, b_norm, rz, 6 * n) {
            return (x, 0, true);
        }
        let mut p = z.clone();
        let mut q = vec![Vector6::zeros(); n];
        for iteration in 1..=tolerance.max_iter {
            self.apply(&p, &mut q);
            let pq = dot(&p, &q);
            if !(pq > 0.0 && pq.is_finite()) {
                return (x, iteration, false);
            }
            let alpha = rz / pq;
            for k in 0..n {
                x[k] += p[k] * alpha;
                r[k] -= q[k] * alpha;
            }
            precondition(&r, &mut z);
            let rz_new = dot(&r, &z);
            if tolerance.met(dot(&r, &r).sqrt(), b_norm, rz_new, 6 * n) {
                return (x, iteration, true);
            }
            let beta = rz_new / rz;
            rz = rz_new;
            for k in 0..n {
                p[k] = z[k] + p[k] * beta;
            }
        }
        (x, tolerance.max_iter, false)
    }
}

#[cfg(test)]
mod tests;
