//! Pairwise DSM-ICP (Xu & Qin 2024, Sec. 3.1), coarse to fine over the
//! overview levels.
//!
//! `register(reference, moving)` returns the rigid transform `t_ref_moving` that
//! maps points of the moving DSM (x, y, height in the CRS) onto the reference:
//! p_ref = t_ref_moving p_moving. All math is in a local frame centred on the
//! overlap, in f64; the world transform is formed at the end.
//!
//! Files, one noun each: [`config`] (metric, settings), [`result`] (what comes
//! back), [`sample`] (stratified query points), `level` (one rung of the ladder:
//! sample, run, judge), `iterate` (the loop on one screen: associate, weight,
//! fit, converged), `robust` (roughness filter, Tukey weights), [`associate`]
//! (exact grid NN matches, parallel over blocks).

pub mod associate;
pub mod config;
mod iterate;
mod level;
pub mod result;
mod robust;
pub mod sample;

use nalgebra::{Isometry3, Vector3};

pub use config::{IcpConfig, Metric};
pub use result::{IcpError, IcpResult, IcpStatus, NnStatsSummary};

/// Row-major 4x4 of a transform: [`crate::geo::rigid::to_rows`].
pub use crate::geo::rigid::to_rows as matrix_rows;

use crate::geo::Bounds;
use crate::grid::{Grid, Pyramid};
use level::{start_level, Level};

/// Registers `moving` onto `reference` (see module docs): levels from the
/// coarsest useful one down to full resolution, each starting from the last
/// one's estimate; a level that fails ends the ladder with its status.
pub fn register<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
) -> Result<IcpResult, IcpError> {
    let overlap = overlap(reference, moving)?;
    let (centre_x, centre_y) = overlap.centre();
    let origin_xy = Vector3::new(centre_x, centre_y, 0.0);
    let start = start_level(reference, moving, &overlap, config.max_level);
    // fixed by the coarsest level's samples, then kept by the finer ones
    let mut origin: Option<Vector3<f64>> = None;
    let mut t_ref_moving_local = Isometry3::identity();
    let mut last = None;
    for index in (0..=start).rev() {
        let level = Level::sample(reference, moving, index, &overlap, &origin_xy, config)?;
        let origin = *origin.get_or_insert_with(|| level.origin(&origin_xy));
        let outcome = level.run(&origin, t_ref_moving_local)?;
        t_ref_moving_local = outcome.t_ref_moving;
        let failed = outcome.failed();
        last = Some(outcome);
        if failed {
            break;
        }
    }
    let outcome = last.expect("at least one level");
    Ok(outcome.into_result(&origin.unwrap_or(origin_xy)))
}

