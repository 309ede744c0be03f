//! Integration tests of `align --resume`: a run killed with SIGKILL once its
//! edge journal holds a finished pair, or a journal cut to one record plus a
//! torn partial line, resumes to exactly the poses of an uninterrupted run; a
//! killed run leaves no poses file behind (the output is written atomically);
//! and journaled pairs are taken from the journal, not recomputed.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use dsmstream::poses::PosesFile;

use crate::util::{bin, dsmgen_tiles, fixtures};

/// Arguments shared by every run (the journal header must match on resume).
const ALIGN_ARGS: &[&str] = &["--threads", "1", "-q"];

fn align_cmd(store: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut cmd = bin();
    cmd.arg("align")
        .arg(store)
        .arg("--out")
        .arg(out)
        .args(ALIGN_ARGS)
        .args(extra);
    cmd
}

fn run_ok(mut cmd: Command) -> Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{:?}: {}",
        cmd,
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn journal_of(out: &Path) -> PathBuf {
    dsmstream::journal::Journal::path_for(out)
}

/// The store of fixtures/synth/grid2x2 (6 overlapping pairs) and the poses and
/// journal of one uninterrupted run, made once for all tests of this file.
struct Reference {
    dir: PathBuf,
    store: PathBuf,
    poses: PosesFile,
    journal: String,
}

fn reference() -> &'static Reference {
    static REFERENCE: OnceLock<Reference> = OnceLock::new();
    REFERENCE.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("cli_resume");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let store = dir.join("grid.zarr");
        let fixtures = fixtures().join("synth/grid2x2");
        let mut ingest = bin();
        ingest
            .arg("ingest")
            .arg(&fixtures)
            .arg("--store")
            .arg(&store);
        ingest.arg("-q");
        run_ok(ingest);
        let out = dir.join("reference.json");
        run_ok(align_cmd(&store, &out, &[]));
        let poses = PosesFile::read(&out).unwrap();
        assert_eq!(poses.poses.len(), 4);
        assert!(!poses.edges.is_empty());
        let journal = std::fs::read_to_string(journal_of(&out)).unwrap();
        Reference {
            dir,
            store,
            poses,
            journal,
        }
    })
}

/// Complete lines of a journal (header first).
fn complete_lines(text: &str) -> Vec<&str> {
    match text.rfind('\n') {
        Some(end) => text[..end].lines().collect(),
        None => Vec::new(),
    }
}

/// A generated 3 x 3 grid of 384 px tiles (20 pairs; several seconds of ICP
/// on one thread, so the journal's two-second flush lands mid-run), ingested,
/// with the poses of one uninterrupted run.
fn slow_collection(dir: &Path) -> (PathBuf, PosesFile, usize) {
    let tiles = dir.join("tiles");
    dsmgen_tiles(
        &[
            "--layout", "grid", "--rows", "3", "--cols", "3", "--size", "384", "--seed", "5",
        ],
        &tiles,
    );
    let store = dir.join("grid.zarr");
    let mut ingest = bin();
    ingest.arg("ingest").arg(&tiles).arg("--store").arg(&store);
    run_ok(ingest);
    let out = dir.join("uninterrupted.json");
    run_ok(align_cmd(&store, &out, &[]));
    let journal = std::fs::read_to_string(journal_of(&out)).unwrap();
    let pairs = complete_lines(&journal).len() - 1;
    (store, PosesFile::read(&out).unwrap(), pairs)
}

#[test]
fn align_killed_after_a_journaled_pair_resumes_to_the_same_poses() {
    let dir = tempfile::tempdir().unwrap();
    let (store, reference, pairs) = slow_collection(dir.path());
    let out = dir.path().join("killed.json");
    let journal = journal_of(&out);
    let mut child = align_cmd(&store, &out, &[])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(600);
    while complete_lines(&std::fs::read_to_string(&journal).unwrap_or_default()).len() < 2 {
        assert!(
            child.try_wait().unwrap().is_none(),
            "align ended before a pair was journaled"
        );
        assert!(Instant::now() < deadline, "no journaled pair after 600 s");
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let killed = complete_lines(&std::fs::read_to_string(&journal).unwrap()).len() - 1;
    eprintln!("killed with {killed} of {pairs} pairs journaled");
    assert!(killed < pairs, "the kill came before the last pair");
    assert!(
        !out.exists(),
        "a killed align left {} behind",
        out.display()
    );
    run_ok(align_cmd(&store, &out, &["--resume"]));
    assert_eq!(PosesFile::read(&out).unwrap(), reference);
    let text = std::fs::read_to_string(&journal).unwrap();
    assert_eq!(
        complete_lines(&text).len() - 1,
        pairs,
        "every pair journaled exactly once after the resume"
    );
}

#[test]
fn align_resumes_from_one_record_and_a_torn_line_to_the_same_poses() {
    let r = reference();
    let lines = complete_lines(&r.journal);
    assert!(lines.len() >= 3, "need a header and two records");
    let out = r.dir.join("torn.json");
    let second = lines[2];
    let torn = format!(
        "{}\n{}\n{}",
        lines[0],
        lines[1],
        &second[..second.len() / 2]
    );
    std::fs::write(journal_of(&out), torn).unwrap();
    run_ok(align_cmd(&r.store, &out, &["--resume"]));
    assert_eq!(PosesFile::read(&out).unwrap(), r.poses);
    // The torn line is gone; the resumed journal has every pair once.
    let text = std::fs::read_to_string(journal_of(&out)).unwrap();
    let resumed = complete_lines(&text);
    assert_eq!(resumed.len(), lines.len());
    assert_eq!(resumed[1], lines[1], "the journaled record is kept as is");
    for line in &resumed[1..] {
        serde_json::from_str::<dsmstream::journal::EdgeRecord>(line).unwrap();
    }
}

#[test]
fn resume_takes_journaled_pairs_from_the_journal() {
    let r = reference();
    let out = r.dir.join("marked.json");
    // Mark one journaled pair with an rmse no registration gives: if resume
    // recomputed the pair, the mark would not reach the output.
    let lines = complete_lines(&r.journal);
    let mut marked = String::new();
    let mut marked_pair = None;
    for (k, line) in lines.iter().enumerate() {
        if k >= 1 && marked_pair.is_none() {
            let mut rec: dsmstream::journal::EdgeRecord = serde_json::from_str(line).unwrap();
            if rec.m_world.is_some() {
                rec.rmse_m = 0.123_456_789;
                marked_pair = Some(rec.key());
                marked.push_str(&serde_json::to_string(&rec).unwrap());
                marked.push('\n');
                continue;
            }
        }
        marked.push_str(line);
        marked.push('\n');
    }
    let (i, j) = marked_pair.expect("a registered pair in the journal");
    std::fs::write(journal_of(&out), marked).unwrap();
    run_ok(align_cmd(&r.store, &out, &["--resume"]));
    let poses = PosesFile::read(&out).unwrap();
    let edge = poses
        .edges
        .iter()
        .find(|e| e.i == i && e.j == j)
        .expect("the marked pair is an edge");
    assert_eq!(edge.rmse_m, 0.123_456_789);
    let reference_edge = r.poses.edges.iter().find(|e| e.i == i && e.j == j);
    assert_ne!(reference_edge.unwrap().rmse_m, 0.123_456_789);
}
