//! Small DSMs get chunks of their own size (issue 12, many DSMs on one
//! machine): a 64 px tile is stored as one 64 px chunk, and a store written
//! before that (one 512 px chunk, mostly padding) still opens and gives the
//! same pixels and figures.

use std::path::Path;

use serde_json::Value;

use crate::util::{dsmgen_tiles, ok, run, text};

/// The JSON file at `path`.
fn read_json(path: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

fn write_json(path: &Path, value: &Value) {
    std::fs::write(path, serde_json::to_vec_pretty(value).unwrap()).unwrap();
}

/// Rewrites level 0 of every DSM of an uncompressed store of 64 px DSMs as
/// the former layout did: one `side` px chunk, NaN beyond the raster.
fn to_former_layout(store: &Path, side: usize) {
    let catalog = read_json(&store.join("zarr.json"));
    let ids = catalog["attributes"]["dsmstream"]["dsms"]
        .as_array()
        .unwrap();
    for id in ids.iter().map(|v| v.as_str().unwrap()) {
        let group = store.join(id);
        let mut meta = read_json(&group.join("zarr.json"));
        let levels = &mut meta["attributes"]["dsmstream"]["levels"];
        assert_eq!(levels.as_array().unwrap().len(), 1, "{id}: one level");
        assert_eq!(levels[0]["chunk"], 64, "{id}: a chunk of its size");
        levels[0]["chunk"] = side.into();
        write_json(&group.join("zarr.json"), &meta);
        let mut array = read_json(&group.join("0/zarr.json"));
        array["chunk_grid"]["configuration"]["chunk_shape"] = serde_json::json!([side, side]);
        write_json(&group.join("0/zarr.json"), &array);
        let file = group.join("0/c/0/0");
        let raw = std::fs::read(&file).unwrap();
        assert_eq!(raw.len(), 64 * 64 * 4, "{id}: raw float32 chunk");
        let mut padded = f32::NAN.to_le_bytes().repeat(side * side);
        for row in 0..64 {
            padded[row * side * 4..(row * side + 64) * 4]
                .copy_from_slice(&raw[row * 64 * 4..(row + 1) * 64 * 4]);
        }
        std::fs::write(&file, padded).unwrap();
    }
}

#[test]
fn small_dsms_get_their_own_chunk_side_and_former_stores_still_read() {
    let tmp = tempfile::tempdir().unwrap();
    let tiles = tmp.path().join("tiles");
    dsmgen_tiles(
        &[
            "--layout", "grid", "--rows", "2", "--cols", "2", "--size", "64",
        ],
        &tiles,
    );
    let store = tmp.path().join("c.zarr");
    let args = ["--compression", "none", "-q"];
    ok(run(&[
        &"ingest", &tiles, &"--store", &store, &args[0], &args[1], &args[2],
    ]));
    let level0 = read_json(&store.join("tile_00/0/zarr.json"));
    assert_eq!(
        level0["chunk_grid"]["configuration"]["chunk_shape"],
        serde_json::json!([64, 64])
    );
    ok(run(&[&"check", &store]));
    let eval = |store: &Path| -> Value {
        let out = ok(run(&[&"eval", &store, &"--json", &"-q"]));
        let mut report: Value = serde_json::from_slice(&out.stdout).unwrap();
        report["seconds"] = Value::Null;
        report["store"] = Value::Null;
        report
    };
    let now = eval(&store);
    let former = tmp.path().join("former.zarr");
    std::fs::rename(&store, &former).unwrap();
    to_former_layout(&former, 512);
    let check = ok(run(&[&"check", &former]));
    assert!(
        text(&check.stdout).contains("all 4 DSMs ok"),
        "{}",
        text(&check.stdout)
    );
    assert_eq!(eval(&former), now, "the same figures from either layout");
}
