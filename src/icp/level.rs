//! One level of the coarse-to-fine ladder: sample the moving DSM at that level,
//! match against the reference's same level, run the loop (first on an even
//! subset of the samples, then on all of them), and judge how it ended.

use nalgebra::{Isometry3, Matrix6, UnitQuaternion, Vector3, Vector6};

use super::associate::{block_order, Association, Distances, Matcher, QueryMemo};
use super::backward::inflate;
use super::config::{LADDER_SAMPLES, PAPER_TAU_M};
use super::final_rule;
use super::iterate::{iterate, Convergence, Phase, Rules};
use super::robust::{smooth_only, weighted};
use super::sample::{pixel_window, sample_overlap};
use super::start::moved_overlap;
use super::{IcpConfig, IcpError, IcpResult, IcpStatus, Metric, NnStatsSummary};
use crate::fit::{fit_information_with, Correspondence, DegeneracyRule, FitInformation, FitSigma};
use crate::geo::rigid::isometry_to_world;
use crate::geo::Bounds;
use crate::grid::{Grid, Pyramid};
use crate::nn::{NnStats, PixelFrame};

/// One level, sampled and ready to run.
pub(super) struct Level<'a, R> {
    reference: &'a R,
    index: usize,
    overlap: Bounds,
    /// Query points: local x, y about the overlap centre, world heights (until `run`).
    samples: Vec<Vector3<f64>>,
    config: &'a IcpConfig,
}

/// How one level ended, in the local frame.
pub(super) struct LevelOutcome {
    pub t_ref_moving: Isometry3<f64>,
    /// Where the registration started (the rotation prior is about it).
    start: Isometry3<f64>,
    pub status: IcpStatus,
    iterations: usize,
    constraint_ratio: f64,
    sigma: FitSigma,
    /// The spread of the iterates whose mean the answer is (`Phase::jitter`).
    jitter: Option<Vector6<f64>>,
    /// The matches at the returned transform, over every sample.
    final_association: Association,
    nn: NnStats,
}

impl<'a, R: Pyramid> Level<'a, R> {
    /// Samples the moving DSM inside `overlap` at level `index` (coarse levels
    /// only bring the estimate near, so they take at most `LADDER_SAMPLES`).
    pub fn sample<M: Pyramid>(
        reference: &'a R,
        moving: &M,
        index: usize,
        overlap: &Bounds,
        origin_xy: &Vector3<f64>,
        config: &'a IcpConfig,
    ) -> Result<Self, IcpError> {
        let mut mov = moving.open_level(index).map_err(IcpError::Read)?;
        let sample_frame = PixelFrame::new(&mov.geotransform(), origin_xy);
        let count = if index == 0 {
            config.samples
        } else {
            config.samples.min(LADDER_SAMPLES)
        };
        let seed = config.seed ^ index as u64;
        let samples = sample_overlap(&mut mov, &sample_frame, overlap, count, seed);
        if let Some(e) = mov.take_error() {
            return Err(IcpError::Read(e));
        }
        if samples.points.is_empty() {
            return Err(IcpError::EmptyOverlap);
        }
        Ok(Level {
            reference,
            index,
            overlap: *overlap,
            samples: samples.points,
            config,
        })
    }

    /// A local frame origin for the whole registration: the overlap centre at
    /// the mean sampled height (any fixed value works; this keeps z small).
    pub fn origin(&self, origin_xy: &Vector3<f64>) -> Vector3<f64> {
        let points = &self.samples;
        let mean_z = points.iter().map(|p| p.z).sum::<f64>() / points.len() as f64;
        Vector3::new(origin_xy.x, origin_xy.y, mean_z)
    }

