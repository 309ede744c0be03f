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
//! (exact grid NN matches, parallel over blocks), `compare` (the starts'
//! places re-scored on the samples they share), `choice` (the best of the
//! starts' results; an ambiguous pair's spread joins its covariance), `restart`
//! and `backward` (two checks of the answer whose gaps beyond the noise join
//! its covariance; an answer the backward run does not confirm is ambiguous),
//! `held` (what a held start's error does to the measured axes).

mod accelerate;
pub mod associate;
mod backward;
mod choice;
mod compare;
pub mod config;
pub mod floor;
mod heights;
mod held;
mod iterate;
mod level;
mod restart;
pub mod result;
mod robust;
pub mod sample;
pub mod start;
#[cfg(test)]
mod testing;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

pub use config::{IcpConfig, Metric};
pub use result::{
    BackwardCheck, CentredPose, CentredSigma, IcpError, IcpResult, IcpStatus, NnStatsSummary,
    RestartCheck, SearchReach, SecondHeight,
};

/// Row-major 4x4 of a transform: [`crate::geo::rigid::to_rows`].
pub use crate::geo::rigid::to_rows as matrix_rows;

use crate::fit::{DegeneracyRule, WallSnap};
use crate::geo::Bounds;
use crate::grid::{Grid, Pyramid};
use crate::nn::{PlaneTable, WithPlanes, NORMAL_RADIUS_PX};
use choice::{choose, slid_rivals, unconfirmed};
use iterate::Rules;
use level::{start_level, Level};
use start::{find_starts, moved_overlap, Start, Starts};

/// Final robust costs closer than this ratio, at places that differ in a
/// measured direction, make a pair ambiguous.
pub const AMBIGUOUS_COST_RATIO: f64 = 0.9;

/// Registers `moving` onto `reference` (see module docs): the global initial
/// search ([`start`]) gives one start (or the best few when it is ambiguous);
/// from each, levels from the coarsest useful one down to full resolution,
/// each starting from the last one's estimate (a level that fails ends the
/// ladder with its status). The start whose result fits best is kept; the
/// restart check (`restart`) and the backward check (`backward`) then
/// widen its covariance where the data do not pin it down as its curvature says.
pub fn register<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
) -> Result<IcpResult, IcpError> {
    let starts = find_starts(reference, moving, config)?;
    // every run from here on matches against full-resolution ring planes
    // of the same few pixels: each is fitted once
    let reference = &WithPlanes::new(reference, 0, plane_table(reference, moving, &starts)?);
    let mut tried: Vec<(IcpResult, f64)> = Vec::new();
    let mut first_error = None;
    for start in &starts.starts {
        match from_start(reference, moving, config, &starts, start) {
            Ok(r) => {
                let ended = compare::shift_at_centre(&r.0);
                tracing::debug!(start = ?start.shift_m, ?ended, cost = r.1, status = ?r.0.status, inliers = r.0.inliers, samples = r.0.samples, overlap = r.0.overlap, "start result");
                tried.push(r)
            }
            Err(e) => {
                first_error.get_or_insert(e);
            }
        }
    }
    if tried.is_empty() {
        return Err(first_error.unwrap_or(IcpError::EmptyOverlap));
    }
    // choice cost, own cost; ordered by the own cost, which decides between
    // results at one place (the choice's sort is stable)
    let mut tried: Vec<(IcpResult, f64, f64)> = tried.into_iter().map(|(r, c)| (r, c, c)).collect();
    tried.sort_by(|a, b| a.2.total_cmp(&b.2));
    compare::on_shared_samples(reference, moving, &mut tried, starts.pixel_m)?;
    let ends: Vec<(IcpResult, f64)> = (tried.iter())
        .filter(|t| t.0.status.is_converged_or_held() || t.0.status == IcpStatus::MaxIterations)
        .map(|t| (t.0.clone(), t.2))
        .collect();
    let (forward, own) = choose(tried, starts.ambiguity, starts.pixel_m);
    let forward = slid_rivals(reference, moving, forward, own, &ends, starts.pixel_m)?;
    let limits = (starts.pixel_m, starts.radius_m);
    let forward = restart::check_restarts(reference, moving, config, forward, limits);
    let result = check_backward(reference, moving, config, &starts, forward);
    let result = unconfirmed(result, &ends, starts.pixel_m);
    let tau_m = config.tau_at(0, starts.pixel_m, starts.starts[0].cost_m);
    let mut result = heights::check_heights(reference, moving, result, tau_m, starts.pixel_m)?;
    if let Some(info) = result.information.as_mut() {
        floor::apply(info, starts.pixel_m, config.sigma_floor_px);
    }
    let shift = result.centred().shift_m;
    let offset_m = shift[0].hypot(shift[1]);
    if let Some(info) = result.information.as_mut() {
        held::spread_held(info, config.model, starts.radius_m, offset_m);
    }
    result.search = starts.ambiguity.is_some().then_some(SearchReach {
        cut_m: starts.cut_m,
        reached_m: starts.radius_m,
        offset_m,
    });
    Ok(result)
}

