//! The demo's last word on each collection: one line per part (ingest, align,
//! fuse, eval) saying what was done and what the numbers mean, so a newcomer
//! reads the verdict without decoding the tables above it.

use dsmstream::fuse::FuseReport;
use dsmstream::store::ingest::DsmOutcome;
use dsmstream::synth::score::PairwiseError;

/// Worst relative error between registered DSMs (vs the truth) under which
/// the collection is said to agree: a few cells of a 0.5 m DSM in height.
pub const AGREES_WORST_M: f64 = 0.10;

/// `ingest: 4 DSMs, 0.26 Mpx, 99.2% valid`.
pub fn ingest_line(outcomes: &[DsmOutcome]) -> String {
    let pixels: u64 = outcomes.iter().map(|o| o.width * o.height).sum();
    let valid: u64 = outcomes.iter().map(|o| o.valid_count).sum();
    format!(
        "ingest: {} DSMs, {:.2} Mpx, {:.1}% valid",
        outcomes.len(),
        pixels as f64 / 1e6,
        100.0 * valid as f64 / pixels.max(1) as f64
    )
}

/// `align: 5 pairs, worst pairwise error 3.1 cm (spanning tree 7.2 cm) -> the collection agrees`.
pub fn align_line(pairs: usize, full: &PairwiseError, mst: &PairwiseError) -> String {
    let verdict = if full.worst_m < AGREES_WORST_M {
        "the collection agrees".to_string()
    } else {
        format!(
            "some pair is off by more than {:.0} cm: look at the scene graph plot",
            AGREES_WORST_M * 100.0
        )
    };
    format!(
        "align: {pairs} pairs, worst pairwise error vs truth {}, {:.4} deg (spanning tree {}) -> {verdict}",
        length(full.worst_m),
        full.worst_deg,
        length(mst.worst_m),
    )
}

/// A length in cm below a metre, else in m.
fn length(m: f64) -> String {
    if m.abs() < 1.0 {
        format!("{:.1} cm", 100.0 * m)
    } else {
        format!("{m:.2} m")
    }
}

/// `fuse: 562 x 256 px at 0.5 m, 97.3% valid -> fused_full.tif`.
pub fn fuse_line(r: &FuseReport) -> String {
    let name = r
        .path
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    format!(
        "fuse: {} x {} px at {} m, {:.1}% valid -> {name}",
        r.width,
        r.height,
        r.gsd_m,
        100.0 * r.valid_pixels as f64 / (r.width * r.height).max(1) as f64
    )
}

/// `eval: fused vs truth rmse_tau 1.163 m (uncorrected 1.764 m, true poses
/// 1.156 m) -> registration removed 99% of the misfit poses can remove`.
///
/// The fused mosaic at the true poses is the floor: what is left there is the
/// DSMs' own noise (gridding, occlusions, the generator's errors), which no
/// correction can remove; the share is of the misfit above that floor, so a
/// collection with noisy DSMs does not read as a poor registration.
pub fn eval_line(fused_rmse_m: f64, uncorrected_rmse_m: f64, true_poses_rmse_m: f64) -> String {
    let removable = uncorrected_rmse_m - true_poses_rmse_m;
    let verdict = if removable <= 0.0 {
        "the DSMs were already as aligned as their true poses make them".to_string()
    } else if fused_rmse_m < uncorrected_rmse_m {
        let share = ((uncorrected_rmse_m - fused_rmse_m) / removable).min(1.0);
        format!(
            "registration removed {:.0}% of the misfit poses can remove",
            100.0 * share
        )
    } else {
        "registration did not improve the mosaic".to_string()
    };
    format!(
        "eval: fused vs truth rmse_tau {fused_rmse_m:.3} m (uncorrected {uncorrected_rmse_m:.3} m, \
         true poses {true_poses_rmse_m:.3} m) -> {verdict}"
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use dsmstream::store::ingest::DsmAction;

    fn err(worst_m: f64) -> PairwiseError {
        PairwiseError {
            mean_m: worst_m / 2.0,
            worst_m,
            worst_deg: 0.001,
        }
    }

    #[test]
    fn lines_state_the_numbers_and_the_verdict() {
        let o = DsmOutcome {
            id: "a".into(),
            path: "a.tif".into(),
            action: DsmAction::Ingested,
            width: 500,
            height: 400,
            levels: 3,
            valid_count: 150_000,
            stored_bytes: 0,
            seconds: 0.0,
            georeferenced_by: Vec::new(),
            warped: None,
        };
        assert_eq!(
            ingest_line(&[o.clone(), o]),
            "ingest: 2 DSMs, 0.40 Mpx, 75.0% valid"
        );
        let good = align_line(5, &err(0.031), &err(0.072));
        assert!(good.starts_with("align: 5 pairs, worst pairwise error vs truth 3.1 cm"));
        assert!(good.ends_with("(spanning tree 7.2 cm) -> the collection agrees"));
        let bad = align_line(5, &err(68.28), &err(0.5));
        assert!(
            bad.contains("vs truth 68.28 m, 0.0010 deg (spanning tree 50.0 cm)"),
            "{bad}"
        );
        assert!(bad.contains("off by more than 10 cm"));
        assert_eq!(
            eval_line(1.163, 1.764, 1.156),
            "eval: fused vs truth rmse_tau 1.163 m (uncorrected 1.764 m, true poses 1.156 m) \
             -> registration removed 99% of the misfit poses can remove"
        );
        // a result a hair better than the true poses: all of it, not more
        assert!(
            eval_line(0.027, 1.899, 0.028).ends_with("removed 100% of the misfit poses can remove")
        );
        assert!(eval_line(0.5, 0.5, 0.6).ends_with("as aligned as their true poses make them"));
        assert!(eval_line(2.0, 1.0, 0.5).ends_with("did not improve the mosaic"));
    }
}
