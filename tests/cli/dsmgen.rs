//! `dsmgen tiles --render ...` and the scene flags, run as the built binary.

use std::process::Command;

use dsmstream::synth::{Rendering, Truth};

/// Every rendering writes its tiles and an exact truth.json that names it;
/// the truth (the rigid motions) does not depend on the rendering.
#[test]
fn renderings_write_tiles_and_the_same_truth() {
    let mut truths = Vec::new();
    for (flag, rendering) in [
        ("centre", Rendering::Centre),
        ("lidar-max", Rendering::LidarMax),
        ("tin", Rendering::Tin),
        ("smooth", Rendering::Smooth),
    ] {
        let dir = tempfile::tempdir().unwrap();
        crate::util::dsmgen_tiles(
            &[
                "--count",
                "2",
                "--size",
                "64",
                "--seed",
                "4",
                "--render",
                flag,
                "--dz-offset",
                "150",
            ],
            dir.path(),
        );
        assert!(dir.path().join("tile_01.tif").is_file());
        let truth = Truth::load(&dir.path().join("truth.json")).unwrap();
        let generation = truth.generation.as_ref().unwrap();
        assert_eq!(generation.rendering, rendering);
        assert_eq!(generation.dz_offset_m, 150.0);
        truths.push(truth);
    }
    for t in &truths[1..] {
        assert_eq!(t.tiles[1].matrix_world, truths[0].tiles[1].matrix_world);
    }
    // tile_01 (odd) carries the datum offset on top of its +-2 m draw.
    let dz = truths[0].tiles[1].shift_m[2] - truths[0].tiles[0].shift_m[2];
    assert!((dz - 150.0).abs() <= 4.0, "{dz}");
}

#[test]
fn bad_point_density_is_refused_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_dsmgen"))
        .args(["tiles", "--render", "idw", "--points-per-px", "0", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--points-per-px"), "{err}");
}

#[test]
fn a_pixel_factor_that_does_not_divide_the_tile_is_refused_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_dsmgen"))
        .args(["tiles", "--size", "256", "--odd-gsd-factor", "3", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("pixel factor 3"), "{err}");
}
