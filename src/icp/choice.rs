//! The best of the starts' results, and what the others say about it.
//!
//! When the global search is ambiguous, the ladder runs from each of its best
//! few peaks (and from the georeferenced position). The place the samples all
//! places share rank first wins (`compare`; else the lowest own robust cost);
//! results at other places within [`AMBIGUOUS_COST_RATIO`] of it by either
//! score make the pair `Ambiguous`. The
//! winner's sandwich covariance is the curvature of its own basin only: on
//! featureless ground (sparse stereo, fields) nearly equal basins lie metres
//! apart and the winner is a coin toss among them: tile_264 -> tile_265 of
//! the 20 x 20 grid of 128 m tiles in the sparse TIN rendering reported x to
//! 7 cm and was 1.3 m (18 sigma) off. So the spread of the nearly-as-good places about the winner,
//! the between-component covariance of an equal mixture (1/K sum d_k d_k^T
//! over the K places, the winner's d = 0), joins its covariance: the graph
//! learns from the pair what all its places agree on (height, tilt, often one
//! horizontal direction) and not the coin toss.
//!
//! A start still sliding when its iterations ran out (`MaxIterations`) is no
//! answer, but where it stopped it can say the converged winner is not the
//! bottom of the data's cost: k=9 of `tools/scripts/pair_battery.py --narrow`
//! (a 72 m offset across a 38 m strip, beyond the search cut to half of it)
//! had three of four starts slide to places 6-10 m from the one that
//! converged, at lower own costs, and the pair reported x to 1.3 m, 70 m off.
//! Own costs of sliding runs are no judge alone (a run sliding off a strip is
//! scored on what still lands: on the 20 x 20 grid of 128 m tiles 27
//! converged pairs, all within 3 of their x and y sigmas, had one cheaper by
//! 1-8 %), and the samples two places share tell metres apart on smooth
//! ground only by a few per cent. So only a place no other start converged
//! to is judged, against each place where a sliding start stopped at an own
//! cost no higher, on the samples the two share ([`slid_rivals`]); within
//! [`AMBIGUOUS_COST_RATIO`] there it is a rival like any other.
//!
//! A winner its backward check or its restarts do not confirm
//! (`icp::backward`, `icp::restart`) is `Ambiguous` too, with the spread of
//! every place the starts ended at ([`unconfirmed`]).

use nalgebra::{Matrix6, Point3, Vector3};

use super::backward::{inflate, Disagreement};
use super::{compare, IcpError, IcpResult, IcpStatus, AMBIGUOUS_COST_RATIO};
use crate::grid::Pyramid;

/// The best of the results from several starts (result, choice cost, own
/// cost): usable before not, then the lowest choice cost (the samples the
/// places share, `compare`; else the own cost). With several, the ambiguity
/// becomes the ratio of the two best choice costs among results at different
/// places, or of the own costs where another place's is nearly as low or
/// lower; a ratio above [`AMBIGUOUS_COST_RATIO`] makes the pair `Ambiguous`,
/// with the spread of the places that fit nearly as well by either cost
/// added to its covariance ([`spread`]). Returns the best and its own cost.
pub(super) fn choose(
    mut tried: Vec<(IcpResult, f64, f64)>,
    ambiguity: Option<f64>,
    pixel_m: f64,
) -> (IcpResult, f64) {
    let rank = |r: &(IcpResult, f64, f64)| (!r.0.status.is_converged_or_held(), r.1);
    tried.sort_by(|a, b| {
        let (ka, kb) = (rank(a), rank(b));
        ka.0.cmp(&kb.0).then(ka.1.total_cmp(&kb.1))
    });
    let several = tried.len() > 1;
    let mut tried = tried.into_iter();
    let (mut best, best_cost, best_own) = tried.next().expect("at least one start");
    best.ambiguity = ambiguity;
    if !several {
        return (best, best_own);
    }
    // how nearly another usable place fits as well, by either cost (1: as well or better)
    let closeness = |cost: f64, own: f64| {
        let ratio = |a: f64, b: f64| if b > 0.0 { (a / b).min(1.0) } else { 0.0 };
        ratio(best_cost, cost).max(ratio(best_own, own))
    };
    let elsewhere: Vec<(IcpResult, f64)> = tried
        .filter(|(r, _, _)| r.status.is_converged_or_held() && differs(&best, r, pixel_m))
        .map(|(r, cost, own)| (r, closeness(cost, own)))
        .collect();
    best.ambiguity = Some(elsewhere.iter().map(|e| e.1).fold(0.0, f64::max));
    if best.status.is_converged_or_held() && best.ambiguity.unwrap_or(0.0) > AMBIGUOUS_COST_RATIO {
        best = ambiguous(best, &elsewhere);
    }
    (best, best_own)
}