    /// Runs the level from `t_ref_moving` (local frame about `origin`) with
    /// outlier threshold `tau_m` and the loop's `rules`.
    pub fn run(
        mut self,
        origin: &Vector3<f64>,
        t_ref_moving: Isometry3<f64>,
        tau_m: f64,
        rules: &Rules,
    ) -> Result<LevelOutcome, IcpError> {
        let config = self.config;
        for p in &mut self.samples {
            p.z -= origin.z;
        }
        let ref_gt = self
            .reference
            .open_level(self.index)
            .map_err(IcpError::Read)?
            .geotransform();
        let scale = (1u64 << self.index) as f64;
        let matcher = Matcher {
            reference: self.reference,
            level: self.index,
            frame: PixelFrame::new(&ref_gt, origin),
            tau_m,
            metric: config.metric,
            distances: Distances::Bound,
        };
        block_order(&mut self.samples, &matcher.frame, 256);
        let stop = Convergence {
            lever_m: self.overlap.half_diagonal(),
            tolerance_m: config.tolerance_m * scale,
        };
        let mut nn = NnStats::default();
        let mut full_memo = vec![QueryMemo::default(); self.samples.len()];
        let (phase, iterations) = ladder(
            &matcher,
            &self.samples,
            &mut full_memo,
            t_ref_moving,
            &stop,
            (config, rules),
            &mut nn,
        )?;
        let t_ref_moving = phase.t_ref_moving;
        let exact = Matcher {
            distances: Distances::Exact,
            ..matcher
        };
        let final_association = match_at(
            &exact,
            &self.samples,
            &mut full_memo,
            &t_ref_moving,
            &mut nn,
        )?;
        let min_inliers = 30.max(self.samples.len() / 100);
        Ok(LevelOutcome {
            t_ref_moving,
            start: rules.start,
            status: judge(&phase, final_association.corrs.len(), min_inliers),
            iterations,
            constraint_ratio: phase.constraint_ratio,
            sigma: phase.sigma,
            jitter: phase.jitter,
            final_association,
            nn,
        })
    }
}

/// Sample ladder: with at least twice [`LADDER_SAMPLES`], converge on an even
/// subset first (every k-th point in chunk order), then refine on all of them
/// (their ring planes carried over); the final iterations, and so the result,
/// use every sample. Returns the last phase and the iterations of all phases.
fn ladder<R: Pyramid>(
    matcher: &Matcher<'_, R>,
    points: &[Vector3<f64>],
    full_memo: &mut [QueryMemo],
    mut t_ref_moving: Isometry3<f64>,
    stop: &Convergence,
    (config, rules): (&IcpConfig, &Rules),
    nn: &mut NnStats,
) -> Result<(Phase, usize), IcpError> {
    // a subset only when it is at most half the samples (50,116 samples of
    // a 50,000 request are one phase, not two of 25,058 and 50,116)
    let stride = if points.len() >= 2 * LADDER_SAMPLES {
        points.len().div_ceil(LADDER_SAMPLES)
    } else {
        1
    };
    let mut iterations = 0;
    if stride >= 2 {
        let subset: Vec<Vector3<f64>> = points.iter().step_by(stride).copied().collect();
        let mut memo = vec![QueryMemo::default(); subset.len()];
        let min_inliers = 30.max(subset.len() / 100);
        let phase = iterate(t_ref_moving, min_inliers, stop, config, rules, &mut |t| {
            match_at(matcher, &subset, &mut memo, t, nn)
        })?;
        iterations += phase.iterations;
        if !matches!(
            phase.status,
            IcpStatus::Converged | IcpStatus::MaxIterations
        ) {
            return Ok((phase, iterations));
        }
        t_ref_moving = phase.t_ref_moving;
        // the subset's ring planes hold for the same points of the full set
        for (full, kept) in full_memo.iter_mut().step_by(stride).zip(memo) {
            *full = kept;
        }
    }
    let min_inliers = 30.max(points.len() / 100);
    let phase = iterate(t_ref_moving, min_inliers, stop, config, rules, &mut |t| {
        match_at(matcher, points, full_memo, t, nn)
    })?;
    iterations += phase.iterations;
    Ok((phase, iterations))
}

