//! Chunks read back: empty chunks recorded at ingest read as no-data, a
//! missing or undecodable chunk file reads as NaN and is reported as an error
//! naming the file.

use super::tests_support::{options, run, surface, utm, Inputs};
use super::{Store, StoreGrid};
use crate::cache::ChunkCache;
use crate::grid::Grid;

#[test]
fn store_grid_records_read_errors() {
    let mut inputs = Inputs::new();
    let a = inputs.add("a.tif", 40, 40, utm(26917), surface(40, 40, 1));
    let store_dir = tempfile::tempdir().unwrap();
    let store_path = store_dir.path().join("c.zarr");
    run(&inputs, &[a], &store_path, &options(16)).unwrap();
    std::fs::write(store_path.join("a/0/c/1/1"), b"not zstd").unwrap();
    let store = Store::open(&store_path).unwrap();
    let cache = ChunkCache::new(1 << 20);
    let mut grid = StoreGrid::new(&store, &cache, 0, 0).unwrap();
    assert!(!grid.get(0, 0).is_nan());
    assert!(grid.get(20, 20).is_nan());
    let err = grid.take_error().unwrap().to_string();
    let file = store_path.join("a/0/c/1/1");
    assert!(err.starts_with(&format!("{}: ", file.display())), "{err}");
    assert!(grid.take_error().is_none());
}

#[test]
fn ingest_records_empty_chunks_and_a_missing_chunk_reads_as_an_error() {
    let mut inputs = Inputs::new();
    let mut data = surface(48, 48, 3);
    for r in 0..16 {
        data[r * 48..r * 48 + 16].fill(f32::NAN); // chunk (0, 0) of level 0 empty
    }
    let a = inputs.add("a.tif", 48, 48, utm(26917), data);
    let store_dir = tempfile::tempdir().unwrap();
    let store_path = store_dir.path().join("c.zarr");
    run(&inputs, &[a], &store_path, &options(16)).unwrap();
    let store = Store::open(&store_path).unwrap();
    let record = store.chunk_record(0).expect("a chunk record");
    assert!(record.is_empty(0, 3, 0, 0));
    assert!(!store_path.join("a/0/c/0/0").exists());
    assert_eq!(record.empty_count(0), 1);
    std::fs::remove_file(store_path.join("a/0/c/2/1")).unwrap();
    let cache = ChunkCache::new(1 << 20);
    let mut grid = StoreGrid::new(&store, &cache, 0, 0).unwrap();
    assert!(grid.get(3, 3).is_nan());
    assert!(
        grid.take_chunk_error().is_none(),
        "an empty chunk is no error"
    );
    assert!(grid.get(20, 40).is_nan());
    let err = grid
        .take_chunk_error()
        .expect("the missing chunk is an error");
    assert!(
        matches!(err, super::ChunkReadError::Missing { .. }),
        "{err}"
    );
    assert!(err.to_string().contains("a/0/c/2/1"), "{err}");
}