/// `best` made `Ambiguous`, with the spread of the places in `elsewhere`
/// (result, closeness) that fit within [`AMBIGUOUS_COST_RATIO`] of it added
/// to its covariance.
fn ambiguous(mut best: IcpResult, elsewhere: &[(IcpResult, f64)]) -> IcpResult {
    best.status = IcpStatus::Ambiguous;
    let rivals: Vec<&IcpResult> = (elsewhere.iter())
        .filter(|(_, near)| *near > AMBIGUOUS_COST_RATIO)
        .map(|(r, _)| r)
        .collect();
    if let Some(extra) = spread(&best, &rivals) {
        let info = best.information.as_mut().expect("spread needs information");
        inflate(info, &extra);
    }
    best
}

/// The converged (or held) `best`, of own cost `best_own`, judged against
/// the places where the starts ended (`ends`: result, own cost; `best`'s
/// own run among them; module docs). Unless another start converged at its
/// place too, each place where a start still sliding stopped elsewhere at an
/// own cost no higher is scored with `best` on the samples the two share
/// ([`compare::closeness`]; too few shared samples leave it unjudged);
/// within [`AMBIGUOUS_COST_RATIO`] the pair becomes `Ambiguous` with their
/// spread.
pub(super) fn slid_rivals<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    best: IcpResult,
    best_own: f64,
    ends: &[(IcpResult, f64)],
    pixel_m: f64,
) -> Result<IcpResult, IcpError> {
    let reached = (ends.iter())
        .filter(|(r, _)| r.status.is_converged_or_held() && !differs(&best, r, pixel_m))
        .count();
    if !best.status.is_converged_or_held() || reached > 1 {
        return Ok(best);
    }
    let mut elsewhere = Vec::new();
    for (r, own) in ends {
        let sliding = r.status == IcpStatus::MaxIterations;
        if sliding && *own <= best_own && differs(&best, r, pixel_m) {
            if let Some(near) = compare::closeness(reference, moving, &best, r)? {
                elsewhere.push((r.clone(), near));
            }
        }
    }
    Ok(with_slid(best, elsewhere))
}

/// `best`, converged or held, whose backward check or restarts did not
/// confirm it (`BackwardCheck::confirms`, `RestartCheck::confirms`):
/// `Ambiguous`, with the spread of every other
/// place where a start ended (`ends`: converged, held or still sliding,
/// whatever its cost) added to its covariance. An unconfirmed answer is no
/// better founded than those places: tile_2397 -> tile_2398 of the 50 x 50
/// grid of 64 m tiles converged 21 m off, at a third of the own cost of the
/// georeferenced start's place, which was the truth. Anything else is
/// returned as it is.
pub(super) fn unconfirmed(
    mut best: IcpResult,
    ends: &[(IcpResult, f64)],
    pixel_m: f64,
) -> IcpResult {
    let unconfirmed =
        best.backward.is_some_and(|b| !b.confirms) || best.restart.is_some_and(|r| !r.confirms());
    if !best.status.is_converged_or_held() || !unconfirmed {
        return best;
    }
    best.status = IcpStatus::Ambiguous;
    let others: Vec<&IcpResult> = (ends.iter().map(|(r, _)| r))
        .filter(|r| differs(&best, r, pixel_m))
        .collect();
    if let Some(extra) = spread(&best, &others) {
        let info = best.information.as_mut().expect("spread needs information");
        inflate(info, &extra);
    }
    best
}

