//! Pairs of 64 m tiles that meet in a 19 m strip (fixtures/synth/narrow64,
//! four tiles of the 50 x 50 grid of seed 5): where `pair` once gave wrong
//! answers with sub-metre sigmas, it must now be right or say how unsure it is.

use crate::util::{fixtures, pair_json, shift_and_sigma};

/// Runs `pair` on two tiles of narrow64: the exit code, the JSON, and the
/// error (estimate minus truth, metres) and reported sigma of the shift at
/// the fit's centre, per axis.
fn pair(reference: &str, moving: &str) -> (Option<i32>, serde_json::Value, [f64; 3], [f64; 3]) {
    let dir = tempfile::tempdir().unwrap();
    pair_in(
        &fixtures().join("synth/narrow64"),
        &dir.path().join("s.zarr"),
        reference,
        moving,
    )
}

/// [`pair`] on two tiles of the folder `tiles` (with its truth.json),
/// ingested into `store`.
fn pair_in(
    tiles: &std::path::Path,
    store: &std::path::Path,
    reference: &str,
    moving: &str,
) -> (Option<i32>, serde_json::Value, [f64; 3], [f64; 3]) {
    let tif = |id: &str| tiles.join(format!("{id}.tif"));
    crate::util::ingest(&[tif(reference), tif(moving)], store);
    let (code, v) = pair_json(store, reference, moving);
    let error = crate::util::shift_error(&tiles.join("truth.json"), reference, moving, &v);
    let sigma = shift_and_sigma(&v).1;
    (code, v, error, sigma)
}

/// Asserts that each of the shift `axes` (0 x, 1 y, 2 z) is within 3 sigma.
fn within_3_sigma(
    axes: std::ops::Range<usize>,
    error: &[f64; 3],
    sigma: &[f64; 3],
    v: &serde_json::Value,
) {
    for k in axes {
        assert!(
            error[k].abs() <= 3.0 * sigma[k],
            "axis {k}: {error:?} against {sigma:?}: {v}"
        );
    }
}

/// `pair` on two tiles of a collection `dsmgen tiles` generates with `args`
/// (whitespace-separated): what [`pair`] returns.
fn generated_pair(
    args: &str,
    reference: &str,
    moving: &str,
) -> (Option<i32>, serde_json::Value, [f64; 3], [f64; 3]) {
    let temp = tempfile::tempdir().unwrap();
    let tiles = temp.path().join("tiles");
    let args: Vec<&str> = args.split_whitespace().collect();
    crate::util::dsmgen_tiles(&args, &tiles);
    pair_in(&tiles, &temp.path().join("s.zarr"), reference, moving)
}

/// tile_941 slid 15 m along its strip onto a smooth 8 m of field and was
/// reported to 0.4 m. The data favour that place (on the samples both places
/// share, the truth's heights differ by 1.2 m NMAD, a changed area, the slid
/// place's by 0.55 m), so the pair cannot be right from its data alone; it
/// must say so: where it was georeferenced the overlap holds a changed
/// building, so the slide and the second height join the sigmas, and every
/// axis is within 3 sigma of the truth.
#[test]
fn a_fit_that_slid_along_a_narrow_overlap_carries_the_slide_in_its_sigmas() {
    let (code, v, error, sigma) = pair("tile_940", "tile_941");
    within_3_sigma(0..3, &error, &sigma, &v);
    if error.iter().any(|e| e.abs() > 2.0) {
        assert_eq!(code, Some(1), "metres off must not exit 0: {v}");
        assert_eq!(v["status"], "ambiguous");
    }
}

/// tile_328 holds a 4.5 m platform over 70 % of the strip that tile_327 does
/// not: the fit on the platform was 3 m off in height at 5 cm. The ground
/// under the other 30 % is within ICP's 10 m outlier threshold but beyond
/// Tukey's cut-off: a second height. The pair is ambiguous (exit 1) and its
/// height sigma covers the truth.
#[test]
fn a_platform_over_most_of_a_narrow_overlap_makes_the_height_ambiguous() {
    let (code, v, error, sigma) = pair("tile_327", "tile_328");
    assert_eq!(code, Some(1), "{v}");
    assert_eq!(v["status"], "ambiguous");
    let second = &v["result"]["second_height"];
    assert!(second["share"].as_f64().unwrap() >= 0.2, "{second}");
    let gap = second["gap_m"].as_f64().unwrap();
    assert!((2.0..5.0).contains(&gap.abs()), "{second}");
    within_3_sigma(2..3, &error, &sigma, &v);
}

