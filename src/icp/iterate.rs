//! The classic ICP loop on one fixed point set (Xu & Qin 2024, Sec. 3.1):
//! associate, weight, fit, update, until [`Convergence::converged`], two steps
//! in a row within a tenth of the fit's standard errors (the noise floor,
//! where association flips jitter the estimate by millimetres), or something
//! breaks (too few matches, a degenerate fit, a run-away motion). The next
//! estimate is the plain step's end or Anderson's jump along a steady creep
//! (`accelerate`); the stopping rules judge the plain step.

use nalgebra::{Isometry3, Vector6};

use super::accelerate::Anderson;
use super::associate::Association;
use super::floor::gridding_sd;
use super::robust::{smooth_only, weighted};
use super::{IcpConfig, IcpError, IcpStatus, Metric};
use crate::fit::{
    point_to_plane_prior, point_to_point, Correspondence, DegeneracyRule, FitSigma, RotationPrior,
};

/// Where one run of the loop over a fixed point set ended.
pub(super) struct Phase {
    pub t_ref_moving: Isometry3<f64>,
    pub status: IcpStatus,
    pub iterations: usize,
    pub constraint_ratio: f64,
    pub sigma: FitSigma,
    /// Most inliers seen in one iteration (a later collapse means divergence).
    pub peak_inliers: usize,
    /// When the loop ran out of iterations and its answer is the mean of its
    /// last iterates ([`settle`]): their spread per axis (x, y, z m, roll,
    /// pitch, yaw rad), part of the answer's uncertainty.
    pub jitter: Option<Vector6<f64>>,
}

impl Default for Phase {
    fn default() -> Self {
        Phase {
            t_ref_moving: Isometry3::identity(),
            status: IcpStatus::MaxIterations,
            iterations: 0,
            constraint_ratio: 1.0,
            sigma: FitSigma::default(),
            peak_inliers: 0,
            jitter: None,
        }
    }
}

/// The stopping rule of one level: motions are measured in metres at the
/// overlap's edge (translation plus angle times the lever arm).
pub(super) struct Convergence {
    /// Half diagonal of the overlap.
    pub lever_m: f64,
    /// Motion below which an update counts as zero (scaled with the level's GSD).
    pub tolerance_m: f64,
}

impl Convergence {
    fn motion_m(&self, t: &Isometry3<f64>) -> f64 {
        t.translation.vector.norm() + t.rotation.angle() * self.lever_m
    }

    /// Done when the last update is below the tolerance, or the estimate stalls.
    pub fn converged(&self, update: &Isometry3<f64>, recent: &[Isometry3<f64>]) -> bool {
        self.motion_m(update) < self.tolerance_m || self.stalled(recent)
    }

    /// At the noise floor the inlier set flips between iterations and the
    /// estimate jitters without a trend: when the net motion over the last four
    /// iterations is below 10 tolerances, the level is done (a slow drift keeps going).
    fn stalled(&self, estimates: &[Isometry3<f64>]) -> bool {
        let n = estimates.len();
        if n < 5 {
            return false;
        }
        let net = estimates[n - 1] * estimates[n - 5].inverse();
        self.motion_m(&net) < 10.0 * self.tolerance_m
    }
}

/// What one level's loop holds and refuses: the degeneracy rule of its fits
/// and the largest translation (metres) from `start` it accepts.
pub(super) struct Rules {
    pub degeneracy: DegeneracyRule,
    pub start: Isometry3<f64>,
    pub cap_m: f64,
    /// The pair's gridding floor at this level (metres, each horizontal axis:
    /// `--sigma-floor-px` pixels; the other axes their shares, see
    /// `icp::floor`): iterates that differ by less are as one to [`settle`],
    /// as they are to the reported sigmas.
    pub floor_m: f64,
}

impl Rules {
    /// A translation from the start beyond the cap: the loop runs away.
    fn moved_too_far(&self, t: &Isometry3<f64>) -> bool {
        (t.translation.vector - self.start.translation.vector).norm() > self.cap_m
    }
}

