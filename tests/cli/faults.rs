//! Fault injection (issue 15): `ingest` and `fuse` killed with SIGKILL at
//! seeded random moments, several times in a row, then run to the end: the
//! result equals an uninterrupted run and nothing is left behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dsmstream"))
}

fn grid2x2() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/synth/grid2x2")
}

/// A small seeded generator (xorshift64*), so every run kills at the same moments.
struct Rng(u64);

impl Rng {
    fn below(&mut self, n: u64) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) % n.max(1)
    }
}

fn run_ok(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Duration {
    let started = Instant::now();
    let mut c = bin();
    for a in args {
        c.arg(a);
    }
    let out = c.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    started.elapsed()
}

/// Start the command and SIGKILL it after `after` (if still running).
fn run_killed(args: &[&dyn AsRef<std::ffi::OsStr>], after: Duration) {
    let mut c = bin();
    for a in args {
        c.arg(a);
    }
    let mut child = c
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(after);
    let _ = child.kill();
    let _ = child.wait();
}

/// Every file under `dir` with its bytes, paths relative to `dir`.
fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    fn walk(base: &Path, dir: &Path, out: &mut Vec<(String, Vec<u8>)>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(base, &p, out);
            } else {
                let rel = p.strip_prefix(base).unwrap().display().to_string();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    let mut out = Vec::new();
    walk(dir, dir, &mut out);
    out.sort();
    out
}

/// A group zarr.json without the height mean/std (summed in parallel: the
/// last bits may differ between runs), which are compared with a tolerance.
fn without_moments(bytes: &[u8]) -> (Value, [f64; 2]) {
    let mut v: Value = serde_json::from_slice(bytes).unwrap();
    let stats = &mut v["attributes"]["dsmstream"]["height_stats"];
    if stats.is_null() {
        return (v, [0.0; 2]);
    }
    let m = [
        stats["mean"].as_f64().unwrap(),
        stats["std"].as_f64().unwrap(),
    ];
    stats["mean"] = Value::Null;
    stats["std"] = Value::Null;
    (v, m)
}

fn same_store(a: &Path, b: &Path) {
    let (fa, fb) = (files(a), files(b));
    let names = |f: &[(String, Vec<u8>)]| f.iter().map(|x| x.0.clone()).collect::<Vec<_>>();
    assert_eq!(names(&fa), names(&fb));
    for ((name, x), (_, y)) in fa.iter().zip(&fb) {
        if name.ends_with("zarr.json") {
            let ((vx, mx), (vy, my)) = (without_moments(x), without_moments(y));
            assert_eq!(vx, vy, "{name}");
            for k in 0..2 {
                assert!(
                    (mx[k] - my[k]).abs() <= 1e-9 * (1.0 + mx[k].abs()),
                    "{name}"
                );
            }
        } else {
            assert!(x == y, "{name} differs");
        }
    }
}

fn leftovers(dir: &Path) -> Vec<String> {
    files(dir)
        .into_iter()
        .map(|f| f.0)
        .filter(|n| n.contains(".tmp") || n.contains(".old-") || n.contains(".spill-"))
        .collect()
}

#[test]
fn ingest_killed_at_random_points_then_resumed_equals_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let reference = dir.path().join("ref.zarr");
    let args = |store: &Path| -> Vec<std::ffi::OsString> {
        let mut v: Vec<std::ffi::OsString> =
            vec!["ingest".into(), grid2x2().into(), "--store".into()];
        v.extend([
            store.as_os_str().to_owned(),
            "--chunk".into(),
            "16".into(),
            "-q".into(),
        ]);
        v
    };
    fn as_refs(v: &[std::ffi::OsString]) -> Vec<&dyn AsRef<std::ffi::OsStr>> {
        v.iter().map(|b| b as &dyn AsRef<std::ffi::OsStr>).collect()
    }
    let full = run_ok(&as_refs(&args(&reference)));
    let mut rng = Rng(0x5eed_1234);
    for trial in 0..3 {
        let store = dir.path().join(format!("t{trial}.zarr"));
        for _ in 0..4 {
            let after = Duration::from_micros(rng.below(full.as_micros() as u64 * 6 / 5));
            run_killed(&as_refs(&args(&store)), after);
        }
        run_ok(&as_refs(&args(&store)));
        same_store(&reference, &store);
        assert!(leftovers(&store).is_empty(), "{:?}", leftovers(&store));
    }
}

#[test]
fn fuse_killed_at_random_points_then_rerun_equals_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("s.zarr");
    run_ok(&[
        &"ingest",
        &grid2x2(),
        &"--store",
        &store,
        &"--chunk",
        &"64",
        &"-q",
    ]);
    let reference = dir.path().join("ref.tif");
    let full = run_ok(&[&"fuse", &store, &"--out", &reference, &"-q"]);
    let out_dir = dir.path().join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let out = out_dir.join("fused.tif");
    let mut rng = Rng(0xfa17_0001);
    for _ in 0..3 {
        for _ in 0..3 {
            let after = Duration::from_micros(rng.below(full.as_micros() as u64 * 6 / 5));
            run_killed(&[&"fuse", &store, &"--out", &out, &"-q", &"--force"], after);
        }
        run_ok(&[&"fuse", &store, &"--out", &out, &"-q", &"--force"]);
        assert!(std::fs::read(&out).unwrap() == std::fs::read(&reference).unwrap());
        assert!(leftovers(&out_dir).is_empty(), "{:?}", leftovers(&out_dir));
    }
}