/// A table of the reference's full-resolution ring planes over the overlap
/// as georeferenced, widened by the search radius (where the starts may move
/// the DSM) and the plane window; None when that is too large to keep
/// ([`crate::nn::planes::MAX_TABLE_PIXELS`]).
fn plane_table<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    starts: &Starts,
) -> Result<Option<PlaneTable>, IcpError> {
    let Some(overlap) = moved_overlap(reference, moving, &Vector3::zeros())? else {
        return Ok(None);
    };
    let grid = reference.open_level(0).map_err(IcpError::Read)?;
    let margin_m = starts.radius_m + (NORMAL_RADIUS_PX + 2) as f64 * grid.geotransform().pixel_m();
    let wide = Bounds {
        min_x: overlap.min_x - margin_m,
        min_y: overlap.min_y - margin_m,
        max_x: overlap.max_x + margin_m,
        max_y: overlap.max_y + margin_m,
    };
    Ok(sample::pixel_window(&grid, &wide)
        .and_then(|[c0, r0, c1, r1]| PlaneTable::new(c0, r0, c1 - c0, r1 - r0)))
}

/// The forward answer reconciled with the backward check ([`backward`]):
/// when their gap is beyond the two fits' noise, the gap is added to its
/// covariance. Only for answers with information; a check that cannot run
/// leaves it as is.
fn check_backward<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
    starts: &Starts,
    forward: IcpResult,
) -> IcpResult {
    let Some(at) = forward.information.as_ref().map(|i| i.centroid) else {
        return forward;
    };
    let limits = (starts.pixel_m, starts.radius_m);
    match backward::register_backward(reference, moving, config, &forward, limits) {
        Ok(back) if !matches!(back.status, IcpStatus::TooFewInliers | IcpStatus::Diverged) => {
            let d = backward::Disagreement::between(&forward.t_ref_moving, &back.t_ref_moving, &at);
            tracing::debug!(shift_m = ?d.shift_m, rotation_rad = ?d.rotation_rad, status = ?back.status, "backward check");
            backward::reconcile(forward, &back, &d)
        }
        Ok(back) => {
            tracing::debug!(status = ?back.status, "backward check did not finish");
            forward
        }
        Err(e) => {
            tracing::debug!(error = %e, "backward check could not run");
            forward
        }
    }
}

