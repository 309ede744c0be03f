//! The restart check of a pair: the full-resolution loop run again from the
//! answer pushed a few pixels along its weakest horizontal direction, once
//! each way (and across it, unless the fit is pinned down there and those
//! find one minimum).
//!
//! A sandwich standard error is the curvature of the cost at the minimum the
//! loop settled in. On a narrow strip of small city tiles that minimum is a
//! notch in a shallow valley: started at the truth, the loop walks 0.4-1.8 m
//! along the strip and reports 6-7 cm (20 x 20 grid of 128 m tiles,
//! docs/measurements.md "Restart check"). Where the data pin the pair down, a
//! restart a few pixels off comes back to the same place within its noise, and
//! the answer and its covariance stand. Where it does not, the minimum is not
//! unique at the claimed precision: the answer stays, and each restart's gap
//! beyond the noise is added to the covariance along the gap (as the backward
//! check does), so the graph learns from the pair only what it pins down.
//! When both restarts settle together and away from the answer, the ladder sat
//! in a side notch (it came in from one start): the place both sides fall
//! into becomes the answer, with the restart's own information.
//!
//! A pair found not unique along its weakest direction has side basins, and
//! they can lie along its well-measured direction too; so can those of a pair
//! the data fix across to worse than the gridding floor (on the sparse TIN
//! grid of 128 m tiles, two pairs sat 1.1 and 3.9 m off along their
//! well-measured x at 14 sigma). Such pairs are checked the same way across.
//! Pairs pinned down to the floor with one minimum (the well-posed 0.5-1 km
//! pairs) pay for two restarts only.
//!
//! A restart that runs off (diverges or loses its matches) from a few pixels
//! beside the answer says the answer is no basin the loop returns to: the
//! check does not confirm it (`RestartCheck::confirms`), and the pair becomes
//! `Ambiguous` like one its backward check does not confirm
//! (`choice::unconfirmed`). On the 50 x 50 grid of 64 m tiles this happened
//! to 7 of 2,787 converged pairs, tile_159 -> tile_160 among them (21 m off
//! at 21 sigma); on 2,700 converged pairs of 128 m tiles and the batteries'
//! small collections, to none.

use nalgebra::{Isometry3, Matrix2, Matrix6, Translation3, UnitQuaternion, Vector3};

use super::backward::{inflate, measured_projector, Disagreement, GapTest};
use super::config::LADDER_SAMPLES;
use super::level::full_resolution;
use super::{IcpConfig, IcpError, IcpResult, IcpStatus, RestartCheck};
use crate::fit::FitInformation;
use crate::grid::Pyramid;

/// How far the restarts start from the answer: this many full-resolution
/// pixels, or three of its standard errors along the direction if more.
pub const RESTART_PIXELS: f64 = 2.0;
/// Restart gaps below this many pixels are the loop's convergence scatter.
pub const MIN_GAP_PIXELS: f64 = 0.1;
/// A fit whose own standard error across its weakest horizontal direction is
/// within this many pixels (the default gridding floor) sits in one sharp
/// minimum there (the 0.5-1 km well-posed pairs: 0.02 pixel); above it, the
/// restarts go across as well.
pub const PINNED_ACROSS_PIXELS: f64 = 0.05;

/// The weakest measured horizontal direction of `result` (unit, x and y) and
/// its standard error, metres; None without information or with both
/// horizontal axes held.
fn weakest_horizontal(result: &IcpResult) -> Option<(Vector3<f64>, f64)> {
    let info = result.information.as_ref()?;
    let c = info.covariance_6x6.fixed_view::<2, 2>(0, 0).into_owned();
    let c: Matrix2<f64> = (c + c.transpose()) * 0.5;
    let eig = c.symmetric_eigen();
    let k = if eig.eigenvalues[0] >= eig.eigenvalues[1] {
        0
    } else {
        1
    };
    let variance = eig.eigenvalues[k];
    if !(variance > 0.0 && variance.is_finite()) {
        return None;
    }
    let v = eig.eigenvectors.column(k);
    Some((Vector3::new(v[0], v[1], 0.0), variance.sqrt()))
}

