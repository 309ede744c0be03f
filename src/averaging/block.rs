//! Pose-graph normal equations with a 3x3 information matrix per edge: the
//! residual of edge (i, j) is r = r0 + x_j - B x_i (B = I for translations in the
//! world frame, B = (R_i^T R_j)^T for right-perturbations of rotations), and
//! H x = -g, H = sum J^T Omega J, g = sum J^T Omega r0. Solved by one coupled
//! conjugate gradient over all 3n unknowns, preconditioned by the scalar multigrid
//! V-cycle ([`super::multilevel`]) of the Laplacian weighted by trace(Omega) / 3
//! (applied to each coordinate): exact when every Omega is isotropic, and a fair
//! approximation when they are not. Memory: about 180 bytes per edge.

use super::cg::StepTolerance;
use super::direct::{solve_within_budget, BlockMatrix};
use super::laplacian::Laplacian;
use super::multilevel::Multilevel;
use nalgebra::{Matrix3, Vector3};

/// One edge's block: residual r0 + x_j - b x_i with information `omega`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BlockEdge {
    pub i: usize,
    pub j: usize,
    pub b: Matrix3<f64>,
    pub omega: Matrix3<f64>,
    pub r0: Vector3<f64>,
}

/// The normal equations of a set of block edges over `n` nodes.
pub(crate) struct BlockSystem {
    pub n: usize,
    pub edges: Vec<BlockEdge>,
    /// Added to every node's diagonal block (times I): fixes the free motions of
    /// the graph (set to a tiny fraction of the typical information).
    pub prior: f64,
}

/// What a solve did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct BlockReport {
    pub iterations: usize,
    pub converged: bool,
}

impl BlockSystem {
    /// out = H p.
    pub fn apply(&self, p: &[Vector3<f64>], out: &mut [Vector3<f64>]) {
        for (o, pi) in out.iter_mut().zip(p) {
            *o = pi * self.prior;
        }
        for e in &self.edges {
            let v = e.omega * (p[e.j] - e.b * p[e.i]);
            out[e.j] += v;
            out[e.i] -= e.b.tr_mul(&v);
        }
    }

    /// J^T Omega u summed over edges, for per-edge vectors u (u = r0: the gradient).
    pub fn gather(
        &self,
        per_edge: impl Fn(usize, &BlockEdge) -> Vector3<f64>,
    ) -> Vec<Vector3<f64>> {
        let mut out = vec![Vector3::zeros(); self.n];
        for (k, e) in self.edges.iter().enumerate() {
            let v = per_edge(k, e);
            out[e.j] += v;
            out[e.i] -= e.b.tr_mul(&v);
        }
        out
    }

    /// The scalar multigrid preconditioner of this system.
    pub fn preconditioner(&self) -> Multilevel {
        let edges = self
            .edges
            .iter()
            .map(|e| {
                (
                    e.i as u32,
                    e.j as u32,
                    (e.omega.trace() / 3.0).max(f64::MIN_POSITIVE),
                )
            })
            .collect();
        Multilevel::new(Laplacian::new(self.n, edges), true)
    }

    /// Solves H x = rhs to `tolerance`: directly when the graph allows
    /// ([`solve_within_budget`]: 0 iterations), else by CG from `start` with
    /// the multigrid preconditioner.
    pub fn solve_auto(
        &self,
        rhs: &[Vector3<f64>],
        start: Option<&[Vector3<f64>]>,
        tolerance: StepTolerance,
    ) -> (Vec<Vector3<f64>>, BlockReport) {
        let mut diagonal = vec![Matrix3::identity() * self.prior; self.n];
        for e in &self.edges {
            diagonal[e.i] += e.b.transpose() * e.omega * e.b;
            diagonal[e.j] += e.omega;
        }
        // r = r0 + x_j - B x_i: H_ij = -B^T Omega.
        let off = self
            .edges
            .iter()
            .map(|e| (e.i, e.j, -(e.b.transpose() * e.omega)));
        let apply = |p: &[Vector3<f64>], out: &mut [Vector3<f64>]| self.apply(p, out);
        let h = BlockMatrix {
            diagonal,
            off,
            apply: &apply,
        };
        if let Some(x) = solve_within_budget(h, rhs, tolerance) {
            let report = BlockReport {
                iterations: 0,
                converged: true,
            };
            return (x, report);
        }
        self.solve(&self.preconditioner(), rhs, start, tolerance)
    }

