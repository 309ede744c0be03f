//! Reliability of the store (issue 15): concurrent ingests, poisoned inputs,
//! damaged stores, missing chunks, leftovers of killed runs, exit codes.
//! `S` below is fixtures/synth/grid2x2 ingested with `--chunk 64`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::Value;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dsmstream"))
}

fn grid2x2() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/synth/grid2x2")
}

fn run(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Output {
    let mut c = bin();
    for a in args {
        c.arg(a);
    }
    c.output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn ok(out: Output) -> Output {
    assert!(
        out.status.success(),
        "exit {:?}: {}",
        out.status.code(),
        stderr(&out)
    );
    out
}

/// Exit code 2 with a one-line error containing `needle`, and no panic.
fn refused(out: Output, needle: &str) -> String {
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains(needle), "{needle:?} not in {err}");
    assert!(!err.contains("panicked"), "{err}");
    let error_lines = err.lines().filter(|l| l.starts_with("error:")).count();
    assert_eq!(error_lines, 1, "{err}");
    err
}

/// `S`: grid2x2 ingested with --chunk 64 into `dir/s.zarr`.
fn store_s(dir: &Path) -> PathBuf {
    let store = dir.join("s.zarr");
    ok(run(&[
        &"ingest",
        &grid2x2(),
        &"--store",
        &store,
        &"--chunk",
        &"64",
        &"-q",
    ]));
    store
}

fn catalog(store: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(store.join("zarr.json")).unwrap()).unwrap()
}