/// `best` with the sliding places compared with it (result, closeness on
/// the shared samples): ambiguous when one is within
/// [`AMBIGUOUS_COST_RATIO`], its ambiguity raised to the nearest.
fn with_slid(mut best: IcpResult, elsewhere: Vec<(IcpResult, f64)>) -> IcpResult {
    let nearest = elsewhere.iter().map(|e| e.1).fold(0.0, f64::max);
    if nearest <= AMBIGUOUS_COST_RATIO {
        return best;
    }
    best.ambiguity = Some(best.ambiguity.unwrap_or(0.0).max(nearest));
    ambiguous(best, &elsewhere)
}

/// The between-place covariance of an equal mixture of `best` and `rivals`
/// about `best`, at its centroid and in its axes (shift m, rotation rad):
/// 1/K sum d_k d_k^T, K = 1 + rivals. None without information or rivals.
fn spread(best: &IcpResult, rivals: &[&IcpResult]) -> Option<Matrix6<f64>> {
    let at = best.information.as_ref()?.centroid;
    if rivals.is_empty() {
        return None;
    }
    let sum: Matrix6<f64> = rivals
        .iter()
        .map(|r| {
            let d = Disagreement::between(&best.t_ref_moving, &r.t_ref_moving.inverse(), &at);
            let gap = d.gap();
            gap * gap.transpose()
        })
        .sum();
    Some(sum / (rivals.len() + 1) as f64)
}

