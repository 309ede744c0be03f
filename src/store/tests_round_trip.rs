//! Store round trips: in-memory rasters through `ingest_with`, read back via
//! `StoreGrid` and via zarrs directly, pixel for pixel on every level; the
//! catalog's attributes and the arrays' metadata.

use std::collections::HashMap;
use std::path::PathBuf;

use super::ingest::DsmAction;
use super::source::{MemSource, SourceRaster};
use super::tests_support::{mean_2x2, options, run, same, surface, utm, Inputs};
use super::{catalog, Store, StoreGrid};
use crate::cache::ChunkCache;
use crate::geo::GeoTransform;
use crate::grid::Grid;

fn check_round_trip(chunk: u64, w: u64, h: u64) {
    let mut inputs = Inputs::new();
    let data = surface(w, h, 1);
    let path = inputs.add("tile_a.tif", w, h, utm(26917), data.clone());
    let store_dir = tempfile::tempdir().unwrap();
    let store_path = store_dir.path().join("c.zarr");
    let actions = run(&inputs, &[path], &store_path, &options(chunk)).unwrap();
    assert_eq!(actions, [DsmAction::Ingested]);

    let store = Store::open(&store_path).unwrap();
    let meta = &store.dsms()[0];
    assert_eq!(
        (meta.id.as_str(), meta.width, meta.height),
        ("tile_a", w, h)
    );
    let valid: Vec<f64> = data
        .iter()
        .filter(|v| !v.is_nan())
        .map(|&v| v as f64)
        .collect();
    assert_eq!(meta.valid_count, valid.len() as u64);
    let mean = valid.iter().sum::<f64>() / valid.len() as f64;
    assert!((meta.height_stats.mean - mean).abs() < 1e-9);
    assert_eq!(meta.nodata, Some(-9999.0));

    let cache = ChunkCache::new(4 * (chunk * chunk * 4) as usize);
    let mut expected = data;
    let (mut lw, mut lh) = (w as usize, h as usize);
    for level in 0..meta.levels.len() {
        if level > 0 {
            expected = mean_2x2(&expected, lw, lh);
            (lw, lh) = (lw.div_ceil(2), lh.div_ceil(2));
        }
        assert_eq!(
            (meta.levels[level].width, meta.levels[level].height),
            (lw as u64, lh as u64)
        );
        // Through the grid, pixel by pixel, in an order that revisits chunks.
        let mut grid = StoreGrid::new(&store, &cache, 0, level).unwrap();
        assert_eq!(
            grid.geotransform(),
            meta.geotransform.overview(level as u32)
        );
        for r in (0..lh).rev() {
            for c in 0..lw {
                let got = grid.get(c as i64, r as i64);
                assert!(
                    same(got, expected[r * lw + c]),
                    "level {level} ({c},{r}): {got} vs {}",
                    expected[r * lw + c]
                );
            }
        }
        assert!(
            grid.get(-1, 0).is_nan()
                && grid.get(lw as i64, 0).is_nan()
                && grid.get(0, lh as i64).is_nan()
        );
        // A window straddling the border.
        let win = grid.read_window(-3, 2, lw.min(40) + 5, 9);
        for (i, &v) in win.iter().enumerate() {
            let (c, r) = (
                (i % (lw.min(40) + 5)) as i64 - 3,
                (i / (lw.min(40) + 5)) as i64 + 2,
            );
            let want = if c < 0 || c >= lw as i64 || r >= lh as i64 {
                f32::NAN
            } else {
                expected[r as usize * lw + c as usize]
            };
            assert!(same(v, want), "window level {level} ({c},{r})");
        }
        assert!(grid.take_error().is_none());
        // Through zarrs directly.
        let array = store.array(0, level).unwrap();
        let all: Vec<f32> = array.retrieve_array_subset(&array.subset_all()).unwrap();
        assert!(
            all.iter().zip(&expected).all(|(&a, &b)| same(a, b)),
            "zarrs level {level}"
        );
    }
    let s = cache.stats();
    assert!(s.peak_bytes <= s.budget_bytes && s.misses > 0);
}

#[test]
fn store_round_trip_power_of_two_chunks() {
    check_round_trip(16, 101, 77);
}

#[test]
fn store_round_trip_odd_chunks() {
    check_round_trip(17, 70, 93);
}

