//! What a collection knows about its pairs' offsets: a converged answer
//! found far beyond them by a widened search is not trusted at full weight.
//!
//! A pair's automatic search radius is cut to half its overlap's width, and
//! doubles while the best place lies on its edge (`crate::icp::start`). On
//! small tiles the doubled radius reaches places where one tile's corner
//! lands on its neighbour's, and among the many such places one can fit by
//! chance as well as a true offset does: no per-pair cost separates them
//! (docs/notes/strips.md, section 6). The collection can: its DSMs share a
//! sensor and a georeferencing, so their offsets are of one scale. The clear
//! pairs (converged, their search not widened) measure it; a converged pair
//! whose widened search put it farther than [`BOUND_FACTOR`] times their
//! [`QUANTILE`] offset enters the graph as `ambiguous` (never at full
//! weight), its horizontal variances widened by its offset squared: the
//! collection says the truth lies near where the pair started, the pair says
//! it lies there, and the edge spans both.
//!
//! Searching such pairs again with the widening capped at the bound was
//! tried first and not kept: on a 12 x 12 grid of 64 m tiles every widened
//! pair was ambiguous already, and searched again it ended nearer but still
//! metres off with a spread a fifth of its first one (per-DSM median 0.50 ->
//! 0.91 m; docs/measurements.md, "A converged answer beyond the
//! collection's offsets").
//!
//! The bound is learned only from a collection that can teach it: at least
//! [`MIN_CLEAR_PAIRS`] clear pairs, and at most [`MAX_WIDENED_SHARE`] of the
//! searched pairs widened (where most pairs widen, the offsets are as large
//! as the cut radius, and the clear pairs are only those that happened to
//! lie inside it). `--max-displacement` sets the radius itself: no cut, no
//! widening, nothing judged. The judgment is a function of the journaled
//! outcomes alone: a resumed run and a merge of shards judge alike.

use crate::icp::{IcpConfig, IcpStatus};
use crate::pipeline::{IcpFit, PairOutcome, PairTask};

/// Clear pairs needed to learn the collection's offsets.
pub const MIN_CLEAR_PAIRS: usize = 10;
/// The clear pairs' offsets are read at this quantile...
pub const QUANTILE: f64 = 0.9;
/// ...and the bound is this multiple of it.
pub const BOUND_FACTOR: f64 = 2.0;
/// Above this share of widened searches, the collection's offsets are not learned.
pub const MAX_WIDENED_SHARE: f64 = 0.2;

/// What the first pass taught about the collection's offsets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reach {
    /// The cap on the widened search, metres.
    pub bound_m: f64,
    /// The clear pairs' offset at [`QUANTILE`], metres.
    pub quantile_m: f64,
    /// Clear pairs (converged, search not widened) it was learned from.
    pub clear: usize,
    /// Pairs whose search ran, and those of them that widened.
    pub searched: usize,
    pub widened: usize,
}

/// What the collection taught and the pairs it judged.
#[derive(Clone, Debug, PartialEq)]
pub struct ReachReport {
    pub reach: Reach,
    /// Converged pairs found beyond the bound by a widened search, now
    /// `ambiguous`.
    pub judged: Vec<PairTask>,
}

/// The collection's offset bound from the first pass's outcomes; None when
/// they cannot teach one (see the module doc).
pub fn learn(outcomes: &[PairOutcome]) -> Option<Reach> {
    let (mut clear, mut searched, mut widened) = (Vec::new(), 0, 0);
    for fit in outcomes.iter().filter_map(PairOutcome::fit) {
        let Some(search) = fit.search.as_deref() else {
            continue;
        };
        searched += 1;
        if search.widened() {
            widened += 1;
        } else if fit.reliable() {
            clear.push(search.offset_m);
        }
    }
    if clear.len() < MIN_CLEAR_PAIRS || widened as f64 > MAX_WIDENED_SHARE * searched as f64 {
        return None;
    }
    clear.sort_by(f64::total_cmp);
    let rank = (QUANTILE * (clear.len() - 1) as f64).ceil() as usize;
    let quantile_m = clear[rank];
    Some(Reach {
        bound_m: BOUND_FACTOR * quantile_m,
        quantile_m,
        clear: clear.len(),
        searched,
        widened,
    })
}

