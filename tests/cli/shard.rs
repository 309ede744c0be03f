//! Integration tests of sharded `align`: three `--shard K/3` processes run at
//! once, then `--merge`, give the poses of a single run to 1e-9; the merge
//! names a missing or incomplete shard and refuses a shard still running; a
//! shard re-run resumes its journal; with stderr not a terminal, `align`,
//! `eval`, `fuse` and `ingest` print plain progress lines at the interval asked for.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use dsmstream::align::Shard;
use dsmstream::journal::OutputLock;
use dsmstream::poses::PosesFile;

use crate::util::{assert_ok, bin, dsmgen_tiles, ingest, text};

/// Flags of every run: the shard journals' settings must match the merge's.
const FLAGS: &[&str] = &["--threads", "1", "--cache-mb", "64"];

fn align(store: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut cmd = bin();
    cmd.arg("align")
        .arg(store)
        .arg("--out")
        .arg(out)
        .args(FLAGS)
        .args(extra);
    cmd
}

/// A 3 x 3 grid store (20 overlapping pairs) and a single run's poses.
struct Collection {
    dir: PathBuf,
    store: PathBuf,
    single: PosesFile,
}

fn collection() -> &'static Collection {
    static C: OnceLock<Collection> = OnceLock::new();
    C.get_or_init(|| {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("cli_shard");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let tiles = dir.join("tiles");
        dsmgen_tiles(
            &[
                "--layout",
                "grid",
                "--rows",
                "3",
                "--cols",
                "3",
                "--size",
                "128",
                "--overlap",
                "0.4",
                "--seed",
                "3",
            ],
            &tiles,
        );
        let store = dir.join("grid.zarr");
        ingest(&[tiles], &store);
        let out = dir.join("single.json");
        assert_ok(&align(&store, &out, &["-q"]).output().unwrap());
        let single = PosesFile::read(&out).unwrap();
        Collection { dir, store, single }
    })
}