fn catalog_ids(store: &Path) -> Vec<String> {
    let c = catalog(store);
    let mut ids: Vec<String> = c["attributes"]["dsmstream"]["dsms"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect();
    ids.sort();
    ids
}

/// Edit the JSON file at `path` in place.
fn edit_json(path: &Path, f: impl FnOnce(&mut Value)) {
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

/// Offset of the value of TIFF tag `tag` (classic little-endian TIFF), and its type.
fn tiff_entry(bytes: &[u8], tag: u16) -> (usize, usize) {
    let u16_at = |o: usize| u16::from_le_bytes([bytes[o], bytes[o + 1]]);
    let u32_at = |o: usize| u32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    assert_eq!(&bytes[..4], b"II*\0");
    let ifd = u32_at(4) as usize;
    for i in 0..u16_at(ifd) as usize {
        let e = ifd + 2 + 12 * i;
        if u16_at(e) == tag {
            return (e, u32_at(e + 8) as usize);
        }
    }
    panic!("no tag {tag}");
}

/// tile_00 with ModelPixelScale (x, y) replaced.
fn with_pixel_scale(out: &Path, sx: f64, sy: f64) {
    let mut b = std::fs::read(grid2x2().join("tile_00.tif")).unwrap();
    let (_, at) = tiff_entry(&b, 33550);
    b[at..at + 8].copy_from_slice(&sx.to_le_bytes());
    b[at + 8..at + 16].copy_from_slice(&sy.to_le_bytes());
    std::fs::write(out, b).unwrap();
}

/// tile_00 with the TIFF type of tag `tag` set to UNDEFINED (7).
fn with_undefined_tag(out: &Path, tag: u16) {
    let mut b = std::fs::read(grid2x2().join("tile_00.tif")).unwrap();
    let (entry, _) = tiff_entry(&b, tag);
    b[entry + 2..entry + 4].copy_from_slice(&7u16.to_le_bytes());
    std::fs::write(out, b).unwrap();
}

/// The pid of a process that has exited.
fn dead_pid() -> u32 {
    let mut child = Command::new("true").spawn().unwrap();
    let pid = child.id();
    child.wait().unwrap();
    pid
}

#[test]
fn nine_concurrent_ingests_keep_nine_dsms() {
    let dir = tempfile::tempdir().unwrap();
    let inputs: Vec<PathBuf> = (0..9)
        .map(|k| {
            let p = dir.path().join(format!("d{k}.tif"));
            std::fs::copy(grid2x2().join(format!("tile_0{}.tif", k % 4)), &p).unwrap();
            p
        })
        .collect();
    // Into one existing store, and into one store none of them finds.
    let existing = dir.path().join("existing.zarr");
    ok(run(&[
        &"ingest",
        &grid2x2().join("tile_00.tif"),
        &"--store",
        &existing,
        &"-q",
    ]));
    for store in [existing, dir.path().join("fresh.zarr")] {
        let children: Vec<_> = inputs
            .iter()
            .map(|p| {
                bin()
                    .args(["ingest", "-q", "--chunk", "64", "--store"])
                    .arg(&store)
                    .arg(p)
                    .stdout(std::process::Stdio::null())
                    .stderr(std::process::Stdio::piped())
                    .spawn()
                    .unwrap()
            })
            .collect();
        for c in children {
            ok(c.wait_with_output().unwrap());
        }
        let ids = catalog_ids(&store);
        let want: Vec<String> = (0..9).map(|k| format!("d{k}")).collect();
        let got: Vec<String> = ids.into_iter().filter(|i| i.starts_with('d')).collect();
        assert_eq!(got, want, "{}", store.display());
        ok(run(&[&"check", &store]));
    }
}

#[test]
fn implausible_geotiffs_are_refused_at_ingest_and_leave_no_store() {
    let dir = tempfile::tempdir().unwrap();
    type Make = Box<dyn Fn(&Path)>;
    let cases: Vec<(&str, Make, &str)> = vec![
        (
            "huge.tif",
            Box::new(|p| with_pixel_scale(p, 1e308, 1e308)),
            "implausible",
        ),
        (
            "tiny.tif",
            Box::new(|p| with_pixel_scale(p, 1e-300, 1e-300)),
            "implausible",
        ),
        (
            "nocrs.tif",
            Box::new(|p| with_undefined_tag(p, 34735)),
            "no CRS",
        ),
    ];
    for (name, make, needle) in cases {
        let file = dir.path().join(name);
        make(&file);
        let store = dir.path().join(format!("{name}.zarr"));
        let err = refused(run(&[&"ingest", &file, &"--store", &store]), needle);
        assert!(err.contains(name), "{err}");
        assert!(
            !store.exists(),
            "{name}: a store was left at {}",
            store.display()
        );
    }
    // Geo tags of type UNDEFINED are not numbers: ignored as GDAL does.
    let file = dir.path().join("undef_scale.tif");
    with_undefined_tag(&file, 33550);
    let err = refused(
        run(&[&"ingest", &file, &"--store", &dir.path().join("u.zarr")]),
        "no georeferencing",
    );
    assert!(err.contains("undef_scale.tif"), "{err}");
}

#[test]
fn a_damaged_dsm_group_is_reported_and_left_out() {
    let dir = tempfile::tempdir().unwrap();
    let store = store_s(dir.path());
    let group = store.join("tile_01/zarr.json");
    let original = std::fs::read_to_string(&group).unwrap();
    type Damage = Box<dyn Fn(&mut Value)>;
    let damages: Vec<(&str, Damage)> = vec![
        (
            "scale 1e308",
            Box::new(|v| v["attributes"]["dsmstream"]["geotransform"][1] = 1e308.into()),
        ),
        (
            "footprint null",
            Box::new(|v| v["attributes"]["dsmstream"]["footprint"][2] = Value::Null),
        ),
        (
            "chunk 0",
            Box::new(|v| v["attributes"]["dsmstream"]["levels"][0]["chunk"] = 0.into()),
        ),
        (
            "no levels",
            Box::new(|v| v["attributes"]["dsmstream"]["levels"] = Value::Array(vec![])),
        ),
    ];
    for (what, damage) in damages {
        std::fs::write(&group, &original).unwrap();
        edit_json(&group, damage);
        let out = ok(run(&[&"info", &store, &"--json"]));
        let err = stderr(&out);
        assert!(
            err.contains("tile_01") && err.contains("left out"),
            "{what}: {err}"
        );
        let info: Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(info["dsms"].as_array().unwrap().len(), 3, "{what}");
        let fuse = run(&[&"fuse", &store, &"--out", &dir.path().join("f.tif"), &"-q"]);
        assert!(
            !stderr(&fuse).contains("panicked"),
            "{what}: {}",
            stderr(&fuse)
        );
        let check = run(&[&"check", &store]);
        assert_eq!(check.status.code(), Some(1), "{what}");
        let text = String::from_utf8_lossy(&check.stdout);
        assert!(
            text.contains("DAMAGED  tile_01") && text.contains("re-ingest tile_01"),
            "{what}: {text}"
        );
    }
    // Re-ingesting the damaged DSM repairs the store.
    ok(run(&[
        &"ingest",
        &grid2x2().join("tile_01.tif"),
        &"--store",
        &store,
        &"-q",
    ]));
    ok(run(&[&"check", &store]));
}

#[test]
fn unsafe_or_duplicate_catalog_ids_are_refused_on_open() {
    let dir = tempfile::tempdir().unwrap();
    let store = store_s(dir.path());
    let root = store.join("zarr.json");
    let original = std::fs::read_to_string(&root).unwrap();
    edit_json(&root, |v| {
        v["attributes"]["dsmstream"]["dsms"][0] = "../outside".into()
    });
    refused(run(&[&"info", &store]), "../outside");
    std::fs::write(&root, &original).unwrap();
    edit_json(&root, |v| {
        let ids = v["attributes"]["dsmstream"]["dsms"].as_array_mut().unwrap();
        let first = ids[0].clone();
        ids.push(first);
    });
    refused(run(&[&"info", &store]), "\"tile_00\" twice");
    refused(
        run(&[&"align", &store, &"--out", &dir.path().join("p.json")]),
        "\"tile_00\" twice",
    );
}

#[test]
fn a_missing_chunk_is_an_error_not_no_data() {
    let dir = tempfile::tempdir().unwrap();
    let store = store_s(dir.path());
    let chunk = store.join("tile_01/0/c/1/1");
    assert!(chunk.is_file());
    std::fs::remove_file(&chunk).unwrap();
    let name = chunk.display().to_string();
    refused(
        run(&[&"fuse", &store, &"--out", &dir.path().join("f.tif")]),
        &name,
    );
    assert!(!dir.path().join("f.tif").exists());
    refused(run(&[&"eval", &store]), &name);
    let check = run(&[&"check", &store, &"--json"]);
    assert_eq!(check.status.code(), Some(1), "{}", stderr(&check));
    let report: Value = serde_json::from_slice(&check.stdout).unwrap();
    let bad: Vec<&Value> = report["dsms"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|d| d["ok"] == false)
        .collect();
    assert_eq!(bad.len(), 1, "{report}");
    assert_eq!(bad[0]["id"], "tile_01");
    assert!(
        bad[0]["problems"][0].as_str().unwrap().contains(&name),
        "{report}"
    );
    // --force re-ingest repairs it; an unchanged source alone is skipped.
    ok(run(&[
        &"ingest",
        &"--force",
        &grid2x2().join("tile_01.tif"),
        &"--store",
        &store,
        &"-q",
    ]));
    ok(run(&[&"check", &store]));
    ok(run(&[
        &"fuse",
        &store,
        &"--out",
        &dir.path().join("f.tif"),
        &"-q",
    ]));
}

#[test]
fn a_garbled_chunk_and_changed_statistics_are_found_by_check() {
    let dir = tempfile::tempdir().unwrap();
    let store = store_s(dir.path());
    std::fs::write(store.join("tile_02/1/c/0/0"), b"not zstd").unwrap();
    edit_json(&store.join("tile_03/zarr.json"), |v| {
        let m = &mut v["attributes"]["dsmstream"]["height_stats"]["mean"];
        *m = (m.as_f64().unwrap() + 0.5).into();
    });
    let check = run(&[&"check", &store]);
    assert_eq!(check.status.code(), Some(1));
    let text = String::from_utf8_lossy(&check.stdout);
    assert!(
        text.contains("DAMAGED  tile_02") && text.contains("unreadable chunk"),
        "{text}"
    );
    assert!(
        text.contains("DAMAGED  tile_03") && text.contains("differ"),
        "{text}"
    );
    assert!(text.contains("ok       tile_00"), "{text}");
    refused(run(&[&"check", &dir.path().join("nothing")]), "nothing");
}

#[test]
fn stale_temporaries_of_dead_processes_are_removed() {
    let dir = tempfile::tempdir().unwrap();
    let store = store_s(dir.path());
    let pid = dead_pid();
    let out = dir.path().join("fused.tif");
    let spill = dir.path().join(format!("fused.tif.spill-{pid}-0"));
    let catalog_tmp = store.join(format!(".zarr.json.{pid}.tmp"));
    let group_tmp = store.join(format!("tile_00.tmp-{pid}"));
    std::fs::write(&spill, b"x").unwrap();
    std::fs::write(&catalog_tmp, b"{").unwrap();
    std::fs::create_dir(&group_tmp).unwrap();
    ok(run(&[&"fuse", &store, &"--out", &out, &"-q"]));
    assert!(!spill.exists());
    ok(run(&[&"ingest", &grid2x2(), &"--store", &store, &"-q"]));
    assert!(!catalog_tmp.exists() && !group_tmp.exists());
}

#[test]
fn poses_implying_a_runaway_mosaic_are_refused_early() {
    let dir = tempfile::tempdir().unwrap();
    let store = store_s(dir.path());
    let shift = |t: f64| -> Value {
        serde_json::json!([
            [1.0, 0.0, 0.0, t],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0]
        ])
    };
    let rot90 = serde_json::json!([
        [0.0, -1.0, 0.0, 0.0],
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, 1.0]
    ]);
    for (what, m) in [
        ("1e6 m", shift(1e6)),
        ("1e9 m", shift(1e9)),
        ("90 degrees", rot90),
    ] {
        let poses = dir.path().join("poses.json");
        let entries: Vec<Value> = (0..4)
            .map(|k| {
                let m = if k == 3 { m.clone() } else { shift(0.0) };
                serde_json::json!({"id": format!("tile_0{k}"), "matrix_world": m})
            })
            .collect();
        std::fs::write(&poses, serde_json::json!({"crs": "EPSG:32617", "poses": entries, "edges": [], "graph": "full", "gauge": "mean"}).to_string()).unwrap();
        let out = dir.path().join("f.tif");
        let started = std::time::Instant::now();
        let err = refused(
            run(&[&"fuse", &store, &"--poses", &poses, &"--out", &out]),
            "tile_03",
        );
        assert!(err.contains("mosaic would be"), "{what}: {err}");
        assert!(
            started.elapsed().as_secs() < 10,
            "{what}: not refused early"
        );
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with("f.tif"))
            .collect();
        assert!(left.is_empty(), "{what}: {left:?}");
    }
}