/// The loop on one point set, matched by `associate` at a given estimate.
pub(super) fn iterate(
    mut t_ref_moving: Isometry3<f64>,
    min_inliers: usize,
    stop: &Convergence,
    config: &IcpConfig,
    rules: &Rules,
    associate: &mut dyn FnMut(&Isometry3<f64>) -> Result<Association, IcpError>,
) -> Result<Phase, IcpError> {
    let mut phase = Phase {
        t_ref_moving,
        ..Phase::default()
    };
    let mut recent: Vec<Isometry3<f64>> = vec![t_ref_moving];
    // steps below two tolerances are the loop's jitter: taken plain
    let mut accelerate = Anderson::new(&t_ref_moving, stop.lever_m, 2.0 * stop.tolerance_m);
    let mut was_quiet = false;
    for _ in 0..config.max_iter {
        phase.iterations += 1;
        // 1. associate: exact grid NN of every query, beyond tau dropped
        let assoc = associate(&t_ref_moving)?;
        if assoc.corrs.len() < min_inliers {
            phase.status = IcpStatus::TooFewInliers;
            break;
        }
        phase.peak_inliers = phase.peak_inliers.max(assoc.corrs.len());
        // 2. weight: rough places out, Tukey biweights outside each cell's band
        let (corrs, cells) = smooth_only(assoc.corrs, &assoc.cells, config.max_roughness_m);
        let corrs = weighted(corrs, &cells, config.metric);
        // 3. fit the update that brings the matches together
        let prior = config.rotation_prior(&t_ref_moving, &rules.start);
        let Some(step) = fit(&corrs, config, &rules.degeneracy, prior.as_ref()) else {
            // not one direction the surface constrains
            phase.status = IcpStatus::Degenerate;
            break;
        };
        if let Some(sigma) = step.sigma {
            phase.sigma = sigma;
        }
        phase.constraint_ratio = step.constraint_ratio;
        // 4. update the estimate and check the stopping rule (on the plain step)
        let plain = step.update * t_ref_moving;
        phase.t_ref_moving = plain;
        tracing::trace!(t = ?plain.translation.vector, n = corrs.len(), "iteration");
        if rules.moved_too_far(&plain) {
            phase.status = IcpStatus::Diverged;
            break;
        }
        recent.push(plain);
        // two steps in a row within a tenth of the fit's standard errors: the
        // loop walks in its own noise (association flips), nothing to gain
        let quiet = step
            .sigma
            .as_ref()
            .is_some_and(|s| within_noise(&step.update, s));
        let at_noise_floor = quiet && was_quiet;
        was_quiet = quiet;
        if at_noise_floor || stop.converged(&step.update, &recent) {
            phase.status = IcpStatus::Converged;
            break;
        }
        // 5. the next estimate: the plain step's end or Anderson's jump (never
        // beyond the cap)
        let next = accelerate.next(&t_ref_moving, &plain);
        t_ref_moving = if rules.moved_too_far(&next) {
            plain
        } else {
            next
        };
    }
    if phase.status == IcpStatus::MaxIterations {
        // the overlap's RMS radius: half its diagonal / sqrt(3) (a rectangle)
        let radius_m = stop.lever_m / 3f64.sqrt();
        settle(&mut phase, &recent, &gridding_sd(rules.floor_m, radius_m));
    }
    Ok(phase)
}

/// A step this share of the fit's standard errors is the noise floor.
pub(super) const NOISE_SHARE: f64 = 0.1;

/// True when every axis of `update` is within [`NOISE_SHARE`] of its
/// standard error (a held axis, with none, must not move).
fn within_noise(update: &Isometry3<f64>, sigma: &FitSigma) -> bool {
    let (t, r) = (update.translation.vector, update.rotation.scaled_axis());
    (0..3).all(|k| {
        t[k].abs() <= NOISE_SHARE * sigma.trans_m[k] + 1e-12
            && r[k].abs() <= NOISE_SHARE * sigma.rot_deg[k].to_radians() + 1e-15
    })
}

/// Iterates averaged when a loop runs out of iterations without a trend.
const SETTLE_WINDOW: usize = 10;

