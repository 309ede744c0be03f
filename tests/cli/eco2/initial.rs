//! `--initial`: a DSM moved beyond the search radius is recovered from
//! approximate initial poses (align and pair), the gauge follows them, and the
//! journal records them.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix4, Vector3};
use serde_json::{json, Value};

use super::{error_m, matrix, rewrite, translation, Box2, Truth};
use crate::util::{fixtures, ingest, ok, run, text};

/// The chain4 fixture with tile_03 moved by `shift` (its file's origin), in `dir/s.zarr`.
fn shifted_chain(dir: &Path, shift: (f64, f64)) -> (PathBuf, Truth) {
    let tiles = dir.join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    let chain4 = fixtures().join("synth/chain4");
    for name in [
        "tile_00.tif",
        "tile_01.tif",
        "tile_02.tif",
        "tile_03.tif",
        "truth.json",
    ] {
        std::fs::copy(chain4.join(name), tiles.join(name)).unwrap();
    }
    rewrite(&tiles.join("tile_03.tif"), shift, |_, _, h| h);
    let store = dir.join("s.zarr");
    ingest(std::slice::from_ref(&tiles), &store);
    (store, Truth::load(&tiles))
}

/// The error of tile_02^-1 tile_03 in `poses` against the truth with tile_03
/// moved by `shift` (the correction must first undo it), at tile_03's corners.
fn chain_error(poses: &Path, truth: &Truth, shift: (f64, f64)) -> f64 {
    let doc: Value = serde_json::from_str(&std::fs::read_to_string(poses).unwrap()).unwrap();
    let pose = |id: &str| {
        let p = doc["poses"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["id"] == id)
            .unwrap();
        matrix(&p["matrix_world"])
    };
    let undo = translation(Vector3::new(-shift.0, -shift.1, 0.0));
    let rel_truth = truth.m(2).try_inverse().unwrap() * truth.m(3) * undo;
    let rel = pose("tile_02").try_inverse().unwrap() * pose("tile_03");
    let g = truth.gt(3);
    let tile = Box2 {
        min_x: g[0] + shift.0,
        max_x: g[0] + shift.0 + 128.0,
        min_y: g[3] + shift.1 - 128.0,
        max_y: g[3] + shift.1,
    };
    error_m(&rel, &rel_truth, &tile.corners())
}

#[test]
fn initial_poses_recover_a_dsm_offset_beyond_the_search_radius() {
    let dir = tempfile::tempdir().unwrap();
    let shift = (40.0, -30.0);
    let (store, truth) = shifted_chain(dir.path(), shift);
    let radius = ["--max-displacement", "15"];
    // without: the offset is beyond the search radius
    let plain = dir.path().join("plain.json");
    let out = run(&[&"align", &store, &"--out", &plain, &radius[0], &radius[1]]);
    let failed = !out.status.success() || chain_error(&plain, &truth, shift) > 5.0;
    assert!(failed, "{}", text(&out.stdout));
    // with 80 % of the offset given as tile_03's initial pose
    let initial = dir.path().join("initial.json");
    let start = translation(Vector3::new(-0.8 * shift.0, -0.8 * shift.1, 0.0));
    let rows: Vec<Vec<f64>> = (0..4)
        .map(|r| (0..4).map(|c| start[(r, c)]).collect())
        .collect();
    let doc = json!({"poses": [{"id": "tile_03", "matrix_world": rows}]});
    std::fs::write(&initial, doc.to_string()).unwrap();
    let poses = dir.path().join("poses.json");
    ok(run(&[
        &"align",
        &store,
        &"--out",
        &poses,
        &radius[0],
        &radius[1],
        &"--initial",
        &initial,
    ]));
    let e = chain_error(&poses, &truth, shift);
    assert!(e < 0.15, "with --initial: {e} m");
    // the mean gauge follows the initial poses: on average the poses move the
    // collection's centre as the initial ones do
    let doc: Value = serde_json::from_str(&std::fs::read_to_string(&poses).unwrap()).unwrap();
    let o = nalgebra::Vector4::new(
        500_140.0 + shift.0 / 4.0,
        4_799_936.0 + shift.1 / 4.0,
        200.0,
        1.0,
    );
    let mut mean = Vector3::zeros();
    for p in doc["poses"].as_array().unwrap() {
        let initial = if p["id"] == "tile_03" {
            start
        } else {
            Matrix4::identity()
        };
        mean += (matrix(&p["matrix_world"]) * o - initial * o).xyz() / 4.0;
    }
    assert!(
        mean.norm() < 0.02,
        "mean offset from the initial poses {mean}"
    );
    // pair takes the same file
    let out = ok(run(&[
        &"pair",
        &store,
        &"tile_02",
        &"tile_03",
        &"--json",
        &radius[0],
        &radius[1],
        &"--initial",
        &initial,
    ]));
    let doc: Value = serde_json::from_slice(&out.stdout).unwrap();
    let undo = translation(Vector3::new(-shift.0, -shift.1, 0.0));
    let rel_truth = truth.m(2).try_inverse().unwrap() * truth.m(3) * undo;
    let g = truth.gt(3);
    let corner = [(g[0] + shift.0 + 10.0, g[3] + shift.1 - 10.0)];
    let e = error_m(&matrix(&doc["matrix_world"]), &rel_truth, &corner);
    assert!(e < 0.15, "pair --initial: {e} m");
    // the gauge follows the initial poses: an anchor keeps its initial pose
    let anchored = dir.path().join("anchored.json");
    ok(run(&[
        &"align",
        &store,
        &"--out",
        &anchored,
        &radius[0],
        &radius[1],
        &"--initial",
        &initial,
        &"--anchor",
        &"tile_03",
    ]));
    let doc: Value = serde_json::from_str(&std::fs::read_to_string(&anchored).unwrap()).unwrap();
    let p3 = doc["poses"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["id"] == "tile_03")
        .unwrap();
    assert!(
        (matrix(&p3["matrix_world"]) - start).amax() < 1e-9,
        "{}",
        p3
    );
    assert!(chain_error(&anchored, &truth, shift) < 0.15);
    // the journal records the initial poses: another file is refused
    let other = dir.path().join("other.json");
    std::fs::write(&other, r#"{"poses": []}"#).unwrap();
    let out = run(&[
        &"align",
        &store,
        &"--out",
        &poses,
        &radius[0],
        &radius[1],
        &"--initial",
        &other,
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("--initial"),
        "{}",
        text(&out.stderr)
    );
}
