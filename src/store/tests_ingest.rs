//! Ingest decisions: a rerun skips, `--force` and a changed source replace,
//! bad inputs and unusable store paths are refused before anything is written.

use super::ingest::DsmAction;
use super::tests_support::{options, run, same, snapshot, surface, utm, Inputs};
use super::{Store, StoreGrid};
use crate::cache::ChunkCache;
use crate::geo::Crs;
use crate::grid::Grid;

#[test]
fn store_rerun_skips_force_replaces_changed_source_replaces() {
    let mut inputs = Inputs::new();
    let a = inputs.add("a.tif", 30, 30, utm(26917), surface(30, 30, 4));
    let store_dir = tempfile::tempdir().unwrap();
    let store_path = store_dir.path().join("c.zarr");
    let mut opts = options(16);
    assert_eq!(
        run(&inputs, std::slice::from_ref(&a), &store_path, &opts).unwrap(),
        [DsmAction::Ingested]
    );
    assert_eq!(
        run(&inputs, std::slice::from_ref(&a), &store_path, &opts).unwrap(),
        [DsmAction::Skipped]
    );
    opts.force = true;
    assert_eq!(
        run(&inputs, std::slice::from_ref(&a), &store_path, &opts).unwrap(),
        [DsmAction::Replaced]
    );
    opts.force = false;
    // Change the source: different content and size.
    std::fs::write(&a, b"changed bytes").unwrap();
    let new_data = surface(30, 30, 9);
    inputs.rasters.get_mut(&a).unwrap().data = new_data.clone();
    assert_eq!(
        run(&inputs, std::slice::from_ref(&a), &store_path, &opts).unwrap(),
        [DsmAction::Replaced]
    );
    let store = Store::open(&store_path).unwrap();
    assert_eq!(store.dsms().len(), 1);
    let cache = ChunkCache::new(1 << 20);
    let mut grid = StoreGrid::new(&store, &cache, 0, 0).unwrap();
    assert!(same(grid.get(5, 7), new_data[7 * 30 + 5]));
    let names: Vec<String> = std::fs::read_dir(&store_path)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names
            .iter()
            .all(|n| !n.contains(".tmp-") && !n.contains(".old-")),
        "{names:?}"
    );
}

#[test]
fn store_refuses_bad_inputs_before_writing() {
    let mut inputs = Inputs::new();
    let good = inputs.add("good.tif", 30, 30, utm(26917), surface(30, 30, 5));
    let store_dir = tempfile::tempdir().unwrap();
    let store_path = store_dir.path().join("c.zarr");
    run(
        &inputs,
        std::slice::from_ref(&good),
        &store_path,
        &options(16),
    )
    .unwrap();
    let before = snapshot(&store_path);

    let geo = inputs.add(
        "geo.tif",
        30,
        30,
        Crs {
            epsg: Some(4230),
            is_geographic: true,
            ..Default::default()
        },
        surface(30, 30, 6),
    );
    // NAD83(CSRS) / UTM 17N: a datum dsmstream does not take as NAD83
    let other = inputs.add("other.tif", 30, 30, utm(2958), surface(30, 30, 7));
    let fresh = inputs.add("fresh.tif", 30, 30, utm(26917), surface(30, 30, 8));
    let empty = inputs.add("empty.tif", 0, 30, utm(26917), vec![]);
    let cases = [
        (
            geo,
            "geographic CRS EPSG:4230 (degrees) is not a metric frame",
        ),
        (
            other,
            "CRS EPSG:2958 differs from the collection's CRS EPSG:26917",
        ),
        (empty, "empty raster"),
    ];
    for (bad, message) in cases {
        // The good new file comes first: nothing may be written for it either.
        let err = run(
            &inputs,
            &[fresh.clone(), bad.clone()],
            &store_path,
            &options(16),
        )
        .unwrap_err();
        assert!(err.is_bad_input(), "{err}");
        let text = err.to_string();
        assert!(
            text.contains(message) && text.contains(&bad.display().to_string()),
            "{text}"
        );
        assert_eq!(
            snapshot(&store_path),
            before,
            "store changed after refusing {}",
            bad.display()
        );
    }

    // All no-data: found during its pass; its temporary is removed, the catalog untouched.
    let nodata = inputs.add("nodata.tif", 30, 30, utm(26917), vec![f32::NAN; 900]);
    let err = run(&inputs, &[nodata], &store_path, &options(16)).unwrap_err();
    assert!(err.to_string().contains("no valid pixels"), "{err}");
    assert_eq!(snapshot(&store_path), before);
}

#[test]
fn store_refuses_unusable_store_paths() {
    let mut inputs = Inputs::new();
    let good = inputs.add("good.tif", 20, 20, utm(26917), surface(20, 20, 1));
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("plain_file");
    std::fs::write(&file, b"x").unwrap();
    let err = run(
        &inputs,
        std::slice::from_ref(&good),
        &file.join("c.zarr"),
        &options(16),
    )
    .unwrap_err();
    assert!(
        err.is_bad_input() && err.to_string().contains("plain_file"),
        "{err}"
    );
    let not_store = dir.path().join("full");
    std::fs::create_dir(&not_store).unwrap();
    std::fs::write(not_store.join("data.bin"), b"x").unwrap();
    let err = run(&inputs, &[good], &not_store, &options(16)).unwrap_err();
    assert!(err.to_string().contains("not a dsmstream store"), "{err}");
}

#[test]
fn a_refused_input_leaves_no_store_at_a_fresh_path() {
    let mut inputs = Inputs::new();
    let nodata = inputs.add("nodata.tif", 30, 30, utm(26917), vec![f32::NAN; 900]);
    let dir = tempfile::tempdir().unwrap();
    for fresh in [
        dir.path().join("new.zarr"),
        dir.path().join("empty_dir.zarr"),
    ] {
        let existed = fresh.ends_with("empty_dir.zarr");
        if existed {
            std::fs::create_dir(&fresh).unwrap();
        }
        let err = run(&inputs, std::slice::from_ref(&nodata), &fresh, &options(16)).unwrap_err();
        assert!(err.to_string().contains("no valid pixels"), "{err}");
        if existed {
            assert_eq!(
                std::fs::read_dir(&fresh).unwrap().count(),
                0,
                "left files behind"
            );
        } else {
            assert!(!fresh.exists(), "{} left behind", fresh.display());
        }
    }
}