/// True when two results put the moving DSM more than a pixel apart along an
/// axis the best one measures (a held axis may differ freely).
fn differs(best: &IcpResult, other: &IcpResult, pixel_m: f64) -> bool {
    let at = best
        .information
        .as_ref()
        .map(|i| i.centroid)
        .unwrap_or_else(Vector3::zeros);
    let p = Point3::from(at);
    let d = best.t_ref_moving.transform_point(&p) - other.t_ref_moving.transform_point(&p);
    (0..3).any(|k| {
        let held = best.degenerate.iter().any(|a| a.index() == k);
        !held && d[k].abs() > pixel_m
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Translation3, Vector6};

    /// A converged result `dx` metres east of the identity with a 5 cm, 0.01
    /// degree covariance (information to match) at the origin.
    fn at(dx: f64) -> IcpResult {
        IcpResult::with_diagonal(
            Isometry3::from_parts(Translation3::new(dx, 0.0, 0.0), Default::default()),
            Vector3::zeros(),
            Vector6::new(0.05, 0.05, 0.01, 1.7e-4, 1.7e-4, 1.7e-4),
            50.0,
        )
    }

    /// Two places 4 m apart at nearly the same cost: the pair is ambiguous and
    /// its x sigma covers the other place (equal mixture: 4 / sqrt 2 m); y and
    /// z keep their own sigmas. A clear winner keeps its covariance.
    #[test]
    fn an_ambiguous_pair_carries_the_spread_of_its_places() {
        let (chosen, _) = choose(
            vec![(at(4.0), 0.30, 0.30), (at(0.0), 0.29, 0.29)],
            Some(0.95),
            0.5,
        );
        assert_eq!(chosen.status, IcpStatus::Ambiguous);
        assert!(
            (chosen.t_ref_moving.translation.x - 0.0).abs() < 1e-12,
            "the cheaper place wins"
        );
        let sigma = chosen.information.as_ref().unwrap().sigma;
        let expected = (0.05f64.powi(2) + 16.0 / 2.0).sqrt();
        assert!((sigma[0].unwrap() - expected).abs() < 1e-9, "{sigma:?}");
        assert!((sigma[1].unwrap() - 0.05).abs() < 1e-9, "{sigma:?}");
        assert!((sigma[2].unwrap() - 0.01).abs() < 1e-9, "{sigma:?}");

        let (clear, _) = choose(
            vec![(at(4.0), 0.60, 0.60), (at(0.0), 0.29, 0.29)],
            Some(0.5),
            0.5,
        );
        assert_eq!(clear.status, IcpStatus::Converged);
        assert_eq!(clear.information.as_ref().unwrap().sigma[0], Some(0.05));
        // a place the shared samples rank clearly worse but whose own fit is
        // as good is a rival: the two costs disagree, the pair is ambiguous
        let (disagree, _) = choose(
            vec![(at(4.0), 0.60, 0.28), (at(0.0), 0.29, 0.31)],
            Some(0.5),
            0.5,
        );
        assert_eq!(disagree.status, IcpStatus::Ambiguous);
        assert_eq!(disagree.t_ref_moving.translation.x, 0.0);
        assert!(disagree.information.as_ref().unwrap().sigma[0].unwrap() > 2.0);
        // the same place twice is not ambiguous
        let (same, _) = choose(
            vec![(at(0.1), 0.30, 0.30), (at(0.0), 0.29, 0.29)],
            Some(0.95),
            0.5,
        );
        assert_eq!(same.status, IcpStatus::Converged);
    }

    /// A place where a sliding start stopped that fits within the ratio of
    /// the converged winner on their shared samples makes the pair ambiguous
    /// with their spread (the winner's place kept); one clearly worse there
    /// leaves it as it was.
    #[test]
    fn a_sliding_start_that_fits_as_well_elsewhere_is_a_rival() {
        let near = with_slid(at(0.0), vec![(at(6.0), 0.95), (at(9.0), 0.5)]);
        assert_eq!(near.status, IcpStatus::Ambiguous);
        assert_eq!(near.t_ref_moving.translation.x, 0.0);
        assert_eq!(near.ambiguity, Some(0.95));
        // equal mixture of the winner and the one rival: 6 / sqrt 2 m
        let expected = (0.05f64.powi(2) + 36.0 / 2.0).sqrt();
        let sigma = near.information.as_ref().unwrap().sigma;
        assert!((sigma[0].unwrap() - expected).abs() < 1e-9, "{sigma:?}");

        let far = with_slid(at(0.0), vec![(at(6.0), 0.8)]);
        assert_eq!(far.status, IcpStatus::Converged);
        assert_eq!(far.information.as_ref().unwrap().sigma[0], Some(0.05));
        assert_eq!(with_slid(at(0.0), vec![]).status, IcpStatus::Converged);
    }

    /// A winner its backward check (or a restart) did not confirm is
    /// ambiguous, with the spread of every other place a start ended at, whatever its status or
    /// cost (its own place and places within a pixel add nothing); a
    /// confirmed one, or one without a check, is left as it is.
    #[test]
    fn an_unconfirmed_winner_carries_every_place_the_starts_reached() {
        let checked = |confirms: bool| {
            let mut r = at(0.0);
            r.backward = Some(crate::icp::BackwardCheck {
                shift_m: [0.0; 3],
                rotation_deg: [0.0; 3],
                status: IcpStatus::MaxIterations,
                chi_square: Some(30.0),
                beyond_noise: true,
                confirms,
            });
            r
        };
        let mut sliding = at(20.0);
        sliding.status = IcpStatus::MaxIterations;
        let ends = vec![
            (at(0.0), 0.3),
            (at(0.2), 0.3),
            (sliding, 0.9),
            (at(6.0), 0.5),
        ];
        let chosen = unconfirmed(checked(false), &ends, 0.5);
        assert_eq!(chosen.status, IcpStatus::Ambiguous);
        assert_eq!(chosen.t_ref_moving.translation.x, 0.0);
        // equal mixture of the winner and the two other places
        let expected = (0.05f64.powi(2) + (400.0 + 36.0) / 3.0).sqrt();
        let sigma = chosen.information.as_ref().unwrap().sigma;
        assert!((sigma[0].unwrap() - expected).abs() < 1e-9, "{sigma:?}");
        assert!((sigma[1].unwrap() - 0.05).abs() < 1e-9, "{sigma:?}");

        // a restart that ran off does not confirm it either
        let mut ran_off = at(0.0);
        ran_off.restart = Some(crate::icp::RestartCheck {
            tried: 4,
            ran: 3,
            lost: 1,
            ..Default::default()
        });
        assert_eq!(
            unconfirmed(ran_off, &ends, 0.5).status,
            IcpStatus::Ambiguous
        );

        let kept = unconfirmed(checked(true), &ends, 0.5);
        assert_eq!(kept.status, IcpStatus::Converged);
        assert_eq!(kept.information.as_ref().unwrap().sigma[0], Some(0.05));
        assert_eq!(
            unconfirmed(at(0.0), &ends, 0.5).status,
            IcpStatus::Converged
        );
    }
}