/// tile_1891 -> tile_1892 of the same grid: the best place within half their
/// 19 m strip lay on its edge, the radius doubled to 19 m and the pair
/// converged 12 m off at 4 sigma, every check of the pair confirming it. The
/// grid's clear pairs lie within 5 m: in a 4 x 4 block around the pair,
/// `align` judges that answer `ambiguous` (its edge is not `converged` and
/// its DSM not placed by it) and says so. (tile_159 -> tile_160, 21 m off,
/// was this test's pair until its restarts judged it on its own.)
#[test]
fn a_converged_answer_beyond_the_collections_offsets_is_not_trusted() {
    let temp = tempfile::tempdir().unwrap();
    let dir = temp.path();
    let tiles = dir.join("tiles");
    crate::util::grid_tiles(&tiles, "50", "128", "5", "centre");
    let block: Vec<_> = (36..40)
        .flat_map(|r| (40..44).map(move |c| r * 50 + c))
        .map(|k| tiles.join(format!("tile_{k}.tif")))
        .collect();
    let store = dir.join("b.zarr");
    crate::util::ingest(&block, &store);
    let (_, v) = pair_json(&store, "tile_1891", "tile_1892");
    let error = crate::util::shift_error(&tiles.join("truth.json"), "tile_1891", "tile_1892", &v);
    assert!(
        v["status"] == "converged" && error[0].hypot(error[1]) > 10.0,
        "the pair no longer converges far off alone: {error:?} {v}"
    );
    let poses = dir.join("p.json");
    let run = crate::util::run(&[&"align", &store, &"--out", &poses]);
    crate::util::assert_ok(&run);
    let out = crate::util::text(&run.stdout);
    assert!(
        out.contains("1 of 2 searches widened beyond half an overlap converged farther than"),
        "{out}"
    );
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&poses).unwrap()).unwrap();
    let edge = (doc["edges"].as_array().unwrap().iter())
        .find(|e| e["i"] == "tile_1891" && e["j"] == "tile_1892")
        .unwrap();
    assert_eq!(edge["converged"], false, "{edge}");
    let pose = (doc["poses"].as_array().unwrap().iter())
        .find(|p| p["id"] == "tile_1892")
        .unwrap();
    assert!(
        pose["status"] == "weak" || pose["status"] == "unconstrained",
        "{pose}"
    );
}

/// tile_159 -> tile_160 (fixtures/synth/README.md): the search widened to
/// 38 m and the one start of ten that converged put tile_160 21 m off with
/// metre sigmas (20 sigma), backward check confirming. Three of its four
/// restarts, pushed a few pixels aside, ran off instead of returning: the
/// answer is no basin, the pair is ambiguous and exits 1.
#[test]
fn an_answer_its_restarts_run_off_from_is_ambiguous() {
    let (code, v, error, _) = pair("tile_159", "tile_160");
    assert!(
        error[1].abs() > 10.0,
        "the pair now finds its place: {error:?} {v}"
    );
    assert!(v["result"]["restart"]["lost"].as_u64().unwrap() > 0, "{v}");
    assert_eq!(v["status"], "ambiguous", "{v}");
    assert_eq!(code, Some(1), "{v}");
}

/// Two 128 m tiles at 0.5 m sharing a 38 m strip, the second 72 m off
/// (k=9 of `tools/scripts/pair_battery.py --narrow`): the truth lies beyond
/// the search cut to half the strip, and the best place within it was a
/// chance fit among nearly equal ones. `pair` converged 70 m off with 1.3 m
/// sigmas from the georeferenced start, while the three other starts slid
/// to places 6-10 m away at lower costs and fit within 4 % of it on the
/// samples they share: the pair is ambiguous, exits 1, and its horizontal
/// sigmas say it does not know the place to tens of metres.
#[test]
fn a_converged_answer_that_other_starts_slid_past_is_ambiguous() {
    let args = "--layout chain --count 2 --size 256 --gsd 0.5 --overlap 0.3 --render centre \
                --max-shift-m 50 --relief 0.3 --buildings 0.55 --lakes 0.2 --water flat \
                --noise 0.3 --seed 3331";
    let (code, v, error, sigma) = generated_pair(args, "tile_00", "tile_01");
    assert!(
        error[0].hypot(error[1]) > 10.0,
        "the pair now finds its place: {error:?} {v}"
    );
    assert_eq!(v["status"], "ambiguous", "{error:?} {v}");
    assert_eq!(code, Some(1), "{v}");
    assert!(sigma[0].min(sigma[1]) > 10.0, "{sigma:?} {v}");
}