    /// Solves H x = rhs from `start` (zero if None) to `tolerance`.
    pub fn solve(
        &self,
        hierarchy: &Multilevel,
        rhs: &[Vector3<f64>],
        start: Option<&[Vector3<f64>]>,
        tolerance: StepTolerance,
    ) -> (Vec<Vector3<f64>>, BlockReport) {
        let n = self.n;
        let dot = |a: &[Vector3<f64>], b: &[Vector3<f64>]| {
            a.iter().zip(b).map(|(x, y)| x.dot(y)).sum::<f64>()
        };
        let mut work = hierarchy.workspace::<Vector3<f64>>();
        let mut x = start.map_or_else(|| vec![Vector3::zeros(); n], <[_]>::to_vec);
        let mut r = rhs.to_vec();
        let mut q = vec![Vector3::zeros(); n];
        if start.is_some() {
            self.apply(&x, &mut q);
            r.iter_mut().zip(&q).for_each(|(r, q)| *r -= q);
        }
        let b_norm = dot(rhs, rhs).sqrt();
        let report = |iterations, converged| BlockReport {
            iterations,
            converged,
        };
        if b_norm == 0.0 {
            return (vec![Vector3::zeros(); n], report(0, true));
        }
        let mut z = vec![Vector3::zeros(); n];
        // The multigrid can break down on information spanning ten orders of
        // magnitude (a weak edge at 1 % of a weak fit beside strong ones); then
        // plain CG, slower but finite.
        // (r^T r is no energy: the chi^2 rule then stays off.)
        let mut tolerance = tolerance;
        let precondition = |r: &[Vector3<f64>], z: &mut [Vector3<f64>], work: &mut _| {
            hierarchy.apply(&|k| r[k], z, work);
            let finite = z.iter().all(|v| v.iter().all(|c| c.is_finite()));
            if !finite {
                z.copy_from_slice(r);
            }
            finite
        };
        if !precondition(&r, &mut z, &mut work) {
            tolerance.chi2_per_unknown = 0.0;
        }
        let mut rz = dot(&r, &z);
        if tolerance.met(dot(&r, &r).sqrt(), b_norm, rz, 3 * n) {
            return (x, report(0, true));
        }
        let mut p = z.clone();
        for iteration in 1..=tolerance.max_iter {
            self.apply(&p, &mut q);
            let pq = dot(&p, &q);
            if !(pq > 0.0 && pq.is_finite()) {
                return (x, report(iteration, false));
            }
            let alpha = rz / pq;
            for k in 0..n {
                x[k] += p[k] * alpha;
                r[k] -= q[k] * alpha;
            }
            if !precondition(&r, &mut z, &mut work) {
                tolerance.chi2_per_unknown = 0.0;
            }
            let rz_new = dot(&r, &z);
            if tolerance.met(dot(&r, &r).sqrt(), b_norm, rz_new, 3 * n) {
                return (x, report(iteration, true));
            }
            let beta = rz_new / rz;
            rz = rz_new;
            for k in 0..n {
                p[k] = z[k] + p[k] * beta;
            }
        }
        (x, report(tolerance.max_iter, false))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anisotropic_chain_is_solved_exactly() {
        // 0 - 1 - 2 - 0 triangle with anisotropic information; compare to a dense solve.
        let omega = |a: f64, b: f64, c: f64| Matrix3::from_diagonal(&Vector3::new(a, b, c));
        let edges = vec![
            BlockEdge {
                i: 0,
                j: 1,
                b: Matrix3::identity(),
                omega: omega(1.0, 1e-3, 10.0),
                r0: Vector3::new(1.0, 2.0, 3.0),
            },
            BlockEdge {
                i: 1,
                j: 2,
                b: Matrix3::identity(),
                omega: omega(1e-3, 1.0, 10.0),
                r0: Vector3::new(-1.0, 0.5, 0.0),
            },
            BlockEdge {
                i: 2,
                j: 0,
                b: Matrix3::identity(),
                omega: omega(1.0, 1.0, 1.0),
                r0: Vector3::new(0.2, 0.1, -0.3),
            },
        ];
        let system = BlockSystem {
            n: 3,
            edges,
            prior: 1e-6,
        };
        let rhs = system.gather(|_, e| -(e.omega * e.r0));
        let tolerance = StepTolerance {
            relative: 1e-13,
            chi2_per_unknown: 0.0,
            max_iter: 200,
        };
        let (x, report) = system.solve(&system.preconditioner(), &rhs, None, tolerance);
        assert!(report.converged);
        let mut dense = nalgebra::DMatrix::<f64>::zeros(9, 9);
        for c in 0..9 {
            let mut unit = vec![Vector3::zeros(); 3];
            unit[c / 3][c % 3] = 1.0;
            let mut out = vec![Vector3::zeros(); 3];
            system.apply(&unit, &mut out);
            for r in 0..9 {
                dense[(r, c)] = out[r / 3][r % 3];
            }
        }
        let b = nalgebra::DVector::from_fn(9, |r, _| rhs[r / 3][r % 3]);
        let exact = dense.lu().solve(&b).unwrap();
        for r in 0..9 {
            assert!(
                (x[r / 3][r % 3] - exact[r]).abs() < 1e-6 * exact.amax(),
                "{r}"
            );
        }
    }
}
