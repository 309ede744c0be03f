//! The gridding floor of a pair's standard errors. Two DSMs gridded from
//! points (lidar binning, stereo TIN or IDW, matching windows) place each wall
//! and ridge to a fraction of a pixel, and that placement error is shared by
//! the whole overlap: no residual statistic of the fit sees it, nor do the
//! restart and backward checks (they refit the same rasters). Measured over
//! generated collections in four renderings (docs/measurements.md, "Gridding
//! floor"), the errors of 256-512 m tiles were about twice the fit's sigmas,
//! with a common part of about 1/20 pixel.
//!
//! So a pair reports (k pixel)^2 more variance on each measured horizontal
//! axis and smaller shares of it on height and, as arcs at the RMS radius of
//! the points, on the rotations. The floor is mostly each DSM's own placement, shared by
//! all of its pairs and consistent around every cycle, so the graph weighs the
//! fit's own covariance (weighing the floor with the yaw share at 1 made the
//! 1 km chain's worst DSM 4 mm worse and the 20 x 20 grid's median 6 mm) and
//! each pose's reported sigmas get its DSM's half: on the shift
//! ([`pose_floor_m`]) and, as arcs over the DSM's own footprint, on the
//! rotation ([`pose_floor_rad`]). Without the rotation's half, two DSMs that
//! know their relative yaw from their one pair alone (a chain of two 2 km
//! tiles) reported yaw sigmas of 0.0007 deg for errors of 0.0033 deg: the
//! pair's own yaw sigma without its floor, split between the two.

use super::backward::projector_for_extras;
use crate::fit::FitInformation;
use nalgebra::{Matrix6, Vector6};

/// Default floor, in pixels of the coarser DSM (`--sigma-floor-px`).
pub const DEFAULT_SIGMA_FLOOR_PX: f64 = 0.05;

/// The other axes' floors as shares of the horizontal one: height
/// [`HEIGHT_SHARE`] of it, the tilts [`TILT_SHARE`] and yaw [`YAW_SHARE`] of
/// its arc at the RMS radius of the points. A rotation needs the walls'
/// placement errors to differ across the overlap, and they partly average
/// out; height moves with a wall's placement only on slopes. Chosen so that
/// every axis of the generated pairs measured (two seeds, four renderings,
/// 128-512 m tiles) was within 3 sigma for 98-100 % of pairs.
pub const HEIGHT_SHARE: f64 = 0.1;
/// See [`HEIGHT_SHARE`].
pub const TILT_SHARE: f64 = 0.1;
/// See [`HEIGHT_SHARE`].
pub const YAW_SHARE: f64 = 0.5;

/// The covariance of the gridding error for a fit at `pixel_m` with floor
/// `k_px` (pixels): x and y get (k pixel)^2, the other axes their shares
/// (rotations as arcs at the fit's RMS radius).
pub fn gridding_covariance(info: &FitInformation, pixel_m: f64, k_px: f64) -> Matrix6<f64> {
    let sd = gridding_sd(k_px * pixel_m, info.radius_m);
    Matrix6::from_diagonal(&sd.map(|s| s * s))
}

/// The floor's standard deviation per axis (x, y, z m, roll, pitch, yaw rad)
/// for a horizontal floor of `arc_m` over points at RMS radius `radius_m`.
pub fn gridding_sd(arc_m: f64, radius_m: f64) -> Vector6<f64> {
    let radius_m = radius_m.max(1e-6);
    Vector6::new(
        arc_m,
        arc_m,
        HEIGHT_SHARE * arc_m,
        TILT_SHARE * arc_m / radius_m,
        TILT_SHARE * arc_m / radius_m,
        YAW_SHARE * arc_m / radius_m,
    )
}

/// Sets the gridding floor of `info` on the directions it measures (held
/// directions stay without variance).
pub fn apply(info: &mut FitInformation, pixel_m: f64, k_px: f64) {
    if k_px > 0.0 && pixel_m > 0.0 {
        let range = projector_for_extras(&info.covariance_6x6, info.radius_m);
        let g = range * gridding_covariance(info, pixel_m, k_px) * range.transpose();
        info.gridding_6x6 = (g + g.transpose()) * 0.5;
    }
}

/// One DSM's share of the floor on x, y and height (metres): half the pair's
/// variance, for a DSM of `pixel_m` pixels.
pub fn pose_floor_m(pixel_m: f64, k_px: f64) -> [f64; 3] {
    let h = k_px * pixel_m / std::f64::consts::SQRT_2;
    [h, h, HEIGHT_SHARE * h]
}

/// One DSM's share of the floor on roll, pitch and yaw (radians): half the
/// variance a pair's floor puts on its rotations, as arcs at `radius_m`, the
/// RMS radius of the DSM's footprint about its centre ([`footprint_radius_m`]).
pub fn pose_floor_rad(pixel_m: f64, k_px: f64, radius_m: f64) -> [f64; 3] {
    let sd = gridding_sd(k_px * pixel_m / std::f64::consts::SQRT_2, radius_m);
    [sd[3], sd[4], sd[5]]
}