/// Runs the restart check on `forward` and folds it into its covariance.
/// Only for answers with information that ran to an end (not diverged, not
/// too few matches); a restart that cannot run is skipped. A pair whose
/// minimum proves not unique along its weakest direction (a gap joined the
/// covariance, or the answer moved), or whose own standard error across it
/// is above [`PINNED_ACROSS_PIXELS`], is checked across as well.
pub(super) fn check_restarts<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
    forward: IcpResult,
    limits: (f64, f64),
) -> IcpResult {
    if matches!(
        forward.status,
        IcpStatus::TooFewInliers | IcpStatus::Diverged
    ) {
        return forward;
    }
    let Some((direction, sigma_m)) = weakest_horizontal(&forward) else {
        return forward;
    };
    let checked = restart_by(
        reference,
        moving,
        config,
        forward,
        (direction, step_m(sigma_m, limits.0)),
        limits,
    );
    let across = Vector3::new(-direction.y, direction.x, 0.0);
    let Some(sigma_m) = sigma_along(&checked, &across) else {
        return checked;
    };
    let pinned = sigma_m <= PINNED_ACROSS_PIXELS * limits.0;
    if pinned && !checked.restart.is_some_and(|c| c.found_side_basins()) {
        return checked;
    }
    let push = (across, step_m(sigma_m, limits.0));
    check_across(reference, moving, config, checked, push, limits)
}

/// How far a restart starts from the answer along a direction where the fit
/// has standard error `sigma_m`, at full-resolution pixels of `pixel_m`.
fn step_m(sigma_m: f64, pixel_m: f64) -> f64 {
    (RESTART_PIXELS * pixel_m).max(3.0 * sigma_m)
}

/// The restart check with pushes of `push` (a horizontal unit across the
/// weakest direction, metres) on `checked`, merged with its check along.
fn check_across<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
    checked: IcpResult,
    push: (Vector3<f64>, f64),
    limits: (f64, f64),
) -> IcpResult {
    let along = checked.restart.unwrap_or_default();
    let mut checked = restart_by(reference, moving, config, checked, push, limits);
    if let Some(across) = checked.restart.as_mut() {
        *across = along.and(across);
    }
    checked
}

/// The standard error of `result` along the horizontal unit `direction`,
/// metres; None without information.
fn sigma_along(result: &IcpResult, direction: &Vector3<f64>) -> Option<f64> {
    let c = result.information.as_ref()?.covariance_6x6;
    let variance = (direction.transpose() * c.fixed_view::<3, 3>(0, 0) * direction)[(0, 0)];
    (variance > 0.0 && variance.is_finite()).then(|| variance.sqrt())
}

/// The restart check with pushes of `step_m` along `direction`.
fn restart_by<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
    mut forward: IcpResult,
    (direction, step_m): (Vector3<f64>, f64),
    limits: (f64, f64),
) -> IcpResult {
    let Some(centroid) = forward.information.as_ref().map(|i| i.centroid) else {
        return forward;
    };
    // a restart only asks where the loop settles: the ladder's sample count
    // is plenty for that (its own covariance enters the test)
    let config = &IcpConfig {
        samples: config.samples.min(LADDER_SAMPLES),
        ..config.clone()
    };
    let mut check = RestartCheck::default();
    // the two restarts are independent: run side by side (each is parallel
    // over its blocks too; this fills the serial parts of the other), kept
    // in the order + then -
    let run = |sign: f64| {
        restart(
            reference,
            moving,
            config,
            &forward,
            &(direction * (sign * step_m)),
            limits,
        )
    };
    let (plus, minus) = rayon::join(|| run(1.0), || run(-1.0));
    let mut restarts = Vec::with_capacity(2);
    for ran in [plus, minus] {
        match ran {
            Ok(r) if !matches!(r.status, IcpStatus::TooFewInliers | IcpStatus::Diverged) => {
                restarts.push(r)
            }
            Ok(r) => {
                tracing::debug!(status = ?r.status, "restart did not finish");
                check.lost += 1;
            }
            Err(e) => tracing::debug!(error = %e, "restart could not run"),
        }
    }
    check.tried = 2;
    check.ran = restarts.len();
    // both restarts settle together and away from the answer: the ladder sat
    // in a side notch, and the basin both sides fall into is the answer
    if let [a, b] = &restarts[..] {
        let apart = |x: &IcpResult, y: &IcpResult| {
            gap(&x.t_ref_moving, &y.t_ref_moving, &centroid)
                .shift_m
                .norm()
        };
        // together: closer to each other than half their way from the answer
        // (restarts that run out of iterations jitter beyond their noise)
        let together = apart(a, b) < 0.5 * apart(&forward, a).min(apart(&forward, b));
        if beyond_noise(&forward, a) && beyond_noise(&forward, b) && together {
            let moved = gap(&forward.t_ref_moving, &a.t_ref_moving, &centroid);
            check.moved_m = moved.shift_m.norm();
            tracing::debug!(shift_m = ?moved.shift_m, "both restarts agree elsewhere");
            let kept = b.clone();
            forward = IcpResult {
                ambiguity: forward.ambiguity,
                iterations: forward.iterations + a.iterations,
                ..a.clone()
            };
            restarts = vec![kept];
        }
    }
    let Some(centroid) = forward.information.as_ref().map(|i| i.centroid) else {
        return forward;
    };
    for restarted in &restarts {
        check.gap_m = check.gap_m.max(
            gap(&forward.t_ref_moving, &restarted.t_ref_moving, &centroid)
                .shift_m
                .norm(),
        );
        let Some(d) = measured_gap(&forward, restarted, &centroid) else {
            continue;
        };
        let Some(info) = forward.information.as_mut() else {
            break;
        };
        let test = d.test(&joint(info, restarted));
        tracing::debug!(shift_m = ?d.shift_m, chi_square = test.chi_square, status = ?restarted.status, "restart");
        if test.beyond_noise() {
            check.beyond_noise += 1;
        }
        if widens(&test, d.shift_m.norm(), limits.0) {
            check.widened += 1;
            inflate(info, &d.model_error(&test));
        }
    }
    forward.restart = Some(check);
    forward
}

