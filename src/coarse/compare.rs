//! The last step of the search: the refined candidates and the georeferenced
//! position (zero shift: where the DSM is, or where `--initial` put it) scored
//! on one set of moving samples at one clip, so that their costs compare.
//!
//! The georeferenced position is kept unless a candidate fits better by more
//! than [`KEEP_SE`] standard errors of the paired difference: the difference
//! of the two robust costs over the same samples, with its standard error from
//! the per-sample differences. Where every nearby shift fits about as well
//! (flat ground, a narrow strip, noise-free data over a plain), the DSM's own
//! georeferencing is the better guess than the shift that won by chance.

use super::cost::{bilinear, median_in_place, Clip, Residual, Sample, ShiftScore};
use super::search::{best_spread, Trial};
use super::tilt::fit_plane;
use crate::grid::Grid;

/// Standard errors of the paired difference by which a shift must fit better
/// than the georeferenced position to replace it.
pub const KEEP_SE: f64 = 2.0;
/// Fewest samples with a reference height at both shifts for a comparison.
pub const MIN_PAIRED: usize = 16;

/// Every sample's H_ref(x + dx, y + dy) - h at one shift, NaN where the
/// reference has no height.
pub fn residuals<G: Grid + ?Sized>(
    reference: &mut G,
    samples: &[Sample],
    shift_xy_m: [f64; 2],
) -> Vec<Residual> {
    samples
        .iter()
        .map(|s| Residual {
            x_m: s.x_m,
            y_m: s.y_m,
            dh_m: bilinear(reference, s.x_m + shift_xy_m[0], s.y_m + shift_xy_m[1]) - s.h_m,
        })
        .collect()
}

/// One shift's residuals as robust losses, sample by sample.
#[derive(Clone, Debug)]
pub struct Losses {
    /// The shift's score at the clip used (support, offset, spread, cost).
    pub score: ShiftScore,
    /// min(|dh - plane|, clip)^2 per sample, m^2 (the plane as in
    /// [`super::cost::score_residuals`]); NaN without a height.
    pub loss_m2: Vec<f64>,
}

impl Losses {
    /// The losses of `residuals` at `clip`; an infinite cost below
    /// `min_support` residuals.
    pub fn new(residuals: &[Residual], clip: Clip, min_support: usize) -> Losses {
        let valid: Vec<Residual> = residuals
            .iter()
            .copied()
            .filter(|r| r.dh_m.is_finite())
            .collect();
        let support = valid.len();
        if support < min_support.max(3) {
            return Losses {
                score: ShiftScore {
                    support,
                    ..ShiftScore::EMPTY
                },
                loss_m2: vec![f64::NAN; residuals.len()],
            };
        }
        let mut scratch = Vec::with_capacity(support);
        let plane = fit_plane(&valid, &mut scratch);
        scratch.clear();
        scratch.extend(valid.iter().map(|r| plane.detrended(r).abs()));
        let nmad_m = 1.4826 * median_in_place(&mut scratch);
        let clip_m = clip.height_m(nmad_m);
        let loss_m2: Vec<f64> = residuals
            .iter()
            .map(|r| match plane.detrended(r).abs() {
                e if e.is_nan() => f64::NAN,
                e => e.min(clip_m).powi(2),
            })
            .collect();
        let sum: f64 = loss_m2.iter().filter(|l| l.is_finite()).sum();
        Losses {
            score: ShiftScore {
                support,
                dz_m: plane.offset_m,
                nmad_m,
                cost_m: (sum / support as f64).sqrt(),
            },
            loss_m2,
        }
    }
}

/// The mean per-sample loss of `b` minus that of `a` over the samples both
/// have, and its standard error.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairedDifference {
    pub mean_m2: f64,
    pub standard_error_m2: f64,
    /// Samples with a loss at both shifts.
    pub count: usize,
}

