//! Integration tests of what a user from the GIS ecosystem brings and expects:
//! poses files written elsewhere, re-runs that keep finished work, outputs that
//! are not silently replaced.

use std::path::Path;
use std::process::Output;

use serde_json::{json, Value};

use crate::util::{bin, chain4_store, fixtures, ok, run, text};

/// The truth's matrices as `{"poses": [{"id", "matrix_world", <extra>}]}` and
/// nothing else (`lean`), or as a complete poses.json.
fn truth_poses(out: &Path, lean: bool) {
    let truth = fixtures().join("synth/chain4/truth.json");
    let t: Value = serde_json::from_str(&std::fs::read_to_string(truth).unwrap()).unwrap();
    let poses: Vec<Value> = t["tiles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|tile| {
            let mut p = json!({"id": tile["id"], "matrix_world": tile["matrix_world"]});
            if lean {
                p["source"] = json!("another tool");
            }
            p
        })
        .collect();
    let file = if lean {
        json!({"poses": poses, "software": "elsewhere 1.0"})
    } else {
        json!({"crs": t["crs"], "poses": poses, "edges": [], "graph": "full", "gauge": "mean"})
    };
    std::fs::write(out, serde_json::to_string_pretty(&file).unwrap()).unwrap();
}

#[test]
fn a_poses_file_from_elsewhere_fuses_and_evaluates_like_poses_json() {
    let dir = tempfile::tempdir().unwrap();
    let store = chain4_store(dir.path());
    let (lean, full) = (dir.path().join("lean.json"), dir.path().join("full.json"));
    truth_poses(&lean, true);
    truth_poses(&full, false);
    let mut fused = Vec::new();
    let mut evals = Vec::new();
    for poses in [&lean, &full] {
        let out = dir.path().join(format!(
            "{}.tif",
            poses.file_stem().unwrap().to_string_lossy()
        ));
        ok(run(&[
            &"fuse", &store, &"--poses", poses, &"--out", &out, &"-q",
        ]));
        fused.push(std::fs::read(&out).unwrap());
        let e = ok(run(&[&"eval", &store, &"--poses", poses, &"--json"]));
        let mut v: Value = serde_json::from_slice(&e.stdout).unwrap();
        v["poses"] = Value::Null;
        v["seconds"] = Value::Null;
        evals.push(v);
    }
    assert!(fused[0] == fused[1], "same poses, same mosaic");
    assert_eq!(evals[0], evals[1]);
    // The poses are still checked: a missing DSM is named.
    let t: Value = serde_json::from_str(&std::fs::read_to_string(&lean).unwrap()).unwrap();
    let mut short = t.clone();
    short["poses"].as_array_mut().unwrap().pop();
    std::fs::write(&lean, short.to_string()).unwrap();
    let out = run(&[&"eval", &store, &"--poses", &lean]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("no pose for DSM 'tile_03'"),
        "{}",
        text(&out.stderr)
    );
}