/// Whether a restart gap of `gap_m` joins the covariance. A restart sees the
/// same data and samples as the answer, so under one minimum it comes back to
/// it (well-posed pairs: within micrometres): a gap of a tenth of a pixel or
/// more that the noise does not cover (chi-square above 1) is a direction the
/// cost hardly rises along. Smaller gaps are the loop's convergence scatter,
/// unless beyond the noise.
fn widens(test: &GapTest, gap_m: f64, pixel_m: f64) -> bool {
    test.beyond_noise() || (test.chi_square > 1.0 && gap_m >= MIN_GAP_PIXELS * pixel_m)
}

/// The yardstick of a gap between `fit` and a restart: the restart saw the
/// same data, so under a unique minimum it comes back within the noise of one
/// fit; the sum of the two covariances is the same lenient yardstick as the
/// backward check's.
fn joint(fit: &FitInformation, restarted: &IcpResult) -> Matrix6<f64> {
    match &restarted.information {
        Some(r) => fit.covariance_6x6 + r.covariance_6x6,
        None => fit.covariance_6x6 * 2.0,
    }
}

/// True when `other` ended beyond the noise of `fit` and itself (false
/// without information to judge).
fn beyond_noise(fit: &IcpResult, other: &IcpResult) -> bool {
    let Some(info) = fit.information.as_ref() else {
        return false;
    };
    measured_gap(fit, other, &info.centroid)
        .is_some_and(|d| d.test(&joint(info, other)).beyond_noise())
}

/// The gap from `fit` to a restart at `at`, along the directions the restart
/// measured: along a direction it held (pushed off steep terrain, a restart
/// can keep too few matches to move there and stays where it was pushed:
/// xdem-data's Svalbard crops, 20 m pixels, 39 m of a 40 m push) it says
/// nothing about where the minimum lies. None without its information.
fn measured_gap(fit: &IcpResult, restarted: &IcpResult, at: &Vector3<f64>) -> Option<Disagreement> {
    let info = restarted.information.as_ref()?;
    let range = measured_projector(&info.covariance_6x6, info.radius_m);
    let g = range * gap(&fit.t_ref_moving, &restarted.t_ref_moving, at).gap();
    Some(Disagreement {
        shift_m: g.fixed_rows::<3>(0).into_owned(),
        rotation_rad: g.fixed_rows::<3>(3).into_owned(),
    })
}

/// The left perturbation from `forward` to `other` at `at`: D = other
/// forward^-1, its translation D(at) - at and its rotation vector.
fn gap(forward: &Isometry3<f64>, other: &Isometry3<f64>, at: &Vector3<f64>) -> Disagreement {
    let d = other * forward.inverse();
    let p = nalgebra::Point3::from(*at);
    Disagreement {
        shift_m: d.transform_point(&p) - p,
        rotation_rad: d.rotation.scaled_axis(),
    }
}

