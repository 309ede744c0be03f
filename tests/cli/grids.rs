//! Issue 11's grids of small tiles at the default flags, against their
//! targets: many narrow overlaps, weak pairs, three renderings and seeds per
//! grid. Ignored (each collection takes 4-7 minutes on 2 cores); run with
//! `cargo test --release --test cli -- --ignored grids`. The figures in each
//! test's comment are docs/measurements.md's ("The rotation prior weighed by
//! what the data are worth").

use crate::util::{assert_ok, bin, dsmgen, dsmgen_tiles, ingest};

/// What `dsmgen score --json` says of one default `align` of a generated grid.
struct Scored {
    /// The figures below in one line, for messages.
    what: String,
    median_m: f64,
    worst_m: f64,
    worst_deg: f64,
    /// Fractions of DSMs within 3 of their shift and rotation sigmas.
    within_3_sigma: [f64; 2],
}

/// A `rows` x `rows` grid of `size` px tiles (`dsmgen tiles --layout grid`,
/// 30 % overlaps), ingested, aligned at the defaults, scored by `dsmgen score`.
fn align_grid(rows: &str, size: &str, seed: &str, render: &str) -> Scored {
    let temp = tempfile::tempdir().unwrap();
    let dir = temp.path();
    let tiles = dir.join("tiles");
    let layout = [
        "--layout",
        "grid",
        "--overlap",
        "0.3",
        "--rows",
        rows,
        "--cols",
        rows,
        "--size",
        size,
        "--seed",
        seed,
        "--render",
        render,
    ];
    dsmgen_tiles(&layout, &tiles);
    let store = dir.join("c.zarr");
    ingest(std::slice::from_ref(&tiles), &store);
    let poses = dir.join("p.json");
    let run = bin()
        .arg("align")
        .arg(&store)
        .arg("--out")
        .arg(&poses)
        .arg("-q")
        .output()
        .unwrap();
    assert_ok(&run);
    let score = dsmgen()
        .arg("score")
        .arg("--truth")
        .arg(tiles.join("truth.json"))
        .arg("--poses")
        .arg(&poses)
        .arg("--json")
        .output()
        .unwrap();
    assert_ok(&score);
    let v: serde_json::Value = serde_json::from_slice(&score.stdout).unwrap();
    let f = |x: &serde_json::Value| x.as_f64().unwrap();
    let scored = Scored {
        what: String::new(),
        median_m: f(&v["per_dsm"]["median_m"]),
        worst_m: f(&v["per_dsm"]["worst_m"]),
        worst_deg: f(&v["per_dsm"]["worst_deg"]),
        within_3_sigma: [
            f(&v["per_dsm_sigma"]["shift"][2]),
            f(&v["per_dsm_sigma"]["rotation"][2]),
        ],
    };
    let what = format!(
        "{rows} x {rows} seed {seed} {render}: median {} m, worst {} m / {} deg, within 3 sigma {:?}",
        scored.median_m, scored.worst_m, scored.worst_deg, scored.within_3_sigma
    );
    eprintln!("{what}");
    Scored { what, ..scored }
}

/// 20 x 20 DSMs of 128 m (256 px) with 38 m overlaps: per DSM median
/// <= 0.08 m, worst <= 0.25 m and 0.05 deg, every DSM within 3 of its sigmas.
/// Measured 2026-12-04: seed 3 centre 0.0644 / 0.2456 m / 0.0455 deg, seed 5
/// lidar-max 0.0487 / 0.1809 m / 0.0421 deg. (Seed 7 in the sparse TIN
/// rendering, 0.5 points per pixel, reaches the median, 0.060 m, not the
/// worst: 0.80 m, two DSMs beyond 3 sigma, pulled by confidently wrong
/// ambiguous pairs; with every ambiguous pair dropped still 0.71 m:
/// `grids_of_400_sparse_tin_dsms_meet_the_median`.)
#[test]
#[ignore]
fn grids_of_400_dsms_of_128_m_meet_the_targets() {
    for (seed, render) in [("3", "centre"), ("5", "lidar-max")] {
        let s = align_grid("20", "256", seed, render);
        assert!(s.median_m <= 0.08, "{}", s.what);
        assert!(s.worst_m <= 0.25 && s.worst_deg <= 0.05, "{}", s.what);
        assert!(s.within_3_sigma == [1.0, 1.0], "{}", s.what);
    }
}

/// The sparse TIN rendering of the 20 x 20 grid (seed 7): the median target
/// holds and the worst DSM stays under a metre (measured 0.0599 / 0.8029 m).
#[test]
#[ignore]
fn grids_of_400_sparse_tin_dsms_meet_the_median() {
    let s = align_grid("20", "256", "7", "tin");
    assert!(s.median_m <= 0.08 && s.worst_m < 1.0, "{}", s.what);
}

/// 10 x 10 DSMs of 256 m (512 px) with 77 m overlaps: per DSM worst
/// <= 0.10 m, every DSM within 3 of its sigmas.
#[test]
#[ignore]
fn grids_of_100_dsms_of_256_m_meet_the_targets() {
    for (seed, render) in [("4", "centre"), ("6", "lidar-mean"), ("8", "smooth")] {
        let s = align_grid("10", "512", seed, render);
        assert!(s.worst_m <= 0.10, "{}", s.what);
        assert!(s.within_3_sigma == [1.0, 1.0], "{}", s.what);
    }
}