/// The matches of `points` at `t`, their search counters added to `nn`.
fn match_at<R: Pyramid>(
    matcher: &Matcher<'_, R>,
    points: &[Vector3<f64>],
    memo: &mut [QueryMemo],
    t: &Isometry3<f64>,
    nn: &mut NnStats,
) -> Result<Association, IcpError> {
    let assoc = matcher.associate(points, memo, t).map_err(IcpError::Read)?;
    nn.add(&assoc.nn);
    Ok(assoc)
}

/// The level's status from its last phase and the final matches: too few of
/// them, or a collapse below half the peak (the matches collapsed while the
/// motion ran away; the peak is over the last phase, which used the same
/// points) overrides a phase that looked fine.
fn judge(phase: &Phase, final_inliers: usize, min_inliers: usize) -> IcpStatus {
    let mut status = phase.status;
    if status != IcpStatus::TooFewInliers && final_inliers < min_inliers {
        status = IcpStatus::TooFewInliers;
    }
    if status != IcpStatus::TooFewInliers && final_inliers * 2 < phase.peak_inliers {
        status = IcpStatus::Diverged;
    }
    status
}

impl LevelOutcome {
    /// True when the coarse-to-fine ladder must stop here.
    pub fn failed(&self) -> bool {
        matches!(self.status, IcpStatus::TooFewInliers | IcpStatus::Diverged)
    }

    /// Robust spread of the final point-to-plane residuals (1.4826 x their
    /// median absolute deviation), metres: how well the two surfaces agree
    /// here, comparable between starts of one pair. Infinite without matches.
    pub fn robust_cost_m(&self) -> f64 {
        let mut r: Vec<f64> = (self.final_association.corrs.iter())
            .map(Correspondence::plane_residual_m)
            .collect();
        if r.len() < 6 {
            return f64::INFINITY;
        }
        let mid = r.len() / 2;
        let median = *r.select_nth_unstable_by(mid, f64::total_cmp).1;
        let mut dev: Vec<f64> = r.iter().map(|v| (v - median).abs()).collect();
        1.4826 * *dev.select_nth_unstable_by(mid, f64::total_cmp).1
    }

    /// What the final fit knows, in the local frame: the final matches,
    /// weighted as the loop weighs them, judged by `rule`. None for
    /// point-to-point fits or too few matches.
    pub fn information(&self, config: &IcpConfig, rule: &DegeneracyRule) -> Option<FitInformation> {
        if config.metric == Metric::PointToPoint {
            return None;
        }
        let a = &self.final_association;
        let (corrs, cells) = smooth_only(a.corrs.clone(), &a.cells, config.max_roughness_m);
        let corrs = weighted(corrs, &cells, config.metric);
        let prior = config.rotation_prior(&self.t_ref_moving, &self.start);
        let mut info = fit_information_with(&corrs, config.model, rule, prior.as_ref())?;
        // an answer that is the mean of a jittering loop is uncertain by that
        // jitter too (local axes at the overlap centre, near the centroid)
        if let Some(j) = self.jitter {
            inflate(&mut info, &Matrix6::from_diagonal(&j.map(|v| v * v)));
        }
        Some(info)
    }

    /// The registration's result: the transform taken to world coordinates
    /// (the local frame is the world shifted by `origin`), the statistics
    /// of the final matches and `information` (local frame) moved to the world.
    pub fn into_result(
        self,
        origin: &Vector3<f64>,
        information: Option<FitInformation>,
    ) -> IcpResult {
        let matches = &self.final_association;
        let plane: Vec<f64> = matches
            .corrs
            .iter()
            .map(Correspondence::plane_residual_m)
            .collect();
        let information = information.map(|mut info| {
            info.centroid += origin;
            info
        });
        let centre = information.as_ref().map_or(*origin, |i| i.centroid);
        let degenerate = information
            .as_ref()
            .map(|i| i.degenerate.clone())
            .unwrap_or_default();
        let status = match self.status {
            IcpStatus::Converged if !degenerate.is_empty() => IcpStatus::Degenerate,
            s => s,
        };
        IcpResult {
            t_ref_moving: isometry_to_world(&self.t_ref_moving, origin),
            rmse_m: rms(&matches.distances_m),
            rmse_plane_m: rms(&plane),
            inliers: matches.corrs.len(),
            samples: matches.queries,
            overlap: matches.with_reference_below as f64 / matches.queries.max(1) as f64,
            iterations: self.iterations,
            status,
            constraint_ratio: self.constraint_ratio,
            sigma: self.sigma,
            information,
            centre_m: [centre.x, centre.y, centre.z],
            degenerate,
            ambiguity: None,
            backward: None,
            restart: None,
            second_height: None,
            search: None,
            nn: NnStatsSummary {
                queries: self.nn.queries,
                pixels_visited: self.nn.pixels_visited,
            },
        }
    }
}

