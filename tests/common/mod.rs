//! Helpers for integration test files not yet moved into the single test
//! binary (tests/cli/). tests/cli/util.rs holds the same helpers and more;
//! a file moved into tests/cli/ uses `crate::util` instead of this module.

use std::path::Path;
use std::process::Command;

/// `dsmgen tiles <args> --out <out>`: a generated tile set with its truth.json.
#[allow(dead_code)]
pub fn dsmgen_tiles(args: &[&str], out: &Path) {
    let gen = Command::new(env!("CARGO_BIN_EXE_dsmgen"))
        .arg("tiles")
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(
        gen.status.success(),
        "dsmgen tiles {args:?}: {}",
        String::from_utf8_lossy(&gen.stderr)
    );
}