/// Converged pairs whose widened search put them beyond the bound.
pub fn beyond(outcomes: &[PairOutcome], reach: &Reach) -> Vec<PairTask> {
    let far = |fit: &IcpFit| {
        fit.reliable()
            && fit
                .search
                .as_ref()
                .is_some_and(|s| s.widened() && s.offset_m > reach.bound_m)
    };
    (outcomes.iter())
        .filter(|o| o.fit().is_some_and(far))
        .map(PairOutcome::pair)
        .collect()
}

/// Learns the collection's bound from `outcomes` and makes each converged
/// pair beyond it `ambiguous`, its horizontal variances widened by its
/// offset squared (see the module doc); None when nothing was learned (or
/// `config` sets the search radius).
pub fn judge(outcomes: &mut [PairOutcome], config: &IcpConfig) -> Option<ReachReport> {
    if config.max_displacement_m.is_finite() {
        return None;
    }
    let reach = learn(outcomes)?;
    let judged = beyond(outcomes, &reach);
    for outcome in outcomes.iter_mut() {
        let PairOutcome::Registered { pair, fit, .. } = outcome else {
            continue;
        };
        if !judged.contains(pair) {
            continue;
        }
        let offset_m = fit.search.as_ref().map_or(0.0, |s| s.offset_m);
        tracing::info!(
            reference = pair.reference,
            moving = pair.moving,
            offset_m,
            bound_m = reach.bound_m,
            "a converged answer beyond the collection's offsets: ambiguous"
        );
        widen_horizontally(fit, offset_m);
    }
    Some(ReachReport { reach, judged })
}

