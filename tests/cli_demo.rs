//! `dsmstream demo`, the README's first command: both bundled collections run
//! end to end from the repository root, and on the real-terrain cut the motion
//! averaging result beats the spanning tree on the fused surface.

use std::process::Command;

/// (pairs rmse_tau, fused-truth rmse_tau) of one row of a side-by-side table.
fn row(table: &str, name: &str) -> (f64, f64) {
    let line = table
        .lines()
        .find(|l| l.split_whitespace().next() == Some(name))
        .unwrap_or_else(|| panic!("no row {name} in\n{table}"));
    let v: Vec<f64> = line
        .split_whitespace()
        .skip(1)
        .map(|x| x.parse().unwrap())
        .collect();
    (v[0], v[2])
}

#[test]
fn demo_runs_both_collections_and_full_beats_mst_on_real_terrain() {
    let work = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_dsmstream"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["demo", "--work"])
        .arg(work.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}\n{stdout}",
        String::from_utf8_lossy(&out.stderr)
    );
    let tables: Vec<&str> = stdout.split("side by side").skip(1).collect();
    assert_eq!(tables.len(), 2, "{stdout}");
    for table in &tables {
        let (none, full) = (row(table, "none"), row(table, "full"));
        assert!(full.0 < none.0 && full.1 < none.1, "{table}");
    }
    // real terrain (measured 2026-12-01): fused-truth full 0.032 m, mst 0.073 m, none 1.899 m
    let real = tables[1];
    let (full, mst, none) = (row(real, "full"), row(real, "mst"), row(real, "none"));
    assert!(full.1 < mst.1 && full.1 < 0.15 && none.1 > 1.0, "{real}");
    assert!(work.path().join("ttp2015/fused_full.tif").exists());
    assert!(work.path().join("synth/plots/scene_graph.png").exists());
}