/// The coarse-to-fine ladder from one start; the result and its robust cost.
fn from_start<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
    starts: &Starts,
    start: &Start,
) -> Result<(IcpResult, f64), IcpError> {
    // A start within the paper's tau of the identity is where the ladder
    // always began: sample the plain overlap as before (same samples, same
    // results on well-posed pairs); farther, where the moved DSM lands.
    let near = start.shift_m.xy().norm() < config::PAPER_TAU_M;
    let sampled = if near {
        Vector3::zeros()
    } else {
        start.shift_m
    };
    let overlap = moved_overlap(reference, moving, &sampled)?.ok_or(IcpError::NoOverlap)?;
    let (centre_x, centre_y) = overlap.centre();
    let origin_xy = Vector3::new(centre_x, centre_y, 0.0);
    let top = start_level(reference, moving, &overlap, config.max_level);
    // fixed by the coarsest level's samples, then kept by the finer ones
    let mut origin: Option<Vector3<f64>> = None;
    // a pure translation is the same in the local frame
    let t_start = Isometry3::from_parts(
        Translation3::from(start.shift_m),
        UnitQuaternion::identity(),
    );
    let mut t_ref_moving_local = t_start;
    let mut last = None;
    for index in (0..=top).rev() {
        let level = Level::sample(reference, moving, index, &overlap, &origin_xy, config)?;
        let origin = *origin.get_or_insert_with(|| level.origin(&origin_xy));
        let pixel_m = level_pixel_m(reference, index)?.max(starts.pixel_m);
        let rules = Rules {
            degeneracy: level_rule(index, starts.pixel_m),
            start: t_start,
            cap_m: starts.radius_m,
            floor_m: config.sigma_floor_px * pixel_m,
        };
        let tau_m = config.tau_at(index, pixel_m, start.cost_m);
        let outcome = level.run(&origin, t_ref_moving_local, tau_m, &rules)?;
        t_ref_moving_local = outcome.t_ref_moving;
        let failed = outcome.failed();
        last = Some(outcome);
        if failed {
            break;
        }
    }
    let outcome = last.expect("at least one level");
    let cost = outcome.robust_cost_m();
    let information = outcome.information(config, &final_rule(starts.pixel_m));
    Ok((
        outcome.into_result(&origin.unwrap_or(origin_xy), information),
        cost,
    ))
}

/// The reference's pixel on overview `index`, metres.
fn level_pixel_m<R: Pyramid>(reference: &R, index: usize) -> Result<f64, IcpError> {
    let gt = reference
        .open_level(index)
        .map_err(IcpError::Read)?
        .geotransform();
    Ok(gt.pixel_m())
}

/// Which directions the loop holds on overview `index`: on the overviews only
/// those the surface does not see at all (their residuals are still large,
/// their sigmas would hold directions that are merely not yet converged); at
/// full resolution also those pinned worse than [`final_rule`] says.
fn level_rule(index: usize, pixel_m: f64) -> DegeneracyRule {
    if index == 0 {
        final_rule(pixel_m)
    } else {
        DegeneracyRule {
            max_sigma_m: f64::INFINITY,
            walls: Some(WallSnap::of_pixel(pixel_m)),
            ..DegeneracyRule::default()
        }
    }
}

