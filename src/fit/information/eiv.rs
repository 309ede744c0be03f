//! Errors in variables: the part of the normal equations that is noise of the
//! reference normals. Point-to-surface takes each normal from a plane fitted
//! to a ring of noisy reference pixels; its horizontal components carry that
//! noise (variance `Correspondence::normal_var`). The regressor a = (q x n / R,
//! n) is linear in n, so E[a a^T] = a0 a0^T + A Cov(n) A^T with
//! A = ([q]x / R ; I): on a flat, noisy strip the second term is all H holds
//! about the along-strip shift and yaw, and a sandwich built on it reports
//! centimetres for a direction the data do not fix. The final information
//! (not the ICP steps) takes that term out of H and, weighted by r^2, out of
//! the meat.

use nalgebra::{DMatrix, Matrix6, SymmetricEigen, Vector3};

use crate::fit::Correspondence;

/// Smallest corrected eigenvalue kept, relative to the largest: directions the
/// correction leaves without information get sigmas up to 100x the best one's
/// instead of an infinite or negative variance.
const FLOOR: f64 = 1e-4;

/// The noise terms of H and of the meat over `corrs` about `centroid` (scaled
/// rotations at `radius_m`, as [`super::NormalEquations`]).
pub(super) fn noise_terms(
    corrs: &[Correspondence],
    centroid: &Vector3<f64>,
    radius_m: f64,
) -> (Matrix6<f64>, Matrix6<f64>) {
    let (mut h, mut meat) = (Matrix6::zeros(), Matrix6::zeros());
    for c in corrs.iter().filter(|c| c.normal_var > 0.0) {
        let q = c.moving - centroid;
        let mut cov_a = Matrix6::zeros();
        for e in [Vector3::x(), Vector3::y()] {
            let col = super::jacobian_row(&q, &e, radius_m);
            cov_a += col * col.transpose();
        }
        cov_a *= c.normal_var;
        h += c.weight * cov_a;
        meat += (c.weight * c.plane_residual_m()).powi(2) * cov_a;
    }
    (h, meat)
}

/// The inverse of the corrected `h` on the span of the kept eigen-directions
/// of the uncorrected one (`eig`, `keep`), its eigenvalues floored at FLOOR of
/// the largest.
pub(super) fn corrected_inverse(
    eig: &SymmetricEigen<f64, nalgebra::U6>,
    keep: &[bool; 6],
    h: &Matrix6<f64>,
) -> Matrix6<f64> {
    super::on_kept(eig, keep, h, |reduced| {
        let e = ((&reduced + reduced.transpose()) * 0.5).symmetric_eigen();
        let floor = FLOOR * e.eigenvalues.max().max(f64::MIN_POSITIVE);
        let inv_vals = e.eigenvalues.map(|v| 1.0 / v.max(floor));
        Some(&e.eigenvectors * DMatrix::from_diagonal(&inv_vals) * e.eigenvectors.transpose())
    })
}

/// `m` with its negative eigenvalues set to zero.
pub(super) fn positive_part(m: &Matrix6<f64>) -> Matrix6<f64> {
    let e = ((m + m.transpose()) * 0.5).symmetric_eigen();
    let vals = e.eigenvalues.map(|v| v.max(0.0));
    e.eigenvectors * Matrix6::from_diagonal(&vals) * e.eigenvectors.transpose()
}
