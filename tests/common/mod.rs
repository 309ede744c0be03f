//! Helpers shared by the integration test binaries.

use std::path::Path;
use std::process::Command;

/// `dsmgen tiles <args> --out <out>`: a generated tile set with its truth.json.
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