impl PairedDifference {
    pub fn between(a: &Losses, b: &Losses) -> PairedDifference {
        let d: Vec<f64> = a
            .loss_m2
            .iter()
            .zip(&b.loss_m2)
            .map(|(la, lb)| lb - la)
            .filter(|d| d.is_finite())
            .collect();
        let n = d.len();
        if n < 2 {
            return PairedDifference {
                mean_m2: f64::NAN,
                standard_error_m2: f64::NAN,
                count: n,
            };
        }
        let mean = d.iter().sum::<f64>() / n as f64;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        PairedDifference {
            mean_m2: mean,
            standard_error_m2: (var / n as f64).sqrt(),
            count: n,
        }
    }

    /// `b` fits better than `a` by more than `k` standard errors, on at least
    /// [`MIN_PAIRED`] samples.
    pub fn b_better_by(&self, k: f64) -> bool {
        self.count >= MIN_PAIRED && -self.mean_m2 > k * self.standard_error_m2
    }
}

/// The refined candidates ranked on common samples, and what was kept.
#[derive(Clone, Debug)]
pub struct Ranking {
    /// Best first: the georeferenced position when kept, then the candidates
    /// by their cost at the common clip, then any candidate the samples do not
    /// reach (at its refinement's cost).
    pub trials: Vec<Trial>,
    /// The georeferenced position is first because no candidate fit better by
    /// more than [`KEEP_SE`] standard errors.
    pub kept_georeferenced: bool,
    /// The best candidate's loss minus the georeferenced position's.
    pub gain: Option<PairedDifference>,
}