/// A loop that ran out of iterations while jittering about a point (the
/// inlier set flips, each step overshoots by decimetres on a rough cost) has
/// found that point: their mean is a better answer than the last iterate.
/// Without a trend (the two halves of the last [`SETTLE_WINDOW`] iterates
/// agree within the fit's standard errors with the gridding floor `floor`
/// added per axis, as the reported sigmas have it) the answer becomes that
/// mean and the iterates' spread its `jitter`; with a jitter within those
/// standard errors too, the loop counts as converged. A drift keeps its last
/// iterate and `MaxIterations`.
/// (A 2 m lidar grid of Tommy Thompson Park against its 1 m DSM cycled by
/// 5 cm along y, its fit's sigma 0.8 cm, the floor 10 cm: `MaxIterations`
/// 2 cm from the truth before the floor counted.)
fn settle(phase: &mut Phase, recent: &[Isometry3<f64>], floor: &Vector6<f64>) {
    let n = recent.len();
    if n < SETTLE_WINDOW + 1 {
        return;
    }
    let window = &recent[n - SETTLE_WINDOW..];
    let last = window[SETTLE_WINDOW - 1];
    // each iterate as a 6-vector about the last (translation, rotation vector)
    let about = |t: &Isometry3<f64>| {
        let d = t * last.inverse();
        let (v, r) = (d.translation.vector, d.rotation.scaled_axis());
        Vector6::new(v.x, v.y, v.z, r.x, r.y, r.z)
    };
    let mean = |ts: &[Isometry3<f64>]| ts.iter().map(about).sum::<Vector6<f64>>() / ts.len() as f64;
    let half = SETTLE_WINDOW / 2;
    let (early, late, all) = (mean(&window[..half]), mean(&window[half..]), mean(window));
    let spread = window
        .iter()
        .map(|t| (about(t) - all).map(|v| v * v))
        .sum::<Vector6<f64>>()
        .map(|v| (v / SETTLE_WINDOW as f64).sqrt());
    let sigma = &phase.sigma;
    let scale = |k: usize| {
        let s = if k < 3 {
            sigma.trans_m[k]
        } else {
            sigma.rot_deg[k - 3].to_radians()
        };
        // a held axis (no sigma) gets no floor: it must not move
        if s > 0.0 {
            s.hypot(floor[k])
        } else {
            s
        }
    };
    // axes the fit gave no sigma (held, or not estimated) must not move at all
    let within =
        |v: &Vector6<f64>, factor: f64| (0..6).all(|k| v[k].abs() <= factor * scale(k) + 1e-9);
    if !within(&(late - early), 1.0) {
        tracing::trace!(trend = ?(late - early), ?spread, ?floor, "not settled: a trend");
        return;
    }
    phase.t_ref_moving = Isometry3::from_parts(
        nalgebra::Translation3::from(all.fixed_rows::<3>(0).into_owned()),
        nalgebra::UnitQuaternion::from_scaled_axis(all.fixed_rows::<3>(3).into_owned()),
    ) * last;
    phase.jitter = Some(spread);
    if within(&spread, 1.0) {
        phase.status = IcpStatus::Converged;
    } else {
        tracing::trace!(?spread, sigma = ?phase.sigma, ?floor, "settled at the mean, jitter beyond the sigmas");
    }
}

/// One fitted step; `sigma` only from the point-to-plane fits.
struct Step {
    update: Isometry3<f64>,
    constraint_ratio: f64,
    sigma: Option<FitSigma>,
}