/// `ambiguous`, with `spread_m`^2 added to the horizontal variances (of the
/// covariance and of the standard errors; an axis the fit held stays held).
fn widen_horizontally(fit: &mut IcpFit, spread_m: f64) {
    fit.status = IcpStatus::Ambiguous;
    if let Some(info) = fit.information.as_mut() {
        for k in 0..2 {
            if info.covariance[k][k] > 0.0 {
                info.covariance[k][k] += spread_m * spread_m;
            }
        }
    }
    if let Some(sigma) = fit.sigma.as_mut() {
        for s in &mut sigma.trans_m[..2] {
            if *s > 0.0 {
                *s = s.hypot(spread_m);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::FitSigma;
    use crate::icp::SearchReach;
    use crate::pipeline::PairInformation;
    use nalgebra::Matrix4;

    fn outcome(
        k: usize,
        status: IcpStatus,
        cut_m: f64,
        reached_m: f64,
        offset_m: f64,
    ) -> PairOutcome {
        PairOutcome::Registered {
            pair: PairTask {
                reference: k,
                moving: k + 1,
            },
            overlap: 0.3,
            fit: IcpFit {
                status,
                t_ref_moving_world: Matrix4::identity(),
                rmse_m: 0.1,
                inliers: 100,
                iterations: 5,
                sigma: None,
                information: None,
                search: Some(Box::new(SearchReach {
                    cut_m,
                    reached_m,
                    offset_m,
                })),
            },
        }
    }

    fn with_information(mut outcome: PairOutcome) -> PairOutcome {
        if let PairOutcome::Registered { fit, .. } = &mut outcome {
            let mut covariance = [[0.0; 6]; 6];
            for (k, v) in [0.01, 0.04, 1e-4, 1e-6, 1e-6, 1e-6].into_iter().enumerate() {
                covariance[k][k] = v;
            }
            fit.information = Some(Box::new(PairInformation {
                covariance,
                centroid_world: [0.0; 3],
                degenerate: Vec::new(),
                gridding: None,
            }));
            fit.sigma = Some(FitSigma {
                rot_deg: [0.01; 3],
                trans_m: [0.1, 0.2, 0.01],
            });
        }
        outcome
    }

    fn status(outcomes: &[PairOutcome], k: usize) -> IcpStatus {
        let o = outcomes.iter().find(|o| o.pair().reference == k).unwrap();
        o.fit().unwrap().status
    }

    /// Twenty clear pairs 0.5-10 m off (their 0.9 quantile 9.5 m: the bound
    /// is 19 m) and widened ones: converged 15 m off (within the bound, kept),
    /// converged 30 m off (beyond: ambiguous, its horizontal sigmas widened by
    /// 30 m), ambiguous 40 m off (left as it is); ambiguous pairs teach nothing.
    #[test]
    fn a_converged_answer_beyond_the_clear_pairs_offsets_is_ambiguous() {
        let mut outcomes: Vec<PairOutcome> = (0..20)
            .map(|k| outcome(k, IcpStatus::Converged, 12.0, 12.0, 0.5 * (k + 1) as f64))
            .collect();
        outcomes.push(outcome(30, IcpStatus::Ambiguous, 12.0, 12.0, 11.0));
        outcomes.push(outcome(40, IcpStatus::Converged, 12.0, 24.0, 15.0));
        outcomes.push(with_information(outcome(
            50,
            IcpStatus::Converged,
            12.0,
            48.0,
            30.0,
        )));
        outcomes.push(outcome(60, IcpStatus::Ambiguous, 12.0, 48.0, 40.0));
        let reach = learn(&outcomes).unwrap();
        assert_eq!((reach.clear, reach.searched, reach.widened), (20, 24, 3));
        assert_eq!((reach.quantile_m, reach.bound_m), (9.5, 19.0));
        let judged = judge(&mut outcomes, &IcpConfig::default()).unwrap();
        assert_eq!(
            judged.judged,
            vec![PairTask {
                reference: 50,
                moving: 51
            }]
        );
        assert_eq!(status(&outcomes, 50), IcpStatus::Ambiguous);
        assert_eq!(status(&outcomes, 40), IcpStatus::Converged);
        let fit = outcomes[22].fit().unwrap();
        let c = fit.information.as_ref().unwrap().covariance;
        assert_eq!([c[0][0], c[1][1], c[2][2]], [900.01, 900.04, 1e-4]);
        let s = fit.sigma.unwrap().trans_m;
        assert_eq!(s, [0.1f64.hypot(30.0), 0.2f64.hypot(30.0), 0.01]);
        // judged again, nothing more changes: the judged pair is no longer
        // converged, and widened pairs never taught the bound
        let before = outcomes.clone();
        let again = judge(&mut outcomes, &IcpConfig::default()).unwrap();
        assert_eq!((again.reach, again.judged.len()), (reach, 0));
        assert_eq!(outcomes, before);
        // a radius the user set: no cut, nothing judged
        let set = IcpConfig {
            max_displacement_m: 50.0,
            ..IcpConfig::default()
        };
        assert_eq!(judge(&mut outcomes, &set), None);
    }

    /// Too few clear pairs, or too many widened searches (offsets as large as
    /// the cut radius): nothing is learned.
    #[test]
    fn a_collection_that_cannot_teach_its_offsets_keeps_the_rule() {
        let few: Vec<PairOutcome> = (0..9)
            .map(|k| outcome(k, IcpStatus::Converged, 12.0, 12.0, 1.0))
            .collect();
        assert_eq!(learn(&few), None);
        let mut wide: Vec<PairOutcome> = (0..16)
            .map(|k| outcome(k, IcpStatus::Converged, 12.0, 12.0, 1.0))
            .collect();
        wide.extend((20..25).map(|k| outcome(k, IcpStatus::Converged, 12.0, 24.0, 20.0)));
        assert_eq!(learn(&wide), None, "5 of 21 widened");
        wide.pop();
        assert!(learn(&wide).is_some(), "4 of 20 widened");
    }
}
