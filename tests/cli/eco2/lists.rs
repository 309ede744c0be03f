//! `ingest @list.txt`: paths relative to the list's own folder, one-line
//! errors for a missing list and a missing listed file.

use crate::util::{fixtures, ok, run, text};

#[test]
fn an_input_list_names_paths_relative_to_its_own_folder() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let lists = dir.path().join("lists");
    std::fs::create_dir(&data).unwrap();
    std::fs::create_dir(&lists).unwrap();
    let chain4 = fixtures().join("synth/chain4");
    for name in ["tile_00.tif", "tile_01.tif", "tile_03.tif"] {
        std::fs::copy(chain4.join(name), data.join(name)).unwrap();
    }
    let list = lists.join("inputs.txt");
    let abs = data.join("tile_03.tif");
    let lines = format!(
        "# relative to this file\n../data/tile_00.tif\n\n   ../data/tile_01.tif\n{}\n",
        abs.display()
    );
    std::fs::write(&list, lines).unwrap();
    let store = dir.path().join("s.zarr");
    // run from elsewhere: the paths do not depend on the current directory
    let mut cmd = crate::util::bin();
    cmd.current_dir(std::env::temp_dir())
        .arg("ingest")
        .arg(format!("@{}", list.display()))
        .arg("--store")
        .arg(&store);
    let out = ok(cmd.output().unwrap());
    assert!(
        text(&out.stdout).contains("3 ingested"),
        "{}",
        text(&out.stdout)
    );
    let missing = format!("@{}", lists.join("none.txt").display());
    let out = run(&[&"ingest", &missing, &"--store", &store]);
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("none.txt") && err.trim_end().lines().count() == 1,
        "{err}"
    );
    // a listed file that does not exist is named
    std::fs::write(&list, "../data/tile_09.tif\n").unwrap();
    let out = run(&[
        &"ingest",
        &format!("@{}", list.display()),
        &"--store",
        &store,
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("tile_09.tif"),
        "{}",
        text(&out.stderr)
    );
}