/// Two 128 m tiles at 0.5 m meeting in a 32 m square corner, 35 m apart
/// across it (k=56 of `tools/scripts/pair_battery.py --narrow`): the truth
/// lies beyond the widened search, and three starts converged at a chance
/// fit 39 m off, reported to 1.5-3.6 m. Registering the reference onto the
/// moving DSM from that answer was still sliding when its iterations ran
/// out, 3.7 m away (chi-square 223): the answer is not confirmed, the pair
/// is ambiguous and exits 1.
#[test]
fn an_answer_the_backward_check_slides_away_from_is_ambiguous() {
    let args = "--layout grid --rows 2 --cols 2 --size 256 --gsd 0.5 --overlap 0.25 \
                --render lidar-max --max-shift-m 50 --dz-offset 150 --relief 0.3 \
                --buildings 0.55 --lakes 0.5 --water flat --noise 0.3 --seed 7833";
    let (code, v, error, _) = generated_pair(args, "tile_01", "tile_02");
    assert!(
        error[0].hypot(error[1]) > 10.0,
        "the pair now finds its place: {error:?} {v}"
    );
    assert_eq!(v["result"]["backward"]["confirms"], false, "{v}");
    assert_eq!(v["status"], "ambiguous", "{error:?} {v}");
    assert_eq!(code, Some(1), "{v}");
}

/// tile_2397 -> tile_2398 (fixtures/synth/README.md): converged 21 m off
/// with 1.3 m sigmas; the backward run holds a direction the forward fit
/// measured, so the pair is ambiguous, exits 1, and the places its starts
/// reached (the truth among them) put every axis within 3 sigma.
#[test]
fn an_answer_the_backward_check_cannot_fix_is_ambiguous() {
    let (code, v, error, sigma) = pair("tile_2397", "tile_2398");
    assert!(
        error[0].abs() > 10.0,
        "the pair now finds its place: {error:?} {v}"
    );
    assert_eq!(v["result"]["backward"]["confirms"], false, "{v}");
    assert_eq!(v["status"], "ambiguous", "{v}");
    assert_eq!(code, Some(1), "{v}");
    within_3_sigma(0..3, &error, &sigma, &v);
}

/// A corner pair of 2 m lidar-mean tiles on sloping ground (case 149 of
/// `pair_battery.py --narrow`): the corner holds too little to fix x and y,
/// so the fit holds them where the search put it, 37 m from the truth, and
/// measures the height there. The ground slopes, so that height is 1.4 m off;
/// it was reported to 0.07 m (20 sigma). The held start's error along the
/// slope now joins the height's sigma: within 3 sigma, x and y still held.
#[test]
fn a_height_measured_at_a_held_start_carries_the_starts_error() {
    let args = "--layout grid --rows 2 --cols 2 --size 256 --gsd 2.0 --overlap 0.25 \
                --render lidar-mean --max-shift-m 50 --dz-offset 0 --relief 1 \
                --buildings 0.0 --lakes 0.2 --water nan --noise 1.0 --seed 2637";
    let (code, v, error, sigma) = generated_pair(args, "tile_00", "tile_03");
    assert_eq!(v["status"], "degenerate", "{error:?} {v}");
    assert!(
        error[0].hypot(error[1]) > 10.0 && error[2].abs() > 0.5,
        "the pair now finds its place: {error:?} {v}"
    );
    assert!(
        sigma[0].is_infinite() && sigma[1].is_infinite(),
        "x, y held: {v}"
    );
    within_3_sigma(2..3, &error, &sigma, &v);
    assert_eq!(code, Some(0), "degenerate with its held axes said: {v}");
}

/// Case 154 of `pair_battery.py --narrow` (2 m smooth tiles, a 77 m strip):
/// x is held, and the backward registration ends 11.7 m away along it. That
/// gap says nothing about the measured directions; projected in mixed units
/// (metres with radians) it read as a pitch sigma of 228 deg. Now every
/// rotation sigma stays within a degree.
#[test]
fn a_gap_along_a_held_direction_leaves_the_rotations_alone() {
    let args = "--layout grid --rows 2 --cols 2 --size 256 --gsd 2.0 --overlap 0.15 \
                --render smooth --max-shift-m 50 --dz-offset 0 --relief 0.3 \
                --buildings 0.1 --lakes 0.2 --water nan --noise 0.3 --seed 9936";
    let (_, v, _, _) = generated_pair(args, "tile_02", "tile_03");
    assert_eq!(v["status"], "degenerate", "{v}");
    for k in 0..3 {
        let sigma = v["sigma"]["rotation_deg"][k].as_f64().unwrap();
        assert!(sigma < 1.0, "rotation {k}: sigma {sigma} deg: {v}");
    }
}