/// Ranks `refined` (shifts moving -> reference, metres) against the zero
/// shift, all on `samples` of the moving DSM at one clip (3 NMAD of the best
/// spread among them; module docs). None when the samples are too few or
/// no shift has a reference height under enough of them.
pub fn rank_against_georeferenced<G: Grid + ?Sized>(
    reference: &mut G,
    samples: &[Sample],
    refined: &[Trial],
    common: bool,
    keep: bool,
) -> Option<Ranking> {
    if samples.len() < MIN_PAIRED {
        return None;
    }
    let min_support = MIN_PAIRED.max(samples.len() / 8);
    let shifts: Vec<[f64; 2]> = std::iter::once([0.0, 0.0])
        .chain(refined.iter().map(|t| t.shift_xy_m))
        .collect();
    let residuals: Vec<Vec<Residual>> = shifts
        .iter()
        .map(|&s| residuals(reference, samples, s))
        .collect();
    let own: Vec<Trial> = shifts
        .iter()
        .zip(&residuals)
        .map(|(&shift_xy_m, r)| Trial {
            shift_xy_m,
            score: Losses::new(r, Clip::OwnSpread, min_support).score,
        })
        .collect();
    let clip = Clip::at_spread(best_spread(&own)?);
    tracing::trace!(?own, ?clip, "coarse comparison spreads");
    let mut losses: Vec<Losses> = residuals
        .iter()
        .map(|r| Losses::new(r, clip, min_support))
        .collect();
    let zero = losses.remove(0);
    type Scored = Vec<(Trial, Losses)>;
    let (mut reached, mut unreached): (Scored, Scored) = refined
        .iter()
        .zip(losses)
        .map(|(t, l)| {
            let common = Trial {
                shift_xy_m: t.shift_xy_m,
                score: l.score,
            };
            (common, l)
        })
        .partition(|(t, _)| t.score.cost_m.is_finite());
    // candidates out of the samples' reach keep their refinement's score
    for (t, _) in unreached.iter_mut() {
        if let Some(r) = refined.iter().find(|r| r.shift_xy_m == t.shift_xy_m) {
            t.score = r.score;
        }
    }
    if common {
        reached.sort_by(|a, b| a.0.score.cost_m.total_cmp(&b.0.score.cost_m));
    } else {
        // (ablation) ranked by the refinement's own-clip costs, which they report
        for (t, _) in reached.iter_mut() {
            if let Some(r) = refined.iter().find(|r| r.shift_xy_m == t.shift_xy_m) {
                t.score = r.score;
            }
        }
        reached.sort_by(|a, b| a.0.score.cost_m.total_cmp(&b.0.score.cost_m));
        unreached.sort_by(|a, b| a.0.score.cost_m.total_cmp(&b.0.score.cost_m));
    }
    let gain = reached
        .first()
        .filter(|_| zero.score.cost_m.is_finite())
        .map(|(_, best)| PairedDifference::between(&zero, best));
    let kept_georeferenced =
        keep && zero.score.cost_m.is_finite() && !gain.is_some_and(|g| g.b_better_by(KEEP_SE));
    let mut trials = Vec::with_capacity(refined.len() + 1);
    if kept_georeferenced {
        // (ablation) without the common clip, its own-clip score on these samples
        let score = if common {
            zero.score
        } else {
            own[0].score
        };
        trials.push(Trial {
            shift_xy_m: [0.0, 0.0],
            score,
        });
    }
    trials.extend(reached.into_iter().chain(unreached).map(|(t, _)| t));
    Some(Ranking {
        trials,
        kept_georeferenced,
        gain,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Height differences on a 2 m lattice of a 7 x 7 square.
    fn lattice(dh_m: impl Fn(usize) -> f64) -> Vec<Residual> {
        (0..49)
            .map(|k| Residual {
                x_m: (k % 7) as f64 * 2.0,
                y_m: (k / 7) as f64 * 2.0,
                dh_m: dh_m(k),
            })
            .collect()
    }

    #[test]
    fn losses_clip_about_the_plane_and_skip_voids() {
        let r = lattice(|k| match k {
            3 => f64::NAN,
            4 => 6.0,
            k => 1.0 + 0.01 * (k % 7) as f64,
        });
        let l = Losses::new(&r, Clip::Common(0.5), 3);
        assert_eq!(l.score.support, 48);
        assert!(l.loss_m2[3].is_nan());
        assert!(
            (l.loss_m2[4] - 0.25).abs() < 1e-12,
            "clipped: {:?}",
            l.loss_m2
        );
        assert!(l.loss_m2[10] < 1e-20, "on the plane: {:?}", l.loss_m2);
        assert!(l.score.cost_m < 0.1, "{:?}", l.score);
        let starved = Losses::new(&r[..2], Clip::Common(0.5), 3);
        assert_eq!(starved.score.cost_m, f64::INFINITY);
    }

    #[test]
    fn a_consistent_small_gain_is_significant_and_noise_is_not() {
        // b is better on every sample by 0.01 m^2 give or take 0.005: significant.
        let n = 200;
        let a: Vec<f64> = (0..n).map(|i| 0.1 + 0.001 * (i % 7) as f64).collect();
        let b: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, x)| x - 0.01 + 0.005 * ((i % 3) as f64 - 1.0))
            .collect();
        let as_losses = |v: &[f64]| Losses {
            score: ShiftScore::EMPTY,
            loss_m2: v.to_vec(),
        };
        let d = PairedDifference::between(&as_losses(&a), &as_losses(&b));
        assert_eq!(d.count, n);
        assert!((d.mean_m2 + 0.01).abs() < 1e-3, "{d:?}");
        assert!(d.b_better_by(KEEP_SE));
        // the same mean gain hidden in differences of +-0.5: not significant
        let c: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, x)| x - 0.01 + if i % 2 == 0 { 0.5 } else { -0.5 })
            .collect();
        let d = PairedDifference::between(&as_losses(&a), &as_losses(&c));
        assert!(!d.b_better_by(KEEP_SE), "{d:?}");
        // equal losses: no gain
        let d = PairedDifference::between(&as_losses(&a), &as_losses(&a));
        assert!(!d.b_better_by(KEEP_SE), "{d:?}");
    }
}
