//! Integration tests of `align`'s journal and output (issue 15, issue 13):
//! a journal of another collection or with a non-rigid matrix is refused with
//! the journal and line named (exit 2); `--out` naming a directory is refused
//! before any pair is registered; a second `align` on the same output is
//! refused while the first runs; the `--graph mst` summary counts tree edges;
//! `--threads 1` keeps the work on one thread.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dsmstream"))
}

fn align(store: &Path, out: &Path, extra: &[&str]) -> Output {
    bin()
        .arg("align")
        .arg(store)
        .arg("--out")
        .arg(out)
        .args(["--threads", "1", "-q"])
        .args(extra)
        .output()
        .unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn journal_of(out: &Path) -> PathBuf {
    dsmstream::journal::Journal::path_for(out)
}

/// The store of fixtures/synth/grid2x2 (4 DSMs, 6 pairs) and the journal of
/// one run, made once for all tests of this file.
struct Reference {
    dir: PathBuf,
    store: PathBuf,
    journal: String,
    stdout: String,
}

fn reference() -> &'static Reference {
    static REFERENCE: OnceLock<Reference> = OnceLock::new();
    REFERENCE.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("spine_align_journal");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let store = dir.join("grid.zarr");
        let fixtures = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/synth/grid2x2");
        let ingest = bin()
            .arg("ingest")
            .arg(&fixtures)
            .arg("--store")
            .arg(&store)
            .arg("-q")
            .output()
            .unwrap();
        assert!(ingest.status.success(), "{}", stderr(&ingest));
        let out = dir.join("reference.json");
        let run = align(&store, &out, &["--graph", "mst"]);
        assert!(run.status.success(), "{}", stderr(&run));
        Reference {
            journal: std::fs::read_to_string(journal_of(&out)).unwrap(),
            stdout: String::from_utf8_lossy(&run.stdout).into_owned(),
            dir,
            store,
        }
    })
}

#[test]
fn mst_summary_counts_tree_edges_not_all_pairs() {
    let r = reference();
    // 4 DSMs: a spanning tree has 3 edges, the 2 x 2 grid has 6 registered pairs
    assert!(
        r.stdout
            .contains("aligned 4 DSMs: 3 tree edges of 6 registered pairs,"),
        "{}",
        r.stdout
    );
}

#[test]
fn resume_with_a_journal_of_another_collection_is_refused() {
    let r = reference();
    let out = r.dir.join("other.json");
    std::fs::write(journal_of(&out), r.journal.replace("tile_0", "elsewhere_0")).unwrap();
    let run = align(&r.store, &out, &["--graph", "mst", "--resume"]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{err}");
    let named = format!(
        "{}, line 2: no DSM 'elsewhere_0",
        journal_of(&out).display()
    );
    assert!(err.contains(&named), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out.exists());
}

#[test]
fn resume_with_a_non_rigid_journal_matrix_is_refused() {
    let r = reference();
    let out = r.dir.join("scaled.json");
    let mut lines: Vec<String> = r.journal.lines().map(String::from).collect();
    let k = lines
        .iter()
        .position(|l| l.contains("\"m_world\":[["))
        .expect("a registered pair");
    let mut record: serde_json::Value = serde_json::from_str(&lines[k]).unwrap();
    record["m_world"][0][0] = serde_json::json!(1.5); // a scale, not a rotation
    lines[k] = record.to_string();
    std::fs::write(journal_of(&out), lines.join("\n") + "\n").unwrap();
    let run = align(&r.store, &out, &["--graph", "mst", "--resume"]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{err}");
    let named = format!("{}, line {}:", journal_of(&out).display(), k + 1);
    assert!(err.contains(&named), "{err}");
    assert!(err.contains("not a rigid transform"), "{err}");
    assert!(!out.exists());
}

#[test]
fn out_naming_a_directory_is_refused_before_any_pair() {
    let r = reference();
    let out = r.dir.join("a_directory");
    std::fs::create_dir_all(&out).unwrap();
    let run = align(&r.store, &out, &[]);
    let err = stderr(&run);
    assert_eq!(run.status.code(), Some(2), "{err}");
    assert!(err.contains("is a directory"), "{err}");
    assert!(!journal_of(&out).exists(), "no pair was registered");
}

fn signal(pid: u32, name: &str) {
    let status = Command::new("kill")
        .arg(format!("-{name}"))
        .arg(pid.to_string())
        .status()
        .unwrap();
    assert!(status.success());
}

#[test]
fn a_second_align_on_the_same_output_is_refused_while_the_first_runs() {
    let r = reference();
    let out = r.dir.join("busy.json");
    let mut first = bin()
        .arg("align")
        .arg(&r.store)
        .arg("--out")
        .arg(&out)
        .args(["--threads", "1", "-q"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // The journal's header is written after the lock is taken.
    let deadline = Instant::now() + Duration::from_secs(300);
    while !std::fs::read_to_string(journal_of(&out)).is_ok_and(|t| t.contains('\n')) {
        assert!(first.try_wait().unwrap().is_none(), "the first run ended");
        assert!(Instant::now() < deadline, "no journal after 300 s");
        std::thread::sleep(Duration::from_millis(5));
    }
    signal(first.id(), "STOP"); // hold it mid-run, whatever the machine's speed
    let second = align(&r.store, &out, &[]);
    signal(first.id(), "CONT");
    let err = stderr(&second);
    assert_eq!(second.status.code(), Some(2), "{err}");
    assert!(err.contains("another dsmstream align is writing"), "{err}");
    assert!(first.wait().unwrap().success());
    assert!(dsmstream::poses::PosesFile::read(&out).is_ok());
    // once the first has ended, the output is free again
    let third = align(&r.store, &out, &["--resume"]);
    assert!(third.status.success(), "{}", stderr(&third));
}

/// CPU seconds of each thread of a running process, by thread id (Linux).
#[cfg(target_os = "linux")]
fn thread_cpu(pid: u32, seen: &mut std::collections::HashMap<String, f64>) {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return;
    };
    for task in tasks.flatten() {
        let Ok(stat) = std::fs::read_to_string(task.path().join("stat")) else {
            continue;
        };
        let Some(after) = stat.rfind(')').map(|k| &stat[k + 2..]) else {
            continue;
        };
        let fields: Vec<&str> = after.split_whitespace().collect();
        // utime and stime: fields 14 and 15 of stat, 12 and 13 after the name
        let ticks: f64 = fields[11].parse::<f64>().unwrap() + fields[12].parse::<f64>().unwrap();
        let name = task.file_name().to_string_lossy().into_owned();
        seen.insert(name, ticks / 100.0);
    }
}

#[cfg(target_os = "linux")]
#[test]
fn one_thread_does_the_work_with_threads_1() {
    let r = reference();
    let out = r.dir.join("one_thread.json");
    let mut child = bin()
        .arg("align")
        .arg(&r.store)
        .arg("--out")
        .arg(&out)
        .args(["--threads", "1", "-q"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut seen = std::collections::HashMap::new();
    while child.try_wait().unwrap().is_none() {
        thread_cpu(child.id(), &mut seen);
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(child.wait().unwrap().success());
    let mut cpu: Vec<f64> = seen.values().copied().collect();
    cpu.sort_by(|a, b| b.total_cmp(a));
    let total: f64 = cpu.iter().sum();
    // All but the busiest thread together used under a tenth of the CPU time
    // (with rayon's global pool they shared the ICP work about evenly).
    assert!(
        total - cpu[0] <= 0.1 * total + 0.05,
        "CPU seconds per thread: {cpu:?}"
    );
}