#[test]
fn store_catalog_attributes_and_array_metadata() {
    let mut inputs = Inputs::new();
    let a = inputs.add("a.tif", 40, 30, utm(32617), surface(40, 30, 2));
    let b = inputs.add("b.tif", 20, 50, utm(32617), surface(20, 50, 3));
    let store_dir = tempfile::tempdir().unwrap();
    let store_path = store_dir.path().join("c.zarr");
    run(&inputs, &[b.clone(), a.clone()], &store_path, &options(16)).unwrap();
    let root = catalog::read_root(&store_path).unwrap();
    assert_eq!(root.dsms, ["b", "a"]);
    assert_eq!(root.crs, Some(utm(32617)));
    let store = Store::open(&store_path).unwrap();
    assert_eq!(store.find("a"), Some(1));
    let meta = &store.dsms()[1];
    assert_eq!(meta.source.path, a.display().to_string());
    assert_eq!(meta.source.size, 5);
    assert_eq!(meta.storage.chunk, 16);
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(store_path.join("a/0/zarr.json")).unwrap())
            .unwrap();
    assert_eq!(doc["dimension_names"], serde_json::json!(["y", "x"]));
    assert_eq!(doc["fill_value"], "NaN");
    assert_eq!(doc["data_type"], "float32");
    assert!(doc["attributes"].get("_zarrs").is_none());
    assert!(doc["codecs"].to_string().contains("zstd"));
    // footprint: the valid pixels' box, inside the raster bounds
    let extent = meta.geotransform.extent(40, 30);
    assert!(meta.footprint.min_x >= extent.min_x && meta.footprint.max_y <= extent.max_y);
}

/// Not a unit test: builds a store from raw float32 rasters, bypassing the
/// GeoTIFF reader, so that `tools/scripts/check_zarr.py` can compare the store
/// with rasterio's reading of the GeoTIFFs. `DSMSTREAM_RAW_DIR` holds `<id>.tif` (the source for
/// rasterio), `<id>.f32` (its pixels as the reader would return them) and
/// `<id>.json` ({width, height, geotransform, epsg, nodata, dtype});
/// the store is written to `DSMSTREAM_RAW_STORE`.
#[test]
#[ignore]
fn store_from_raw_rasters_for_check_zarr() {
    let dir = PathBuf::from(std::env::var("DSMSTREAM_RAW_DIR").expect("DSMSTREAM_RAW_DIR"));
    let store = PathBuf::from(std::env::var("DSMSTREAM_RAW_STORE").expect("DSMSTREAM_RAW_STORE"));
    let chunk: u64 = std::env::var("DSMSTREAM_RAW_CHUNK")
        .map(|c| c.parse().unwrap())
        .unwrap_or(512);
    let mut inputs = Inputs {
        dir: tempfile::tempdir().unwrap(),
        rasters: HashMap::new(),
    };
    let mut tifs = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let json_path = entry.unwrap().path();
        if json_path.extension().is_none_or(|e| e != "json") {
            continue;
        }
        let j: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json_path).unwrap()).unwrap();
        let tif = std::fs::canonicalize(json_path.with_extension("tif")).unwrap();
        let bytes = std::fs::read(json_path.with_extension("f32")).unwrap();
        let data: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        let gt: Vec<f64> = serde_json::from_value(j["geotransform"].clone()).unwrap();
        let raster = SourceRaster {
            path: tif.clone(),
            width: j["width"].as_u64().unwrap(),
            height: j["height"].as_u64().unwrap(),
            geotransform: GeoTransform(gt.try_into().unwrap()),
            crs: utm(j["epsg"].as_u64().unwrap() as u32),
            nodata: j["nodata"].as_f64(),
            dtype: j["dtype"].as_str().unwrap().into(),
            height_unit: None,
            georeferenced_by: Vec::new(),
        };
        inputs
            .rasters
            .insert(tif.clone(), MemSource { raster, data });
        tifs.push(tif);
    }
    let mut opts = options(chunk);
    opts.storage.min_overview_px = 256;
    let actions = run(&inputs, &tifs, &store, &opts).unwrap();
    eprintln!("{actions:?}");
}

#[test]
fn store_types_cross_threads() {
    fn shared<T: Send + Sync>() {}
    fn owned<T: Send>() {}
    shared::<Store>();
    shared::<ChunkCache>();
    owned::<StoreGrid<'static>>();
}
