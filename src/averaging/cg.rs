//! Preconditioned conjugate gradient on block vectors with three independent lanes:
//! the three coordinates of a translation (`Vector3`) or the three columns of a 3x3
//! block (`Matrix3`). Each lane is its own CG (own step sizes) sharing one operator
//! application per iteration, so one pass over the edges serves all three.
//! Works for singular but consistent systems (graph Laplacians).

use nalgebra::{Matrix3, Vector3};

/// Asks the CPU to start loading `slice[index]` (both ends, so a block straddling two
/// cache lines is covered): the edge loops are bound by random access latency.
/// A no-op off x86_64 or out of bounds.
#[inline(always)]
pub(crate) fn prefetch<T>(slice: &[T], index: usize) {
    #[cfg(target_arch = "x86_64")]
    if let Some(item) = slice.get(index) {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let first = (item as *const T).cast::<i8>();
        let last = first.wrapping_add(std::mem::size_of::<T>().saturating_sub(1));
        // SAFETY: SSE is part of the x86_64 baseline, and a prefetch never faults;
        // both addresses lie inside `item` anyway.
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(first);
            _mm_prefetch::<_MM_HINT_T0>(last);
        }
    }
}

/// A node's block: three lanes of CG state.
pub(crate) trait Lanes: Copy {
    fn zero() -> Self;
    /// Per-lane dot products.
    fn lane_dot(&self, other: &Self) -> [f64; 3];
    /// self += x * diag(s).
    fn add_scaled(&mut self, s: [f64; 3], x: &Self);
    /// self = x + self * diag(s).
    fn scale_then_add(&mut self, s: [f64; 3], x: &Self);
    /// self += s * x (every entry).
    fn axpy(&mut self, s: f64, x: &Self);
    /// The entries, column-major.
    fn entries(&self) -> &[f64];
    fn entries_mut(&mut self) -> &mut [f64];
}

impl Lanes for Vector3<f64> {
    fn zero() -> Self {
        Vector3::zeros()
    }
    fn lane_dot(&self, other: &Self) -> [f64; 3] {
        [self.x * other.x, self.y * other.y, self.z * other.z]
    }
    fn add_scaled(&mut self, s: [f64; 3], x: &Self) {
        *self += x.component_mul(&Vector3::from(s));
    }
    fn scale_then_add(&mut self, s: [f64; 3], x: &Self) {
        *self = x + self.component_mul(&Vector3::from(s));
    }
    fn axpy(&mut self, s: f64, x: &Self) {
        *self += x * s;
    }
    fn entries(&self) -> &[f64] {
        self.as_slice()
    }
    fn entries_mut(&mut self) -> &mut [f64] {
        self.as_mut_slice()
    }
}

impl Lanes for Matrix3<f64> {
    fn zero() -> Self {
        Matrix3::zeros()
    }
    fn lane_dot(&self, other: &Self) -> [f64; 3] {
        [0, 1, 2].map(|c| self.column(c).dot(&other.column(c)))
    }
    fn add_scaled(&mut self, s: [f64; 3], x: &Self) {
        *self += x * Matrix3::from_diagonal(&Vector3::from(s));
    }
    fn scale_then_add(&mut self, s: [f64; 3], x: &Self) {
        *self = x + *self * Matrix3::from_diagonal(&Vector3::from(s));
    }
    fn axpy(&mut self, s: f64, x: &Self) {
        *self += x * s;
    }
    fn entries(&self) -> &[f64] {
        self.as_slice()
    }
    fn entries_mut(&mut self) -> &mut [f64] {
        self.as_mut_slice()
    }
}

/// Stopping rule: every lane's residual norm below max(relative * reference, absolute),
/// where reference = max(|b|, |r0|) of that lane.
#[derive(Clone, Copy, Debug)]
pub(crate) struct CgTolerance {
    pub relative: f64,
    pub absolute: f64,
    pub max_iter: usize,
}

/// Stopping rule of the Gauss-Newton and covariance solves on normal equations in
/// information units (H = sum J^T Omega J): stop when |r| <= `relative` x |b|, or
/// when r^T M^-1 r (M the preconditioner; about r^T H^-1 r, the chi^2 the rest
/// of the solve could still gain) is at most `chi2_per_unknown` x the number of
/// unknowns: then the solution is off by about sqrt(`chi2_per_unknown`) of its
/// standard error per unknown, however large or small the right-hand side.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct StepTolerance {
    pub relative: f64,
    pub chi2_per_unknown: f64,
    pub max_iter: usize,
}

impl StepTolerance {
    /// Gauss-Newton steps: 10^-4 of a standard error per unknown.
    pub fn step(max_iter: usize) -> Self {
        StepTolerance {
            relative: 1e-10,
            chi2_per_unknown: 1e-8,
            max_iter,
        }
    }

    /// Covariance samples (about one standard error per unknown each): 10^-3
    /// of it, far below the sampling error.
    pub fn sample(max_iter: usize) -> Self {
        StepTolerance {
            relative: 1e-8,
            chi2_per_unknown: 1e-6,
            max_iter,
        }
    }

