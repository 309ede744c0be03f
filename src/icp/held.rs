//! What a held direction costs the measured ones. A degenerate fit holds the
//! directions its overlap cannot see at their start (solution remapping) and
//! measures the others with the held ones fixed there. A held direction is
//! rarely purely horizontal: on ground that slopes by s, moving along it moves
//! the height too (x and z together, (1, 0, s)), so a start e metres off
//! along it puts the measured height s e off, however small its sigma.
//!
//! The start came from the global search: the truth lies within the searched
//! square of half-width `reached_m` around the georeferenced place, the answer
//! `offset_m` from it, so the start's horizontal error has a variance of about
//! reached^2 / 3 + offset^2 per axis (uniform over the square, about the
//! answer). [`spread_held`] adds that variance along each held direction,
//! scaled to unit horizontal motion: the measured axes then carry what the held
//! start can do to them. The held axes stay unreported (no sigma), and on flat
//! ground (s = 0) nothing changes. A degenerate pair gives no graph edge (this
//! is what `pair` reports); an ambiguous one with held axes enters the graph
//! at the unreliable weight with this covariance.

use nalgebra::{DMatrix, Matrix6, SMatrix};

use super::backward::pseudo_inverse;
use crate::fit::information::standard_error;
use crate::fit::{FitInformation, Model};

/// Adds to `info`'s covariance the variance of a start anywhere in the
/// searched square (module doc) along its held directions.
pub(super) fn spread_held(info: &mut FitInformation, model: Model, reached_m: f64, offset_m: f64) {
    let variance = reached_m.powi(2) / 3.0 + offset_m.powi(2);
    if info.degenerate.is_empty() || !(variance > 0.0 && variance.is_finite()) {
        return;
    }
    let per_metre = held_per_metre(&info.covariance_6x6, info.radius_m, model);
    let extra = per_metre * per_metre.transpose() * variance;
    info.covariance_6x6 += (extra + extra.transpose()) * 0.5;
    info.info_6x6 = pseudo_inverse(&info.covariance_6x6).0;
    for k in 0..6 {
        if info.sigma[k].is_some() {
            info.sigma[k] = Some(standard_error(&info.covariance_6x6, k));
        }
    }
}

/// The held directions of a covariance (its null space among the estimated
/// axes, rotations compared as arcs at `radius_m`) as the motion of all six
/// parameters per metre of horizontal motion (x, y): column c moves the start
/// one metre along axis c within the held directions, and what the held
/// coupling moves with it. Directions with under a tenth of their length
/// horizontal add nothing.
fn held_per_metre(c: &Matrix6<f64>, radius_m: f64, model: Model) -> SMatrix<f64, 6, 2> {
    let estimated = if model == Model::Translation { 3 } else { 6 };
    let arc = |k: usize| if k < 3 { 1.0 } else { radius_m.max(1e-6) };
    let scaled = DMatrix::from_fn(estimated, estimated, |r, k| c[(r, k)] * arc(r) * arc(k));
    let eig = scaled.symmetric_eigen();
    let max = eig.eigenvalues.amax();
    let held: Vec<usize> = (0..estimated)
        .filter(|&k| eig.eigenvalues[k] <= NULL * max)
        .collect();
    let mut out = SMatrix::<f64, 6, 2>::zeros();
    if held.is_empty() {
        return out;
    }
    // the held directions in physical units (rotations back from arcs; the
    // axes the model does not estimate stay zero)
    let n = DMatrix::from_fn(6, held.len(), |r, j| {
        if r < estimated {
            eig.eigenvectors[(r, held[j])] / arc(r)
        } else {
            0.0
        }
    });
    // horizontal motion u = A c of a combination c; c = A^+ u (least norm)
    let a = n.rows(0, 2).into_owned();
    let svd = a.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return out;
    };
    for (s, sv) in svd.singular_values.iter().enumerate() {
        if *sv < MIN_HORIZONTAL {
            continue;
        }
        // n v_s / sigma_s moves the start by u_s (unit, horizontal)
        let along = &n * v_t.row(s).transpose() / *sv;
        let u_s = u.column(s);
        for r in 0..6 {
            for col in 0..2 {
                out[(r, col)] += along[r] * u_s[col];
            }
        }
    }
    out
}

/// Relative eigenvalue at or below which a direction of the covariance is
/// held (the pseudo-inverse leaves exact zeros there, up to rounding).
const NULL: f64 = 1e-12;

/// Least horizontal share of a held direction that takes the start's error.
const MIN_HORIZONTAL: f64 = 0.1;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::Axis;
    use nalgebra::{Vector3, Vector6};

    /// A fit that measured z, roll, pitch and yaw with x and y held along
    /// ground sloping by `slope` in x: its covariance is zero along
    /// (1, 0, slope) and (0, 1, 0).
    fn held_xy(slope: f64) -> FitInformation {
        let measured = [
            Vector6::new(-slope, 0.0, 1.0, 0.0, 0.0, 0.0).normalize(),
            Vector6::new(0.0, 0.0, 0.0, 1.0, 0.0, 0.0),
            Vector6::new(0.0, 0.0, 0.0, 0.0, 1.0, 0.0),
            Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
        ];
        let variances = [0.01f64.powi(2), 1e-8, 1e-8, 1e-8];
        let mut c = Matrix6::zeros();
        for (v, var) in measured.iter().zip(variances) {
            c += v * v.transpose() * var;
        }
        let sigma = std::array::from_fn(|k| (k >= 2).then(|| standard_error(&c, k)));
        FitInformation {
            info_6x6: pseudo_inverse(&c).0,
            covariance_6x6: c,
            sigma,
            degenerate: vec![Axis::X, Axis::Y],
            centroid: Vector3::zeros(),
            effective_samples: 1000.0,
            radius_m: 20.0,
            gridding_6x6: Matrix6::zeros(),
        }
    }

    #[test]
    fn a_held_start_on_sloping_ground_widens_the_height_by_the_slope() {
        let mut info = held_xy(0.04);
        let before = info.sigma[2].unwrap();
        spread_held(&mut info, Model::Rigid, 60.0, 30.0);
        let start_sd = (60.0f64.powi(2) / 3.0 + 30.0f64.powi(2)).sqrt();
        let expected = (before.powi(2) + (0.04 * start_sd).powi(2)).sqrt();
        let after = info.sigma[2].unwrap();
        assert!(
            (after - expected).abs() < 0.02 * expected,
            "{before} -> {after}, expected {expected}"
        );
        assert!(
            info.sigma[0].is_none() && info.sigma[1].is_none(),
            "held stay held"
        );
        assert!(info.info_6x6.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn a_held_start_on_flat_ground_changes_nothing_measured() {
        let mut info = held_xy(0.0);
        let before = info.sigma;
        spread_held(&mut info, Model::Rigid, 60.0, 30.0);
        for (k, (b, a)) in before.iter().zip(&info.sigma).enumerate().skip(2) {
            let (b, a) = (b.unwrap(), a.unwrap());
            assert!((a - b).abs() <= 1e-9 * b.max(1e-12), "{k}: {b} -> {a}");
        }
    }

    #[test]
    fn a_fit_with_nothing_held_is_left_alone() {
        let mut info = held_xy(0.04);
        info.degenerate.clear();
        let before = info.covariance_6x6;
        spread_held(&mut info, Model::Rigid, 60.0, 30.0);
        assert_eq!(info.covariance_6x6, before);
    }
}
