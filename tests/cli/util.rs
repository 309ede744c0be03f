//! Helpers shared by every integration test module: the built binaries, the
//! repository's fixtures, and a checked `ingest`.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The built `dsmstream` binary, ready for arguments.
pub fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dsmstream"))
}

/// The built `dsmgen` binary, ready for arguments.
pub fn dsmgen() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dsmgen"))
}

/// The repository's `fixtures/` folder.
pub fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

/// Process output bytes as text (lossy).
pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// `out` itself, after asserting the process succeeded.
pub fn ok(out: Output) -> Output {
    assert_ok(&out);
    out
}

/// Asserts the process succeeded (exit code, stdout and stderr in the
/// failure message).
/// A refusal as the project makes them: exit 2, one line on stderr naming
/// `file` and saying `why`.
pub fn assert_refusal(out: &Output, file: &str, why: &str) {
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains(file) && err.contains(why), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
}

pub fn assert_ok(out: &Output) {
    assert!(
        out.status.success(),
        "exit {:?}\nstdout: {}\nstderr: {}",
        out.status.code(),
        text(&out.stdout),
        text(&out.stderr)
    );
}

/// `dsmstream ingest <inputs> --store <store> -q`, asserted to succeed.
pub fn ingest(inputs: &[PathBuf], store: &Path) {
    ok(bin()
        .arg("ingest")
        .args(inputs)
        .arg("--store")
        .arg(store)
        .arg("-q")
        .output()
        .unwrap());
}

/// `dsmstream pair <store> <reference> <moving> --json` at the defaults: exit
/// code and document (a panic naming stderr when there is no JSON).
pub fn pair_json(store: &Path, reference: &str, moving: &str) -> (Option<i32>, serde_json::Value) {
    let out = bin()
        .arg("pair")
        .arg(store)
        .args([reference, moving, "--json"])
        .output()
        .unwrap();
    let doc = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|_| panic!("no JSON: {}", text(&out.stderr)));
    (out.status.code(), doc)
}

/// The shift at the fit's centre and its sigma, per axis, from `pair --json`
/// (an axis without a sigma, held, as infinity).
pub fn shift_and_sigma(doc: &serde_json::Value) -> ([f64; 3], [f64; 3]) {
    let at = |v: &serde_json::Value, k: usize, none: f64| v[k].as_f64().unwrap_or(none);
    (
        [0, 1, 2].map(|k| at(&doc["shift_m"], k, f64::NAN)),
        [0, 1, 2].map(|k| at(&doc["sigma"]["shift_m"], k, f64::INFINITY)),
    )
}

/// `dsmgen grid --points <points> <args> --out <out>`, asserted to succeed.
pub fn dsmgen_grid(points: &Path, args: &[&str], out: &Path) {
    ok(dsmgen()
        .arg("grid")
        .arg("--points")
        .arg(points)
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap());
}

/// `dsmgen tiles <args> --out <out>`: a generated tile set with its truth.json.
pub fn dsmgen_tiles(args: &[&str], out: &Path) {
    let gen = dsmgen()
        .arg("tiles")
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(
        gen.status.success(),
        "dsmgen tiles {args:?}: {}",
        text(&gen.stderr)
    );
}

/// `dsmgen tiles --layout grid` of `rows` x `rows` tiles of `size` px with
/// 30 % overlaps, into `out`.
pub fn grid_tiles(out: &Path, rows: &str, size: &str, seed: &str, render: &str) {
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
    dsmgen_tiles(&layout, out);
}

/// `dsmstream align <store> --out <dir>/p.json -q` at the defaults, then
/// `dsmgen score --truth <truth> --poses p.json --json`: its document.
pub fn align_and_score(store: &Path, truth: &Path) -> serde_json::Value {
    let poses = store.with_file_name("p.json");
    let run = bin()
        .arg("align")
        .arg(store)
        .arg("--out")
        .arg(&poses)
        .arg("-q")
        .output()
        .unwrap();
    assert_ok(&run);
    let score = dsmgen()
        .arg("score")
        .arg("--truth")
        .arg(truth)
        .arg("--poses")
        .arg(&poses)
        .arg("--json")
        .output()
        .unwrap();
    assert_ok(&score);
    serde_json::from_slice(&score.stdout).unwrap()
}

/// `dsmstream` with `args`, its output.
pub fn run(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Output {
    let mut c = bin();
    for a in args {
        c.arg(a);
    }
    c.output().unwrap()
}

/// The chain4 fixture ingested into `dir/c.zarr`.
pub fn chain4_store(dir: &Path) -> PathBuf {
    let store = dir.join("c.zarr");
    ingest(&[fixtures().join("synth/chain4")], &store);
    store
}

/// The error of `pair --json`'s shift at its fit's centre against a dsmgen
/// `truth.json` (estimate minus truth, metres, x y z): the true transform is
/// M_ref^-1 M_moving, and the shift at the centre c is c - T^-1 c.
pub fn shift_error(
    truth_json: &Path,
    reference: &str,
    moving: &str,
    pair: &serde_json::Value,
) -> [f64; 3] {
    use nalgebra::{Matrix4, Vector4};
    let truth: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(truth_json).unwrap()).unwrap();
    let m = |id: &str| {
        let tile = truth["tiles"]
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["id"] == id);
        let rows = &tile.unwrap()["matrix_world"];
        Matrix4::from_fn(|r, c| rows[r][c].as_f64().unwrap())
    };
    let t_true = m(reference).try_inverse().unwrap() * m(moving);
    let c = |k: usize| pair["centre_m"][k].as_f64().unwrap();
    let centre = Vector4::new(c(0), c(1), c(2), 1.0);
    let true_shift = centre - t_true.try_inverse().unwrap() * centre;
    [0, 1, 2].map(|k| pair["shift_m"][k].as_f64().unwrap() - true_shift[k])
}
