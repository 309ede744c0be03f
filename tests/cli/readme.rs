//! The README stays honest: its ```sh blocks are run in order, as one bash
//! script (`set -euo pipefail`), in a fresh folder holding a link to the
//! repository's fixtures, with the built `dsmstream` and `dsmgen` first on
//! PATH. A line marked `# readme-test: skip` (install, the demo, the test
//! suite itself) is left out; every other line must succeed.

use std::path::Path;
use std::process::Command;

use crate::util::{fixtures, text};

/// Marks a README line the test does not run (with the reason after it).
const SKIP_MARKER: &str = "# readme-test: skip";

/// The lines of every ```sh block of `markdown`, in order, without the
/// skipped ones.
fn shell_lines(markdown: &str) -> Vec<String> {
    let mut lines = Vec::new();
    let mut in_sh = false;
    for line in markdown.lines() {
        let fence = line.trim_start();
        if fence.starts_with("```") {
            in_sh = !in_sh && fence.trim_start_matches('`').trim() == "sh";
            continue;
        }
        if in_sh && !line.contains(SKIP_MARKER) && !line.trim().is_empty() {
            lines.push(line.to_string());
        }
    }
    lines
}

#[test]
fn shell_blocks_are_found_and_skips_honoured() {
    let md = "x\n```sh\na 1\nb # readme-test: skip\n```\n```text\nc\n```\n```sh\nd\n```\n";
    assert_eq!(shell_lines(md), ["a 1", "d"]);
}

#[test]
fn every_readme_example_runs_as_written() {
    let readme = Path::new(env!("CARGO_MANIFEST_DIR")).join("README.md");
    let lines = shell_lines(&std::fs::read_to_string(&readme).unwrap());
    assert!(lines.len() >= 20, "too few examples found: {lines:?}");
    let dir = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink(fixtures(), dir.path().join("fixtures")).unwrap();
    let bin_dir = Path::new(env!("CARGO_BIN_EXE_dsmstream")).parent().unwrap();
    let path = format!(
        "{}:{}",
        bin_dir.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let script = format!(
        "set -euo pipefail\n{}\n",
        lines
            .iter()
            .map(|l| format!("echo '+ {}' >&2\n{l}", l.replace('\'', "'\\''")))
            .collect::<Vec<_>>()
            .join("\n")
    );
    let out = Command::new("bash")
        .arg("-c")
        .arg(&script)
        .current_dir(dir.path())
        .env("PATH", path)
        .output()
        .unwrap();
    let err = text(&out.stderr);
    let last = err.lines().rfind(|l| l.starts_with("+ ")).unwrap_or("");
    assert!(
        out.status.success(),
        "README example failed (exit {:?}) at: {last}\nstderr:\n{err}\nstdout:\n{}",
        out.status.code(),
        text(&out.stdout)
    );
    assert!(dir.path().join("ttp_fused.tif").is_file());
}