/// The RMS distance of a `width_m` x `height_m` rectangle's points from its
/// centre.
pub fn footprint_radius_m(width_m: f64, height_m: f64) -> f64 {
    ((width_m * width_m + height_m * height_m) / 12.0).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::information::standard_error;
    use crate::fit::Axis;
    use nalgebra::{Vector3, Vector6};

    fn information(variances: [f64; 6], held: &[Axis]) -> FitInformation {
        let covariance = Matrix6::from_diagonal(&Vector6::from(variances));
        let sigma = std::array::from_fn(|k| {
            (!held.iter().any(|a| a.index() == k)).then(|| standard_error(&covariance, k))
        });
        FitInformation {
            info_6x6: Matrix6::from_diagonal(&Vector6::from(variances.map(|v| {
                if v > 0.0 {
                    1.0 / v
                } else {
                    0.0
                }
            }))),
            covariance_6x6: covariance,
            sigma,
            degenerate: held.to_vec(),
            centroid: Vector3::zeros(),
            effective_samples: 100.0,
            radius_m: 200.0,
            gridding_6x6: Matrix6::zeros(),
        }
    }

    #[test]
    fn the_floor_widens_measured_axes_by_their_shares_and_leaves_held_axes() {
        // 0.5 m pixels, floor 0.05 px: 2.5 cm on x, y, shares of it on the others
        let mut info = information([1e-4, 0.0, 1e-6, 1e-8, 1e-8, 1e-8], &[Axis::Y]);
        let fit = info.covariance_6x6;
        apply(&mut info, 0.5, 0.05);
        assert_eq!(info.covariance_6x6, fit, "the fit's own covariance stays");
        let reported = info.reported_sigma();
        let sigma = |a: Axis| reported[a.index()];
        assert!((sigma(Axis::X).unwrap() - (1e-4f64 + 0.025 * 0.025).sqrt()).abs() < 1e-12);
        assert_eq!(sigma(Axis::Y), None, "a held axis stays held");
        assert_eq!(info.reported_covariance()[(1, 1)], 0.0);
        let z = (1e-6f64 + (HEIGHT_SHARE * 0.025f64).powi(2)).sqrt();
        assert!((sigma(Axis::Z).unwrap() - z).abs() < 1e-12);
        let roll_rad = (1e-8f64 + (TILT_SHARE * 0.025 / 200.0).powi(2)).sqrt();
        assert!((sigma(Axis::Roll).unwrap() - roll_rad.to_degrees()).abs() < 1e-12);
        let yaw_rad = (1e-8f64 + (YAW_SHARE * 0.025 / 200.0).powi(2)).sqrt();
        assert!((sigma(Axis::Yaw).unwrap() - yaw_rad.to_degrees()).abs() < 1e-12);
    }

    #[test]
    fn a_dsm_carries_half_the_pair_variance() {
        let f = pose_floor_m(0.5, 0.05);
        assert!((2.0 * f[0] * f[0] - 0.025f64 * 0.025).abs() < 1e-15);
        assert_eq!(f[0], f[1]);
        assert!((f[2] - HEIGHT_SHARE * f[0]).abs() < 1e-15);
    }

    #[test]
    fn a_dsm_carries_half_the_pair_variance_of_rotation_over_its_footprint() {
        // a pair whose points lie at the DSM's own RMS radius: each DSM half its variance
        let radius_m = footprint_radius_m(2048.0, 2048.0);
        assert!((radius_m - 2048.0 / 6f64.sqrt()).abs() < 1e-9);
        let pair = gridding_sd(0.05 * 2.0, radius_m);
        let dsm = pose_floor_rad(2.0, 0.05, radius_m);
        for (k, d) in dsm.iter().enumerate() {
            assert!(
                (2.0 * d * d - pair[3 + k] * pair[3 + k]).abs() < 1e-18,
                "{k}"
            );
        }
        // 2 km DSMs at 2 m: 0.0025 deg of yaw each (docs/measurements.md,
        // "A DSM's rotation sigma without its share of the floor")
        let yaw_deg = dsm[2].to_degrees();
        assert!((yaw_deg - 0.0025).abs() < 2e-4, "{yaw_deg}");
        assert_eq!(pose_floor_rad(2.0, 0.0, radius_m), [0.0; 3]);
    }

    #[test]
    fn a_zero_floor_changes_nothing() {
        let mut info = information([1e-4, 1e-4, 1e-6, 1e-8, 1e-8, 1e-8], &[]);
        apply(&mut info, 0.5, 0.0);
        assert_eq!(info.reported_sigma(), info.sigma);
    }
}