/// Point-to-plane (both plane metrics, degenerate directions held by `rule`)
/// or Kabsch; None when the plane fit constrains no direction. A failed
/// Kabsch is a zero step.
fn fit(
    corrs: &[Correspondence],
    config: &IcpConfig,
    rule: &DegeneracyRule,
    prior: Option<&RotationPrior>,
) -> Option<Step> {
    match config.metric {
        Metric::PointToPlane | Metric::PointToSurface => {
            let f = point_to_plane_prior(corrs, config.model, rule, prior)?;
            Some(Step {
                update: f.update,
                constraint_ratio: f.constraint_ratio,
                sigma: Some(f.sigma),
            })
        }
        Metric::PointToPoint => Some(Step {
            update: point_to_point(corrs, config.model).unwrap_or_else(Isometry3::identity),
            constraint_ratio: 1.0,
            sigma: None,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn shift(x_m: f64) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::new(x_m, 0.0, 0.0), UnitQuaternion::identity())
    }

    fn phase_with_sigma(trans_m: f64) -> Phase {
        Phase {
            sigma: FitSigma {
                rot_deg: [0.01; 3],
                trans_m: [trans_m; 3],
            },
            ..Phase::default()
        }
    }

    #[test]
    fn a_jitter_without_trend_settles_at_its_mean() {
        // +-5 cm about x = 1 m, sigma 8 cm: the mean, converged
        let jitter: Vec<_> = (0..20)
            .map(|k| shift(1.0 + if k % 2 == 0 { 0.05 } else { -0.05 }))
            .collect();
        let mut phase = phase_with_sigma(0.08);
        settle(&mut phase, &jitter, &Vector6::zeros());
        assert!((phase.t_ref_moving.translation.vector.x - 1.0).abs() < 1e-9);
        assert_eq!(phase.status, IcpStatus::Converged);
        // the same jitter with a 2 cm sigma: the mean, still not converged
        let mut phase = phase_with_sigma(0.02);
        settle(&mut phase, &jitter, &Vector6::zeros());
        assert!((phase.t_ref_moving.translation.vector.x - 1.0).abs() < 1e-9);
        assert_eq!(phase.status, IcpStatus::MaxIterations);
        // with a 10 cm gridding floor the 5 cm jitter is within: converged,
        // the jitter kept for the covariance
        let mut phase = phase_with_sigma(0.02);
        settle(&mut phase, &jitter, &Vector6::repeat(0.1));
        assert_eq!(phase.status, IcpStatus::Converged);
        let spread = phase.jitter.expect("the mean was taken");
        assert!(
            (spread.x - 0.05).abs() < 1e-9 && spread.y.abs() < 1e-12,
            "{spread:?}"
        );
    }

    #[test]
    fn a_drift_keeps_its_last_iterate() {
        let drift: Vec<_> = (0..20).map(|k| shift(0.03 * k as f64)).collect();
        let mut phase = phase_with_sigma(0.08);
        phase.t_ref_moving = drift[19];
        settle(&mut phase, &drift, &Vector6::zeros());
        assert_eq!(phase.t_ref_moving, drift[19]);
        assert_eq!(phase.status, IcpStatus::MaxIterations);
        assert_eq!(phase.jitter, None);
        // a drift of 15 cm between the halves stays one beyond a 10 cm floor
        let mut phase = phase_with_sigma(0.08);
        settle(&mut phase, &drift, &Vector6::repeat(0.1));
        assert_eq!(phase.status, IcpStatus::MaxIterations);
        // too few iterates to judge
        let mut phase = phase_with_sigma(0.08);
        settle(&mut phase, &drift[..5], &Vector6::zeros());
        assert_eq!(phase.status, IcpStatus::MaxIterations);
    }

    #[test]
    fn converged_on_a_small_update_or_a_stall_only() {
        let stop = Convergence {
            lever_m: 100.0,
            tolerance_m: 1e-3,
        };
        assert!(stop.converged(&shift(5e-4), &[]));
        assert!(!stop.converged(&shift(2e-3), &[shift(0.0)]));
        // jitter without a trend: net motion over four steps below 10 tolerances
        let jitter: Vec<_> = [0.0, 0.004, 0.001, 0.005, 0.002].map(shift).to_vec();
        assert!(stop.converged(&shift(2e-3), &jitter));
        // a steady drift of 4 mm per step keeps going
        let drift: Vec<_> = [0.0, 0.004, 0.008, 0.012, 0.016].map(shift).to_vec();
        assert!(!stop.converged(&shift(4e-3), &drift));
        // a rotation counts at the lever arm: 1e-4 rad at 100 m is 1 cm
        let turn = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 1e-4),
        );
        assert!(!stop.converged(&turn, &[]));
    }
}