/// The full-resolution level run from `forward` moved by `push` (metres), with
/// the same rules as the last rung of the ladder.
fn restart<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
    forward: &IcpResult,
    push: &Vector3<f64>,
    (pixel_m, radius_m): (f64, f64),
) -> Result<IcpResult, IcpError> {
    let start = Translation3::from(*push) * forward.t_ref_moving;
    let centre = Vector3::from(forward.centre_m);
    // the rotation prior holds to the georeferencing, as on the ladder
    full_resolution(
        reference,
        moving,
        config,
        (&start, UnitQuaternion::identity()),
        &centre,
        (pixel_m, radius_m + push.norm()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::MemPyramid;

    /// Gaps within the 0.999 quantile widen the sigmas once they exceed the
    /// noise (chi-square > 1) and a tenth of a pixel; micrometre scatter and
    /// gaps the noise covers do not; gaps beyond the noise always do.
    #[test]
    fn which_restart_gaps_widen_the_sigmas() {
        let test = |chi_square: f64| GapTest { chi_square, dof: 6 };
        assert!(widens(&test(10.9), 0.98, 0.5), "a metre at 3.3 sigma");
        assert!(!widens(&test(10.9), 1e-6, 0.5), "convergence scatter");
        assert!(!widens(&test(0.8), 0.3, 0.5), "within one sigma");
        assert!(widens(&test(63.6), 1e-6, 0.5), "beyond the noise");
    }

    fn result_with(covariance: Matrix6<f64>) -> IcpResult {
        IcpResult {
            information: Some(FitInformation {
                info_6x6: Matrix6::zeros(),
                covariance_6x6: covariance,
                sigma: [None; 6],
                degenerate: Vec::new(),
                centroid: Vector3::zeros(),
                effective_samples: 1.0,
                radius_m: 100.0,
                gridding_6x6: Matrix6::zeros(),
            }),
            ..IcpResult::converged_at(Isometry3::identity(), [0.0; 3])
        }
    }

    #[test]
    fn the_weakest_horizontal_direction_is_the_largest_xy_variance() {
        let mut c =
            Matrix6::from_diagonal(&nalgebra::Vector6::new(0.01, 0.04, 1e-4, 1e-8, 1e-8, 1e-8));
        let (d, s) = weakest_horizontal(&result_with(c)).unwrap();
        assert!((d.y.abs() - 1.0).abs() < 1e-12 && d.x.abs() < 1e-12);
        assert!((s - 0.2).abs() < 1e-12);
        // a correlated pair: the diagonal's long axis
        c[(0, 0)] = 0.02;
        c[(1, 1)] = 0.02;
        c[(0, 1)] = 0.015;
        c[(1, 0)] = 0.015;
        let (d, _) = weakest_horizontal(&result_with(c)).unwrap();
        assert!((d.x * d.y - 0.5).abs() < 1e-9, "{d:?}");
        // both horizontal axes held: nothing to push along
        c.fixed_view_mut::<2, 2>(0, 0).fill(0.0);
        assert!(weakest_horizontal(&result_with(c)).is_none());
    }

    /// A pair of 200 x 200 px DSMs at 0.5 m of `surface`, the moving one
    /// 60 m east and written so that `shift` registers it.
    fn pair(surface: fn(f64, f64) -> f64, shift: Vector3<f64>) -> (MemPyramid, MemPyramid) {
        crate::icp::testing::side_by_side(surface, 60.0, shift)
    }

    /// Relief in both directions: one minimum.
    fn hills(x: f64, y: f64) -> f64 {
        5.0 * (x / 4.0).sin() * (y / 5.0).cos() + 3.0 * (y / 3.0 + x / 7.0).sin()
    }

    /// Ridges every 8 m along y over relief in x: minima 8 m apart in y.
    fn ridges(x: f64, y: f64) -> f64 {
        1.5 * (y * std::f64::consts::TAU / 8.0).sin() + 5.0 * (x / 9.0).sin()
    }

    /// Translation only, at full resolution, searched within a metre: the
    /// ridges repeat, a wider search would be ambiguous.
    fn near_the_truth() -> IcpConfig {
        IcpConfig {
            model: crate::fit::Model::Translation,
            max_level: 0,
            max_displacement_m: 1.0,
            ..IcpConfig::default()
        }
    }

    fn restarted(surface: fn(f64, f64) -> f64, push_m: f64) -> (IcpResult, IcpResult) {
        let truth = Vector3::new(0.3, -0.2, 0.4);
        let (reference, moving) = pair(surface, truth);
        let config = near_the_truth();
        let forward = crate::icp::register(&reference, &moving, &config).unwrap();
        let at = nalgebra::Point3::from(forward.information.as_ref().unwrap().centroid);
        let shift = forward.t_ref_moving.transform_point(&at) - at;
        assert!(
            (shift - truth).norm() < 0.05,
            "{shift:?} {:?} {:?} it {}",
            forward.status,
            forward.ambiguity,
            forward.iterations
        );
        let checked = restart_by(
            &reference,
            &moving,
            &config,
            forward.clone(),
            (Vector3::y(), push_m),
            (0.5, 10.0),
        );
        (forward, checked)
    }

    #[test]
    fn a_unique_minimum_keeps_its_answer_and_covariance() {
        let (forward, checked) = restarted(hills, 1.0);
        let check = checked.restart.unwrap();
        assert_eq!((check.ran, check.beyond_noise), (2, 0), "{check:?}");
        assert!(check.gap_m < 0.01, "{check:?}");
        assert_eq!(checked.t_ref_moving, forward.t_ref_moving);
        assert_eq!(checked.information, forward.information);
    }

    #[test]
    fn a_restart_in_another_minimum_widens_the_sigma_along_the_gap() {
        let (forward, checked) = restarted(ridges, 5.0);
        let check = checked.restart.unwrap();
        assert!(check.beyond_noise >= 1 && check.gap_m > 3.0, "{check:?}");
        assert_eq!(checked.t_ref_moving, forward.t_ref_moving);
        let sigma = |r: &IcpResult, k: usize| r.information.as_ref().unwrap().sigma[k].unwrap();
        assert!(sigma(&forward, 1) < 0.1, "{:?}", forward.information);
        assert!(sigma(&checked, 1) > 2.0, "{:?}", checked.information);
        // the gap is along y: x and z keep nearly their noise
        assert!(sigma(&checked, 0) < 3.0 * sigma(&forward, 0) + 0.05);
    }

    /// A pair whose weakest direction has side basins is checked across it
    /// as well (four restarts); the across check of relief with one minimum
    /// leaves the answer where it was.
    #[test]
    fn side_basins_along_the_weakest_direction_send_restarts_across() {
        let (forward, checked) = restarted(ridges, 5.0);
        let along = checked.restart.unwrap();
        assert!(along.found_side_basins() && along.tried == 2, "{along:?}");
        let config = near_the_truth();
        let (reference, moving) = pair(ridges, Vector3::new(0.3, -0.2, 0.4));
        let across = check_across(
            &reference,
            &moving,
            &config,
            checked.clone(),
            (Vector3::x(), 1.0),
            (0.5, 10.0),
        );
        let both = across.restart.unwrap();
        assert_eq!((both.tried, both.ran), (4, 4), "{both:?}");
        assert!(both.widened >= along.widened && both.gap_m >= along.gap_m);
        assert_eq!(both.moved_m, 0.0, "{both:?}");
        let x = |r: &IcpResult| r.t_ref_moving.translation.vector.x;
        assert!((x(&across) - x(&forward)).abs() < 1e-3);
        // one sharp minimum: no side basins, no restarts across
        let (forward, unique) = restarted(hills, 1.0);
        assert!(!unique.restart.unwrap().found_side_basins());
        assert_eq!(forward.restart.map(|c| c.tried), Some(2));
    }

    #[test]
    fn the_gap_is_the_left_perturbation_at_the_centroid() {
        let forward = Isometry3::from_parts(
            Translation3::new(5.0, -3.0, 1.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.01),
        );
        let d = Isometry3::from_parts(
            Translation3::new(0.2, 0.0, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.001),
        );
        let at = Vector3::new(100.0, 50.0, 10.0);
        // D about `at`: a rotation about it and then the shift
        let about = Translation3::from(at) * d * Translation3::from(-at);
        let g = gap(&forward, &(about * forward), &at);
        assert!((g.shift_m - Vector3::new(0.2, 0.0, 0.0)).norm() < 1e-9);
        assert!((g.rotation_rad - Vector3::new(0.0, 0.0, 0.001)).norm() < 1e-12);
    }
}