/// A direction is degenerate when its standard error exceeds half a
/// full-resolution pixel (at least 0.5 m; rotations as the arc at the RMS
/// radius of the overlap), or its information is 1e-6 of the best one's;
/// walls count with the shared snapping error of full-resolution pixels.
pub fn final_rule(pixel_m: f64) -> DegeneracyRule {
    DegeneracyRule {
        max_sigma_m: DegeneracyRule::default().max_sigma_m.max(0.5 * pixel_m),
        walls: Some(WallSnap::of_pixel(pixel_m)),
        ..DegeneracyRule::default()
    }
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
    use std::f64::consts::PI;

    /// Terrain with box buildings of varied heights (walls give horizontal
    /// constraints), one per 20 m block at a position of its own: walls on a
    /// shared lattice would all snap to the pixels with one error.
    fn surface(x: f64, y: f64) -> f64 {
        let terrain = 5.0 * (x / 47.0).sin() + 3.0 * (y / 31.0).cos() + 0.01 * x;
        let (cx, cy) = ((x / 20.0).floor(), (y / 20.0).floor());
        let hash = ((cx * 73.0 + cy * 151.0).sin() * 43758.5453).fract().abs();
        let jitter = ((cx * 37.0 + cy * 91.0).sin() * 24634.6345).fract().abs();
        let (fx, fy) = (x / 20.0 - cx, y / 20.0 - cy);
        let size = 0.3 + 0.4 * hash;
        let (x0, y0) = (0.05 + 0.2 * jitter, 0.05 + 0.1 * (1.0 - jitter));
        if hash > 0.35 && fx > x0 && fx < x0 + size && fy > y0 && fy < y0 + size * 1.3 {
            terrain + 4.0 + 25.0 * hash
        } else {
            terrain
        }
    }

    /// A DSM of the surface as seen by a sensor whose data need `t_ref_moving`
    /// to be registered: pixel (x', y') holds h' with t_ref_moving (x', y', h') on the surface.
    fn dsm(
        (left, top): (f64, f64),
        size: i64,
        gsd: f64,
        t_ref_moving: &Isometry3<f64>,
        noise_m: f64,
        seed: u64,
        scatter: bool,
    ) -> MemGrid {
        let gt = GeoTransform::north_up(left, top, gsd, gsd);
        let mut rng = SplitMix64::new(seed);
        MemGrid::from_fn(size, size, gt, |c, r| {
            // one sample per pixel: at its centre (a lattice) or, with
            // `scatter`, anywhere in it, as lidar returns fall
            let (u, v) = if scatter {
                (rng.next_f64(), rng.next_f64())
            } else {
                (0.5, 0.5)
            };
            let (x, y) = gt.pixel_to_world(c as f64 + u, r as f64 + v);
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
        scatter: bool,
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
            (500_000.0, 4_800_200.0),
            400,
            0.5,
            &Isometry3::identity(),
            noise_m,
            1,
            scatter,
        );
        let moving = dsm(
            (500_060.0, 4_800_200.0),
            400,
            0.5,
            &truth,
            noise_m,
            2,
            scatter,
        );
        let (rp, mp) = (
            MemPyramid::build(reference, 64),
            MemPyramid::build(moving, 64),
        );
        let result = register(&rp, &mp, config).unwrap();
        let ground = Point3::new(centre.x, centre.y, surface(centre.x, centre.y));
        let (d_m, a_deg) = pose_error(&result.t_ref_moving, &truth, ground);
        assert!(result.is_usable(), "{:?}", result.status);
        assert!(
            d_m < tol_m && a_deg < tol_deg,
            "error {d_m} m {a_deg} deg; {result:?}"
        );
        if scatter {
            // per axis within 3 of the reported sigmas, at the fit's centroid
            let info = result.information.as_ref().unwrap();
            let c = Point3::from(info.centroid);
            let shift = result.t_ref_moving.transform_point(&c) - truth.transform_point(&c);
            let turn = (result.t_ref_moving.rotation * truth.rotation.inverse()).scaled_axis();
            let error = [shift.x, shift.y, shift.z, turn.x, turn.y, turn.z];
            for (axis, sigma) in info.reported_sigma().iter().enumerate() {
                let e = error[axis] * if axis < 3 { 1.0 } else { 180.0 / PI };
                assert!(
                    sigma.is_none_or(|s| e.abs() <= 3.0 * s),
                    "axis {axis}: {e} vs {sigma:?}"
                );
            }
        }
        result
    }

    #[test]
    fn recovers_known_rigid_motion_forward_and_inverse() {
        let truth = Isometry3::from_parts(
            Translation3::new(1.3, -0.7, 0.9),
            UnitQuaternion::from_euler_angles(0.0002, -0.0003, 0.0006),
        );
        // Noise-free on a lattice with walls filtered: the machinery must be
        // exact. (Walls sampled on a lattice all snap to the pixels alike;
        // docs/notes/lattice.md.)
        let config = IcpConfig {
            samples: 120_000,
            max_roughness_m: 1.0,
            ..Default::default()
        };
        check_recovery(false, 0.0, truth, &config, 0.01, 0.001);
        check_recovery(false, 0.0, truth.inverse(), &config, 0.01, 0.001);
        // Noisy returns scattered over the pixels, walls kept (the default).
        let config = IcpConfig {
            samples: 120_000,
            ..Default::default()
        };
        check_recovery(true, 0.15, truth, &config, 0.1, 0.03);
        check_recovery(true, 0.15, truth.inverse(), &config, 0.1, 0.03);
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
        check_recovery(true, 0.15, truth, &config, 0.05, 1e-9);
        check_recovery(true, 0.15, truth.inverse(), &config, 0.05, 1e-9);
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
        check_recovery(true, 0.15, truth, &config, 0.05, 1e-9);
    }

    #[test]
    fn disjoint_dsms_are_refused() {
        let a = MemPyramid::build(
            dsm((0.0, 100.0), 50, 1.0, &Isometry3::identity(), 0.0, 1, false),
            64,
        );
        let b = MemPyramid::build(
            dsm(
                (500.0, 100.0),
                50,
                1.0,
                &Isometry3::identity(),
                0.0,
                1,
                false,
            ),
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