fn align(store: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .arg("align")
        .arg(store)
        .arg("--out")
        .arg(out)
        .args(["--threads", "1"])
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn align_again_reuses_the_journal_and_refuses_other_settings_with_a_hint() {
    let dir = tempfile::tempdir().unwrap();
    let store = chain4_store(dir.path());
    let out = dir.path().join("poses.json");
    let first = ok(align(&store, &out, &[]));
    assert!(
        !text(&first.stderr).contains("resumed"),
        "{}",
        text(&first.stderr)
    );
    let poses = std::fs::read(&out).unwrap();
    // Same settings, no flag: every pair comes from the journal, same poses.
    let again = ok(align(&store, &out, &[]));
    let err = text(&again.stderr);
    let reused: usize = err
        .split("resumed: ")
        .nth(1)
        .and_then(|s| s.split(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no resumed line: {err}"));
    let journal = std::fs::read_to_string(dsmstream::journal::Journal::path_for(&out)).unwrap();
    assert_eq!(reused, journal.lines().count() - 1, "{err}");
    assert!(
        std::fs::read(&out).unwrap() == poses,
        "resumed poses differ"
    );
    // Other settings: one line naming the journal and the way out.
    let other = align(&store, &out, &["--min-overlap", "0.2"]);
    let err = text(&other.stderr);
    assert_eq!(other.status.code(), Some(2), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains(".journal") && err.contains("--fresh"), "{err}");
    assert!(!err.contains("IcpConfig"), "{err}");
    // --fresh starts over (nothing reused); --resume stays accepted.
    let fresh = ok(align(&store, &out, &["--min-overlap", "0.2", "--fresh"]));
    assert!(
        !text(&fresh.stderr).contains("resumed"),
        "{}",
        text(&fresh.stderr)
    );
    ok(align(
        &store,
        &out,
        &["--min-overlap", "0.2", "--resume", "-q"],
    ));
    let both = align(&store, &out, &["--resume", "--fresh"]);
    assert_eq!(both.status.code(), Some(2));
}

#[test]
fn fuse_keeps_an_existing_output_unless_forced() {
    let dir = tempfile::tempdir().unwrap();
    let store = chain4_store(dir.path());
    let out = dir.path().join("raw.tif");
    std::fs::write(&out, b"precious").unwrap();
    let refused = run(&[&"fuse", &store, &"--out", &out, &"-q"]);
    let err = text(&refused.stderr);
    assert_eq!(refused.status.code(), Some(2), "{err}");
    assert!(err.contains("raw.tif") && err.contains("--force"), "{err}");
    assert_eq!(std::fs::read(&out).unwrap(), b"precious");
    let per_dsm = dir.path().join("each");
    std::fs::create_dir(&per_dsm).unwrap();
    std::fs::write(per_dsm.join("tile_02.tif"), b"mine").unwrap();
    let refused = run(&[&"fuse", &store, &"--per-dsm", &per_dsm, &"-q"]);
    assert_eq!(refused.status.code(), Some(2));
    assert!(text(&refused.stderr).contains("tile_02.tif"));
    assert!(!per_dsm.join("tile_00.tif").exists(), "nothing written");
    ok(run(&[
        &"fuse",
        &store,
        &"--out",
        &out,
        &"--per-dsm",
        &per_dsm,
        &"--force",
        &"-q",
    ]));
    assert_ne!(std::fs::read(&out).unwrap(), b"precious");
    assert!(per_dsm.join("tile_00.tif").exists());
}

#[test]
fn per_dsm_outputs_sit_on_the_mosaic_lattice() {
    use dsmstream::geo::GeoTransform;
    use dsmstream::geotiff::reader::GeoTiffReader;
    use dsmstream::geotiff::writer::{write_geotiff_f32, CogOptions};
    use dsmstream::synth::output::epsg_crs;
    // A 0.5 m DSM and an overlapping 1 m DSM whose origin is 0.3 m off the
    // 0.5 m lattice, both without a pose.
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("in");
    std::fs::create_dir(&data).unwrap();
    for (name, x0, gsd, n) in [
        ("fine", 500_000.0, 0.5, 64u64),
        ("coarse", 500_010.3, 1.0, 32),
    ] {
        let options = CogOptions {
            geotransform: GeoTransform::north_up(x0, 4_800_000.0, gsd, gsd),
            crs: epsg_crs(32617),
            ..Default::default()
        };
        let heights: Vec<f32> = (0..n * n).map(|k| 200.0 + (k % n) as f32 * 0.1).collect();
        write_geotiff_f32(&data.join(format!("{name}.tif")), n, n, options, &heights).unwrap();
    }
    let store = dir.path().join("s.zarr");
    crate::util::ingest(&[data], &store);
    let (mosaic, each) = (dir.path().join("m.tif"), dir.path().join("each"));
    ok(run(&[
        &"fuse",
        &store,
        &"--out",
        &mosaic,
        &"--per-dsm",
        &each,
        &"-q",
    ]));
    let gt = |p: &Path| GeoTiffReader::open(p).unwrap().info().geotransform.0;
    let m = gt(&mosaic);
    assert_eq!(m[1], 0.5);
    for name in ["fine", "coarse"] {
        let g = gt(&each.join(format!("{name}.tif")));
        assert_eq!((g[1], g[5]), (m[1], m[5]), "{name}: the mosaic's cell");
        for (a, b) in [(g[0], m[0]), (g[3], m[3])] {
            let cells = (a - b) / m[1];
            assert!(
                (cells - cells.round()).abs() < 1e-6,
                "{name}: {cells} cells off the lattice"
            );
        }
    }
}

#[test]
fn ingest_reads_an_input_list_file() {
    let dir = tempfile::tempdir().unwrap();
    let chain4 = fixtures().join("synth/chain4");
    let list = dir.path().join("list.txt");
    let lines = format!(
        "# two of the four tiles\n{}\n\n  {}  \n",
        chain4.join("tile_00.tif").display(),
        chain4.join("tile_02.tif").display()
    );
    std::fs::write(&list, lines).unwrap();
    let store = dir.path().join("s.zarr");
    let at_list = format!("@{}", list.display());
    let out = ok(run(&[&"ingest", &at_list, &"--store", &store]));
    let summary = text(&out.stdout);
    assert!(summary.contains("2 ingested"), "{summary}");
    let info = ok(run(&[&"info", &store]));
    let listing = text(&info.stdout);
    assert!(
        listing.contains("tile_02") && !listing.contains("tile_01"),
        "{listing}"
    );
    let missing = format!("@{}", dir.path().join("none.txt").display());
    let refused = run(&[&"ingest", &missing, &"--store", &store]);
    assert_eq!(refused.status.code(), Some(2));
    assert!(
        text(&refused.stderr).contains("none.txt"),
        "{}",
        text(&refused.stderr)
    );
}

#[test]
fn ingest_reports_a_mixed_vertical_reference() {
    use dsmstream::geo::{Crs, GeoTransform};
    use dsmstream::geotiff::writer::{write_geotiff_f32, CogOptions};
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("in");
    std::fs::create_dir(&data).unwrap();
    // Projected EPSG:32617, one with VerticalCSTypeGeoKey 5703 (NAVD88 height).
    let keys = |vertical: bool| {
        let mut k: Vec<u16> = vec![1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32617];
        if vertical {
            k[3] = 4;
            k.extend([4096, 0, 1, 5703]);
        }
        k
    };
    for (name, vertical) in [("geoid", true), ("plain", false)] {
        let options = CogOptions {
            geotransform: GeoTransform::north_up(500_000.0, 4_800_000.0, 1.0, 1.0),
            crs: Crs {
                epsg: Some(32617),
                geokeys: keys(vertical),
                ..Default::default()
            },
            ..Default::default()
        };
        write_geotiff_f32(
            &data.join(format!("{name}.tif")),
            32,
            32,
            options,
            &[100.0; 1024],
        )
        .unwrap();
    }
    let store = dir.path().join("s.zarr");
    let out = ok(run(&[&"ingest", &data, &"--store", &store]));
    let err = text(&out.stderr);
    assert!(
        err.contains("mixed vertical reference (EPSG:5703: geoid; none: plain)"),
        "{err}"
    );
    // One reference for all: no warning.
    std::fs::remove_file(data.join("plain.tif")).unwrap();
    let other = dir.path().join("t.zarr");
    let out = ok(run(&[&"ingest", &data, &"--store", &other]));
    assert!(
        !text(&out.stderr).contains("vertical"),
        "{}",
        text(&out.stderr)
    );
}

#[test]
fn demo_runs_from_any_directory_and_removes_its_temporary_folder() {
    let cwd = tempfile::tempdir().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let out = ok(bin()
        .arg("demo")
        .current_dir(cwd.path())
        .env("TMPDIR", tmp.path())
        .output()
        .unwrap());
    let stdout = text(&out.stdout);
    assert!(stdout.contains("=== 2. real terrain"), "{stdout}");
    let left: Vec<_> = std::fs::read_dir(tmp.path()).unwrap().collect();
    assert!(left.is_empty(), "left in the temp dir: {left:?}");
    assert!(
        std::fs::read_dir(cwd.path()).unwrap().next().is_none(),
        "wrote into the cwd"
    );
}
