//! A split-sample check of a fit's covariance: the correspondences are cut in
//! two halves across the long axis of the overlap, each half is solved alone at
//! the final pose (one linear step), and the two answers are compared with what
//! the covariance predicts for their difference (4 C for halves of the data).
//! When they disagree more (a bias that differs along the overlap: a changed
//! building, a narrow strip that sees different structures at its two ends),
//! the covariance is scaled by that excess. This catches systematic errors the
//! sandwich cannot see within one neighbourhood; a bias common to the whole
//! overlap stays invisible to it.

use nalgebra::{DMatrix, DVector, Matrix2, Matrix6, SymmetricEigen, Vector6};

use super::information::NormalEquations;
use super::Correspondence;

/// The factor (>= 1) by which the covariance `scaled` (in the normal equations'
/// scaled parameters) should grow for the two halves of `corrs` to agree within
/// it: max(1, d^T (4 C)^-1 d / m) over the m kept directions.
pub(crate) fn split_half_factor(
    corrs: &[Correspondence],
    eq: &NormalEquations,
    eig: &SymmetricEigen<f64, nalgebra::U6>,
    keep: &[bool; 6],
    scaled: &Matrix6<f64>,
) -> f64 {
    let kept: Vec<usize> = (0..6).filter(|&k| keep[k]).collect();
    let m = kept.len();
    if m == 0 || corrs.len() < 24 {
        return 1.0;
    }
    let axis = long_axis(corrs, eq);
    let (mut h, mut g) = ([Matrix6::zeros(); 2], [Vector6::zeros(); 2]);
    for c in corrs {
        let q = c.moving - eq.centroid;
        let a_rot = q.cross(&c.normal) / eq.radius_m;
        let a = Vector6::new(
            a_rot.x, a_rot.y, a_rot.z, c.normal.x, c.normal.y, c.normal.z,
        );
        let half = usize::from(q.x * axis.0 + q.y * axis.1 >= 0.0);
        h[half] += c.weight * a * a.transpose();
        g[half] += c.weight * c.plane_residual_m() * a;
    }
    let basis = DMatrix::from_fn(6, m, |r, k| eig.eigenvectors[(r, kept[k])]);
    let solve = |half: usize| -> Option<DVector<f64>> {
        let hk = basis.transpose() * DMatrix::from_column_slice(6, 6, h[half].as_slice()) * &basis;
        let gk = basis.transpose() * DVector::from_column_slice(g[half].as_slice());
        hk.cholesky().map(|ch| -ch.solve(&gk))
    };
    let (Some(t1), Some(t2)) = (solve(0), solve(1)) else {
        return 1.0;
    };
    let d = t1 - t2;
    let predicted =
        basis.transpose() * DMatrix::from_column_slice(6, 6, scaled.as_slice()) * &basis * 4.0;
    let Some(chol) = predicted.cholesky() else {
        return 1.0;
    };
    let s2 = d.dot(&chol.solve(&d)) / m as f64;
    if s2.is_finite() {
        s2.max(1.0)
    } else {
        1.0
    }
}

/// The unit direction of largest spread of the correspondences in x, y.
fn long_axis(corrs: &[Correspondence], eq: &NormalEquations) -> (f64, f64) {
    let mut s = Matrix2::zeros();
    for c in corrs {
        let q = c.moving - eq.centroid;
        s += c.weight
            * nalgebra::Vector2::new(q.x, q.y)
            * nalgebra::Vector2::new(q.x, q.y).transpose();
    }
    let e = s.symmetric_eigen();
    let k = if e.eigenvalues[0] >= e.eigenvalues[1] {
        0
    } else {
        1
    };
    (e.eigenvectors[(0, k)], e.eigenvectors[(1, k)])
}