/// The common box of the two DSMs' full-resolution rasters.
fn overlap<R: Pyramid, M: Pyramid>(reference: &R, moving: &M) -> Result<Bounds, IcpError> {
    let extent = |g: &dyn Grid| g.geotransform().extent(g.width() as u64, g.height() as u64);
    let ref0 = reference.open_level(0).map_err(IcpError::Read)?;
    let mov0 = moving.open_level(0).map_err(IcpError::Read)?;
    extent(&ref0)
        .intersection(&extent(&mov0))
        .ok_or(IcpError::NoOverlap)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::Model;
    use crate::geo::rigid::rotation_angle_deg;
    use crate::geo::GeoTransform;
    use crate::grid::{MemGrid, MemPyramid};
    use crate::rng::SplitMix64;
    use nalgebra::{Point3, Translation3, UnitQuaternion};

    /// Terrain with box buildings of varied heights (walls give horizontal constraints).
    fn surface(x: f64, y: f64) -> f64 {
        let terrain = 5.0 * (x / 47.0).sin() + 3.0 * (y / 31.0).cos() + 0.01 * x;
        let (cx, cy) = ((x / 20.0).floor(), (y / 20.0).floor());
        let hash = ((cx * 73.0 + cy * 151.0).sin() * 43758.5453).fract().abs();
        let (fx, fy) = (x / 20.0 - cx, y / 20.0 - cy);
        let size = 0.3 + 0.4 * hash;
        if hash > 0.35 && fx > 0.2 && fx < 0.2 + size && fy > 0.15 && fy < 0.15 + size * 1.3 {
            terrain + 4.0 + 25.0 * hash
        } else {
            terrain
        }
    }

    /// A DSM of the surface as seen by a sensor whose data need `t_ref_moving`
    /// to be registered: pixel (x', y') holds h' with t_ref_moving (x', y', h') on the surface.
    fn dsm(
        left: f64,
        top: f64,
        size: i64,
        gsd: f64,
        t_ref_moving: &Isometry3<f64>,
        noise_m: f64,
        seed: u64,
    ) -> MemGrid {
        let gt = GeoTransform::north_up(left, top, gsd, gsd);
        let mut rng = SplitMix64::new(seed);
        MemGrid::from_fn(size, size, gt, |c, r| {
            let (x, y) = gt.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            let mut h = surface(x, y);
            for _ in 0..4 {
                let p = t_ref_moving.transform_point(&Point3::new(x, y, h));
                h += surface(p.x, p.y) - p.z;
            }
            let n = (rng.next_f64() + rng.next_f64() + rng.next_f64() - 1.5) * 2.0 * noise_m;
            if rng.next_f64() < 0.02 {
                return f32::NAN;
            }
            (h + n) as f32
        })
    }

    fn pose_error(t_est: &Isometry3<f64>, t_true: &Isometry3<f64>, at: Point3<f64>) -> (f64, f64) {
        let e = t_est.inverse() * t_true;
        let p = e.transform_point(&at);
        (
            (p - at).norm(),
            rotation_angle_deg(e.rotation.to_rotation_matrix().matrix()),
        )
    }

    fn check_recovery(
        noise_m: f64,
        truth_local: Isometry3<f64>,
        config: &IcpConfig,
        tol_m: f64,
        tol_deg: f64,
    ) -> IcpResult {
        let centre = Point3::new(500_130.0, 4_800_100.0, 0.0);
        // truth about the overlap centre, expressed in world coordinates
        let to = Translation3::from(centre.coords);
        let truth = nalgebra::convert::<_, Isometry3<f64>>(to)
            * truth_local
            * nalgebra::convert::<_, Isometry3<f64>>(to.inverse());
        let reference = dsm(
            500_000.0,
            4_800_200.0,
            400,
            0.5,
            &Isometry3::identity(),
            noise_m,
            1,
        );
        let moving = dsm(500_060.0, 4_800_200.0, 400, 0.5, &truth, noise_m, 2);
        let (rp, mp) = (
            MemPyramid::build(reference, 64),
            MemPyramid::build(moving, 64),
        );
        let result = register(&rp, &mp, config).unwrap();
        let (d_m, a_deg) = pose_error(
            &result.t_ref_moving,
            &truth,
            centre + nalgebra::Vector3::new(0.0, 0.0, 10.0),
        );
        assert!(result.is_usable(), "{:?}", result.status);
        assert!(
            d_m < tol_m && a_deg < tol_deg,
            "error {d_m} m {a_deg} deg; {result:?}"
        );
        result
    }

    #[test]
    fn recovers_known_rigid_motion_forward_and_inverse() {
        let truth = Isometry3::from_parts(
            Translation3::new(1.3, -0.7, 0.9),
            UnitQuaternion::from_euler_angles(0.0002, -0.0003, 0.0006),
        );
        // Noise-free: the machinery must be exact. With noise, rigid accuracy is
        // tested on generated city tiles (tests/cli_pair_recovery.rs): this box
        // surface has too few slopes to fix yaw once walls are filtered out.
        let config = IcpConfig {
            samples: 120_000,
            ..Default::default()
        };
        check_recovery(0.0, truth, &config, 0.01, 0.001);
        check_recovery(0.0, truth.inverse(), &config, 0.01, 0.001);
    }

    #[test]
    fn recovers_known_translation_forward_and_inverse() {
        let truth = Isometry3::from_parts(
            Translation3::new(1.3, -0.7, 0.9),
            UnitQuaternion::identity(),
        );
        let config = IcpConfig {
            samples: 120_000,
            model: Model::Translation,
            ..Default::default()
        };
        check_recovery(0.15, truth, &config, 0.05, 1e-9);
        check_recovery(0.15, truth.inverse(), &config, 0.05, 1e-9);
    }

    #[test]
    fn recovers_large_shift_coarse_to_fine() {
        let truth = Isometry3::from_parts(
            Translation3::new(-4.6, 3.9, -2.1),
            UnitQuaternion::identity(),
        );
        let config = IcpConfig {
            samples: 120_000,
            model: Model::Translation,
            ..Default::default()
        };
        check_recovery(0.15, truth, &config, 0.05, 1e-9);
    }

    #[test]
    fn disjoint_dsms_are_refused() {
        let a = MemPyramid::build(dsm(0.0, 100.0, 50, 1.0, &Isometry3::identity(), 0.0, 1), 64);
        let b = MemPyramid::build(
            dsm(500.0, 100.0, 50, 1.0, &Isometry3::identity(), 0.0, 1),
            64,
        );
        assert!(matches!(
            register(&a, &b, &IcpConfig::default()),
            Err(IcpError::NoOverlap)
        ));
    }

    #[test]
    fn flat_terrain_is_flagged_degenerate() {
        let gt = GeoTransform::north_up(0.0, 100.0, 0.5, 0.5);
        let flat = MemPyramid::build(MemGrid::from_fn(200, 200, gt, |_, _| 12.0), 64);
        let r = register(&flat, &flat, &IcpConfig::default()).unwrap();
        assert_eq!(r.status, IcpStatus::Degenerate);
        assert!(!r.is_usable());
    }
}