#[test]
fn a_read_only_store_is_refused_with_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let store = store_s(dir.path());
    let extra = dir.path().join("extra.tif");
    std::fs::copy(grid2x2().join("tile_01.tif"), &extra).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    for e in walk(&store) {
        std::fs::set_permissions(
            &e,
            std::fs::Permissions::from_mode(if e.is_dir() { 0o555 } else { 0o444 }),
        )
        .unwrap();
    }
    std::fs::set_permissions(&extra, std::fs::Permissions::from_mode(0o444)).unwrap();
    // As root, permissions do not stop writes: run as nobody.
    let as_root = unsafe_is_root();
    let mut cmd = if as_root {
        let mut c = Command::new("setpriv");
        c.args(["--reuid=65534", "--regid=65534", "--clear-groups"])
            .arg(env!("CARGO_BIN_EXE_dsmstream"));
        c
    } else {
        bin()
    };
    let out = cmd
        .arg("ingest")
        .arg(&extra)
        .arg("--store")
        .arg(&store)
        .output()
        .unwrap();
    refused(out, "read-only");
    assert_eq!(catalog_ids(&store).len(), 4);
}

fn unsafe_is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .map(|s| {
            s.lines()
                .any(|l| l.starts_with("Uid:") && l.split_whitespace().nth(1) == Some("0"))
        })
        .unwrap_or(false)
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = vec![dir.to_path_buf()];
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}