/// A fresh folder for one test's outputs.
fn folder(name: &str) -> PathBuf {
    let dir = collection().dir.join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn failed(out: &Output) -> String {
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    text(&out.stderr)
}

fn largest_difference(a: &PosesFile, b: &PosesFile) -> f64 {
    assert_eq!(a.poses.len(), b.poses.len());
    let mut worst = 0.0f64;
    for (pa, pb) in a.poses.iter().zip(&b.poses) {
        assert_eq!(pa.id, pb.id);
        for r in 0..4 {
            for c in 0..4 {
                worst = worst.max((pa.matrix_world[(r, c)] - pb.matrix_world[(r, c)]).abs());
            }
        }
    }
    worst
}

#[test]
fn three_concurrent_shards_and_a_merge_equal_a_single_run() {
    let c = collection();
    let out = folder("three").join("poses.json");
    let children: Vec<_> = (0..3)
        .map(|k| {
            align(&c.store, &out, &["--shard", &format!("{k}/3")])
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    let mut shard_pairs = 0;
    for child in children {
        let done = child.wait_with_output().unwrap();
        assert_ok(&done);
        let line = text(&done.stdout);
        assert!(line.contains("of 20 planned pairs"), "{line}");
        shard_pairs += line
            .split_whitespace()
            .nth(2)
            .and_then(|n| n.parse::<usize>().ok())
            .unwrap();
    }
    assert_eq!(shard_pairs, 20, "the shards share the plan out exactly");
    assert!(!out.exists(), "a shard writes no poses");
    let merged = align(&c.store, &out, &["--merge", "-q"]).output().unwrap();
    assert_ok(&merged);
    let merged = PosesFile::read(&out).unwrap();
    let worst = largest_difference(&merged, &c.single);
    assert!(
        worst <= 1e-9,
        "merged poses differ from a single run by {worst}"
    );
    assert_eq!(merged.edges.len(), c.single.edges.len());
}

#[test]
fn the_merge_names_missing_incomplete_and_running_shards() {
    let c = collection();
    let out = folder("missing").join("poses.json");
    let none = failed(&align(&c.store, &out, &["--merge"]).output().unwrap());
    assert!(none.contains("no shard journal"), "{none}");
    for k in [0, 2] {
        assert_ok(
            &align(&c.store, &out, &["--shard", &format!("{k}/3"), "-q"])
                .output()
                .unwrap(),
        );
    }
    let missing = failed(&align(&c.store, &out, &["--merge"]).output().unwrap());
    assert!(missing.contains("shard 1/3 is missing"), "{missing}");
    // Shard 2's journal cut to its header: the merge says which pairs it lacks.
    let journal2 = Shard { index: 2, count: 3 }.journal_path(&out);
    let full = std::fs::read_to_string(&journal2).unwrap();
    std::fs::write(&journal2, full.lines().next().unwrap().to_string() + "\n").unwrap();
    assert_ok(
        &align(&c.store, &out, &["--shard", "1/3", "-q"])
            .output()
            .unwrap(),
    );
    let cut = failed(&align(&c.store, &out, &["--merge"]).output().unwrap());
    assert!(cut.contains("shard 2/3 journaled 0 of its"), "{cut}");
    assert!(cut.contains("rerun --shard 2/3"), "{cut}");
    // The re-run resumes: it registers only what its journal lacks.
    let rerun = align(&c.store, &out, &["--shard", "2/3"]).output().unwrap();
    assert_ok(&rerun);
    assert!(
        text(&rerun.stdout).contains("(0 from its journal)"),
        "{}",
        text(&rerun.stdout)
    );
    let again = align(&c.store, &out, &["--shard", "2/3"]).output().unwrap();
    assert_ok(&again);
    let stdout = text(&again.stdout);
    assert!(
        stdout.contains("pairs (") && !stdout.contains("(0 from its journal)"),
        "{stdout}"
    );
    // A shard that is still running (its lock held) is neither run twice nor merged.
    let held = OutputLock::acquire(&Shard { index: 1, count: 3 }.journal_path(&out)).unwrap();
    let twice = failed(&align(&c.store, &out, &["--shard", "1/3"]).output().unwrap());
    assert!(twice.contains("another dsmstream align"), "{twice}");
    let running = failed(&align(&c.store, &out, &["--merge"]).output().unwrap());
    assert!(running.contains("shard 1/3 is still running"), "{running}");
    drop(held);
    // Other settings: refused by the merge, naming the journal.
    let other = failed(
        &align(&c.store, &out, &["--merge", "--min-overlap", "0.2"])
            .output()
            .unwrap(),
    );
    assert!(
        other.contains("other settings") && other.contains("shard-0-of-3"),
        "{other}"
    );
    assert_ok(&align(&c.store, &out, &["--merge", "-q"]).output().unwrap());
    let merged = PosesFile::read(&out).unwrap();
    assert!(largest_difference(&merged, &c.single) <= 1e-9);
}

#[test]
fn bad_shard_flags_are_refused_at_parse_time() {
    let c = collection();
    let out = folder("flags").join("poses.json");
    for bad in [
        &["--shard", "3/3"][..],
        &["--shard", "x"],
        &["--shard", "0/2", "--merge"],
        &["--merge", "--resume"],
    ] {
        let o = align(&c.store, &out, bad).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{bad:?}: {}", text(&o.stderr));
    }
}

/// The `progress:` lines a command wrote to `stderr_file`.
fn progress_lines(stderr_file: &Path) -> Vec<String> {
    std::fs::read_to_string(stderr_file)
        .unwrap()
        .lines()
        .filter(|l| l.starts_with("progress: "))
        .map(str::to_string)
        .collect()
}

#[test]
fn without_a_terminal_long_commands_print_plain_progress_lines() {
    let c = collection();
    let dir = folder("progress");
    let log = dir.join("stderr.txt");
    let run = |args: &[&str], quiet: bool| {
        let mut cmd = bin();
        cmd.args(args).env("DSMSTREAM_PROGRESS_SECS", "0.02");
        if quiet {
            cmd.arg("-q");
        }
        let status = cmd
            .stderr(std::fs::File::create(&log).unwrap())
            .stdout(std::process::Stdio::null())
            .status()
            .unwrap();
        assert!(
            status.success(),
            "{args:?}: {}",
            std::fs::read_to_string(&log).unwrap()
        );
        progress_lines(&log)
    };
    let store = c.store.to_str().unwrap();
    let out = dir.join("poses.json");
    let out = out.to_str().unwrap();
    let lines = run(&["align", store, "--out", out, "--threads", "1"], false);
    assert!(lines.len() >= 2, "{lines:?}");
    let mut with_total = 0;
    for line in &lines {
        assert!(!line.contains('\u{1b}'), "ANSI code in {line:?}");
        let rest = line.strip_prefix("progress: ").unwrap();
        let (count, rest) = rest.split_once(' ').unwrap();
        match count.split_once('/') {
            // before the first pair ends, the total is not yet reported
            None => assert!(count == "0" && rest.starts_with("pairs, "), "{line}"),
            Some((done, total)) => {
                with_total += 1;
                assert!(
                    done.parse::<u64>().unwrap() <= 20 && total == "20",
                    "{line}"
                );
                assert!(rest.starts_with("pairs ("), "{line}");
                assert!(
                    rest.contains("/s, eta ") && rest.contains(", cache hit "),
                    "{line}"
                );
                assert!(rest.ends_with('%'), "{line}");
            }
        }
        assert!(rest.contains(", elapsed "), "{line}");
    }
    assert!(with_total >= 1, "{lines:?}");
    assert!(
        run(&["align", store, "--out", out, "--threads", "1"], true).is_empty(),
        "-q silences them"
    );
    let eval = run(&["eval", store, "--poses", out, "--threads", "1"], false);
    assert!(eval.iter().any(|l| l.contains(" pairs (")), "{eval:?}");
    let fused = dir.join("fused.tif");
    let fuse = run(
        &[
            "fuse",
            store,
            "--poses",
            out,
            "--out",
            fused.to_str().unwrap(),
        ],
        false,
    );
    assert!(fuse.iter().any(|l| l.contains(" tiles (")), "{fuse:?}");
    let tiles = c.dir.join("tiles");
    let again = dir.join("again.zarr");
    let ingest = run(
        &[
            "ingest",
            tiles.to_str().unwrap(),
            "--store",
            again.to_str().unwrap(),
        ],
        false,
    );
    assert!(
        ingest.iter().any(|l| l.contains("9/9 DSMs (")),
        "{ingest:?}"
    );
}
