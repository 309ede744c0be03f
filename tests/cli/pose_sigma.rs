//! The poses' sigmas where a collection is small: two DSMs that know their
//! relative rotation from one pair, and DSMs of different pixel sizes.

use crate::util::{align_and_score, dsmgen_tiles, ingest};

/// `dsmgen tiles` with `args` into `<dir>/tiles`, ingested into `<dir>/c.zarr`,
/// aligned at the defaults and scored against the truth.
fn generate_and_align(dir: &std::path::Path, args: &[&str]) -> serde_json::Value {
    let tiles = dir.join("tiles");
    dsmgen_tiles(args, &tiles);
    let store = dir.join("c.zarr");
    ingest(std::slice::from_ref(&tiles), &store);
    align_and_score(&store, &tiles.join("truth.json"))
}

fn f(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap()
}

/// Two 2 km DSMs at 2 m sharing a quarter (case 134 of the general battery):
/// their relative yaw comes from the one pair, whose floor (1/20 pixel, as
/// arcs) is most of its yaw sigma. Without each DSM's half of the floor's
/// rotations the poses reported yaw sigmas of 0.0007 deg for errors of
/// 0.0033 deg (4.7 sigma); with it 0.0025 deg.
#[test]
fn two_dsms_carry_their_share_of_the_floor_on_their_rotations() {
    let temp = tempfile::tempdir().unwrap();
    let args = [
        "--count",
        "2",
        "--size",
        "1024",
        "--gsd",
        "2",
        "--overlap",
        "0.25",
        "--render",
        "smooth",
        "--max-shift-m",
        "3",
        "--relief",
        "0.3",
        "--buildings",
        "0",
        "--lakes",
        "0.2",
        "--water",
        "flat",
        "--noise",
        "0.3",
        "--seed",
        "4080",
    ];
    let v = generate_and_align(temp.path(), &args);
    let worst_deg = f(&v["per_dsm"]["worst_deg"]);
    assert!(
        worst_deg > 0.002,
        "{worst_deg} deg: the case no longer has a rotation error to cover"
    );
    let within = &v["per_dsm_sigma"]["rotation"];
    assert_eq!(
        f(&within[2]),
        1.0,
        "DSMs within 1/2/3 rotation sigmas {within}"
    );
}

/// A 2 x 2 grid whose tiles alternate 0.5 m and 1 m pixels over the same
/// footprints (`--odd-gsd-factor 2`: every strip pairs the two sizes), points
/// binned as lidar maxima: every pair is an edge and every DSM is within 5 cm
/// of the truth and within 3 of its sigmas.
#[test]
fn dsms_of_two_pixel_sizes_register_within_their_sigmas() {
    let temp = tempfile::tempdir().unwrap();
    let args = [
        "--layout",
        "grid",
        "--rows",
        "2",
        "--cols",
        "2",
        "--size",
        "512",
        "--overlap",
        "0.3",
        "--seed",
        "21",
        "--odd-gsd-factor",
        "2",
        "--render",
        "lidar-max",
    ];
    let v = generate_and_align(temp.path(), &args);
    let truth = temp.path().join("tiles/truth.json");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(truth).unwrap()).unwrap();
    let gsd: Vec<f64> = (0..4)
        .map(|k| f(&doc["tiles"][k]["geotransform"][1]))
        .collect();
    assert_eq!(gsd, [0.5, 1.0, 1.0, 0.5], "odd tiles at twice the pixel");
    assert_eq!(doc["tiles"][1]["width"], 256);
    assert!(f(&v["per_dsm"]["worst_m"]) < 0.05, "{}", v["per_dsm"]);
    for kind in ["shift", "rotation"] {
        let within = &v["per_dsm_sigma"][kind];
        assert_eq!(f(&within[2]), 1.0, "{kind}: within 1/2/3 sigma {within}");
    }
    let edges = &v["edges"]["count"];
    assert_eq!(edges.as_u64(), Some(6), "every pair in the graph");
}