/// The full-resolution level alone, run from `start_world` (a world transform
/// taking `moving`'s points onto `reference`), with the ladder's last-rung
/// rules: what the backward and restart checks run. `centre` is where the
/// start's shift is judged (far starts sample the overlap where the moved DSM
/// lands), `prior_about` the rotation the rotation prior holds to, and `cap_m`
/// the largest shift from the start.
pub(super) fn full_resolution<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
    (start_world, prior_about): (&Isometry3<f64>, UnitQuaternion<f64>),
    centre: &Vector3<f64>,
    (pixel_m, cap_m): (f64, f64),
) -> Result<IcpResult, IcpError> {
    let shift = start_world.transform_point(&(*centre).into()).coords - centre;
    let sampled = if shift.xy().norm() < PAPER_TAU_M {
        Vector3::zeros()
    } else {
        shift
    };
    let overlap = moved_overlap(reference, moving, &sampled)?.ok_or(IcpError::NoOverlap)?;
    let (centre_x, centre_y) = overlap.centre();
    let origin_xy = Vector3::new(centre_x, centre_y, 0.0);
    let level = Level::sample(reference, moving, 0, &overlap, &origin_xy, config)?;
    let origin = level.origin(&origin_xy);
    let t_start = isometry_to_world(start_world, &-origin);
    let rules = Rules {
        degeneracy: final_rule(pixel_m),
        start: Isometry3::from_parts(t_start.translation, prior_about),
        cap_m,
        floor_m: config.sigma_floor_px * pixel_m,
    };
    let tau_m = config.tau_at(0, pixel_m, f64::NAN);
    let outcome = level.run(&origin, t_start, tau_m, &rules)?;
    let information = outcome.information(config, &final_rule(pixel_m));
    Ok(outcome.into_result(&origin, information))
}

/// The coarsest level whose overlap is still at least 64 px on its short side.
pub(super) fn start_level<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    overlap: &Bounds,
    max_level: usize,
) -> usize {
    let levels = reference.num_levels().min(moving.num_levels());
    let mut best = 0;
    for level in 1..levels.min(max_level + 1) {
        let Ok(grid) = moving.open_level(level) else {
            break;
        };
        match pixel_window(&grid, overlap) {
            Some([c0, r0, c1, r1]) if (c1 - c0).min(r1 - r0) >= 64 => best = level,
            _ => break,
        }
    }
    best
}

fn rms(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn judge_overrides_a_phase_whose_final_matches_collapsed() {
        let phase = Phase {
            status: IcpStatus::Converged,
            peak_inliers: 1000,
            ..Phase::default()
        };
        assert_eq!(judge(&phase, 900, 30), IcpStatus::Converged);
        assert_eq!(judge(&phase, 400, 30), IcpStatus::Diverged);
        assert_eq!(judge(&phase, 20, 30), IcpStatus::TooFewInliers);
        let few = Phase {
            status: IcpStatus::TooFewInliers,
            ..phase
        };
        assert_eq!(judge(&few, 10, 30), IcpStatus::TooFewInliers);
    }

    #[test]
    fn rms_of_nothing_is_nan() {
        assert!(rms(&[]).is_nan());
        assert_eq!(rms(&[3.0, 4.0, 0.0, 0.0]), 2.5);
    }
}