    /// Met by the residual norm `r_norm` (of a right-hand side of norm `b_norm`)
    /// and the preconditioned residual energy `rz` over `unknowns` unknowns.
    pub fn met(&self, r_norm: f64, b_norm: f64, rz: f64, unknowns: usize) -> bool {
        r_norm <= self.relative * b_norm || rz.abs() <= self.chi2_per_unknown * unknowns as f64
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct CgReport {
    pub iterations: usize,
    pub converged: bool,
    /// Largest lane residual norm over its reference at the end.
    pub relative_residual: f64,
}

fn sum_dot<B: Lanes>(a: &[B], b: &[B]) -> [f64; 3] {
    a.iter().zip(b).fold([0.0; 3], |acc, (x, y)| {
        let d = x.lane_dot(y);
        [acc[0] + d[0], acc[1] + d[1], acc[2] + d[2]]
    })
}

/// Solves A x = b from the initial `x`. `apply(p, out)` writes A p into `out`;
/// `precondition(r, out)` writes M^-1 r. Both must be symmetric (positive semi-definite).
pub(crate) fn pcg<B: Lanes>(
    mut apply: impl FnMut(&[B], &mut [B]),
    mut precondition: impl FnMut(&[B], &mut [B]),
    b: Vec<B>,
    x: &mut [B],
    tolerance: CgTolerance,
) -> CgReport {
    let n = x.len();
    let b_norm = sum_dot(&b, &b).map(f64::sqrt);
    // r = b - A x, reusing b's storage.
    let mut r = b;
    let mut q = vec![B::zero(); n];
    apply(x, &mut q);
    for (ri, qi) in r.iter_mut().zip(&q) {
        ri.add_scaled([-1.0; 3], qi);
    }
    let r0_norm = sum_dot(&r, &r).map(f64::sqrt);
    let reference: [f64; 3] = [0, 1, 2].map(|l| b_norm[l].max(r0_norm[l]));
    let limit: [f64; 3] =
        [0, 1, 2].map(|l| (tolerance.relative * reference[l]).max(tolerance.absolute));
    let relative_of = |norms: [f64; 3]| {
        (0..3)
            .map(|l| {
                if reference[l] > 0.0 {
                    norms[l] / reference[l]
                } else {
                    0.0
                }
            })
            .fold(0.0, f64::max)
    };
    let done = |norms: [f64; 3]| (0..3).all(|l| norms[l] <= limit[l]);
    if done(r0_norm) {
        return CgReport {
            iterations: 0,
            converged: true,
            relative_residual: relative_of(r0_norm),
        };
    }
    // z = M^-1 r shares the buffer of q = A p: q is dead once r is updated.
    precondition(&r, &mut q);
    let mut p = q.clone();
    let mut rz = sum_dot(&r, &q);
    let mut norms = r0_norm;
    for iteration in 1..=tolerance.max_iter {
        apply(&p, &mut q);
        let pq = sum_dot(&p, &q);
        let alpha = [0, 1, 2].map(|l| {
            if pq[l] > 0.0 && rz[l] != 0.0 {
                rz[l] / pq[l]
            } else {
                0.0
            }
        });
        for k in 0..n {
            x[k].add_scaled(alpha, &p[k]);
            r[k].add_scaled(alpha.map(|a| -a), &q[k]);
        }
        norms = sum_dot(&r, &r).map(f64::sqrt);
        if done(norms) {
            return CgReport {
                iterations: iteration,
                converged: true,
                relative_residual: relative_of(norms),
            };
        }
        let z = &mut q;
        precondition(&r, z);
        let rz_new = sum_dot(&r, z);
        let beta = [0, 1, 2].map(|l| if rz[l] != 0.0 { rz_new[l] / rz[l] } else { 0.0 });
        for k in 0..n {
            p[k].scale_then_add(beta, &z[k]);
        }
        rz = rz_new;
    }
    CgReport {
        iterations: tolerance.max_iter,
        converged: false,
        relative_residual: relative_of(norms),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Path-graph Laplacian plus a diagonal shift: SPD, solution known.
    #[test]
    fn solves_a_shifted_path_laplacian_per_lane() {
        let n = 50;
        let apply = |p: &[Vector3<f64>], out: &mut [Vector3<f64>]| {
            for k in 0..n {
                let mut y = p[k] * 2.5;
                if k > 0 {
                    y -= p[k - 1];
                }
                if k + 1 < n {
                    y -= p[k + 1];
                }
                out[k] = y;
            }
        };
        let truth: Vec<Vector3<f64>> = (0..n)
            .map(|k| Vector3::new(k as f64, (k as f64).sin(), 1.0))
            .collect();
        let mut b = vec![Vector3::zeros(); n];
        apply(&truth, &mut b);
        let mut x = vec![Vector3::zeros(); n];
        let jacobi = |r: &[Vector3<f64>], out: &mut [Vector3<f64>]| {
            for (o, v) in out.iter_mut().zip(r) {
                *o = v / 2.5;
            }
        };
        let tol = CgTolerance {
            relative: 1e-12,
            absolute: 0.0,
            max_iter: 200,
        };
        let report = pcg(apply, jacobi, b, &mut x, tol);
        assert!(report.converged && report.iterations <= 50, "{report:?}");
        for (a, t) in x.iter().zip(&truth) {
            assert!((a - t).norm() < 1e-9);
        }
    }

    #[test]
    fn matrix_lanes_are_columns() {
        let a = Matrix3::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0);
        assert_eq!(a.lane_dot(&Matrix3::identity()), [1.0, 5.0, 9.0]);
        let mut m = Matrix3::zeros();
        m.add_scaled([1.0, 0.0, 2.0], &a);
        assert_eq!(m.column(1).norm(), 0.0);
        assert_eq!(m.column(2), a.column(2) * 2.0);
    }
}
