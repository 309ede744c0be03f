//! Store round trips: in-memory rasters through `ingest_with`, read back via
//! `StoreGrid` and via zarrs directly; skip / force / refusal logic.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::ingest::{ingest_with, DsmAction, IngestError, IngestOptions, NoProgress};
use super::source::{MemSource, RowSource, SourceError, SourceRaster};
use super::{catalog, Compression, StorageSettings, Store, StoreGrid};
use crate::cache::ChunkCache;
use crate::grid::Grid;
use crate::raster::{Crs, GeoTransform};

fn utm(epsg: u32) -> Crs {
    Crs {
        epsg: Some(epsg),
        ..Default::default()
    }
}

/// A surface with NaN holes (a disc, a stripe, scattered pixels); `seed` varies it.
fn surface(w: u64, h: u64, seed: u32) -> Vec<f32> {
    let mut v = Vec::with_capacity((w * h) as usize);
    for r in 0..h {
        for c in 0..w {
            let (x, y) = (c as f32, r as f32);
            let hole = (x - 30.0).powi(2) + (y - 20.0).powi(2) < 80.0
                || (c + seed as u64).is_multiple_of(37)
                || (r * 13 + c * 7 + seed as u64).is_multiple_of(23);
            v.push(if hole {
                f32::NAN
            } else {
                100.0 + 0.25 * x - 0.5 * y + (x * 0.3 + seed as f32).sin() * 3.0
            });
        }
    }
    v
}

/// Input files (empty placeholders on disk, for paths and mtimes) and their rasters.
struct Inputs {
    dir: tempfile::TempDir,
    rasters: HashMap<PathBuf, MemSource>,
}

impl Inputs {
    fn new() -> Inputs {
        Inputs {
            dir: tempfile::tempdir().unwrap(),
            rasters: HashMap::new(),
        }
    }

    fn add(&mut self, name: &str, w: u64, h: u64, crs: Crs, data: Vec<f32>) -> PathBuf {
        let path = self.dir.path().join(name);
        std::fs::write(&path, name.as_bytes()).unwrap();
        let path = std::fs::canonicalize(path).unwrap();
        let raster = SourceRaster {
            path: path.clone(),
            width: w,
            height: h,
            geotransform: GeoTransform::north_up(630_000.0, 4_833_000.0, 0.5, 0.5),
            crs,
            nodata: Some(-9999.0),
            dtype: "Float32".into(),
        };
        self.rasters
            .insert(path.clone(), MemSource { raster, data });
        path
    }

    fn open(&self, path: &Path) -> Result<Box<dyn RowSource>, SourceError> {
        Ok(Box::new(self.rasters[path].clone()))
    }
}

fn options(chunk: u64) -> IngestOptions {
    IngestOptions {
        storage: StorageSettings {
            chunk,
            compression: Compression::Zstd { level: 3 },
            min_overview_px: 8,
        },
        force: false,
    }
}

fn run(
    inputs: &Inputs,
    paths: &[PathBuf],
    store: &Path,
    opts: &IngestOptions,
) -> Result<Vec<DsmAction>, IngestError> {
    let report = ingest_with(paths, store, opts, &NoProgress, &|p: &Path| inputs.open(p))?;
    Ok(report.outcomes.iter().map(|o| o.action).collect())
}

fn same(a: f32, b: f32) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

/// Level k+1 from level k by the 2x2 valid mean, computed directly.
fn mean_2x2(prev: &[f32], w: usize, h: usize) -> Vec<f32> {
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let mut out = Vec::with_capacity(w2 * h2);
    for r in 0..h2 {
        for c in 0..w2 {
            let vals: Vec<f64> = [
                (2 * r, 2 * c),
                (2 * r, 2 * c + 1),
                (2 * r + 1, 2 * c),
                (2 * r + 1, 2 * c + 1),
            ]
            .iter()
            .filter(|&&(y, x)| y < h && x < w)
            .map(|&(y, x)| prev[y * w + x])
            .filter(|v| !v.is_nan())
            .map(|v| v as f64)
            .collect();
            out.push(if vals.is_empty() {
                f32::NAN
            } else {
                (vals.iter().sum::<f64>() / vals.len() as f64) as f32
            });
        }
    }
    out
}

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
    let bounds = meta.geotransform.bounds(40, 30);
    assert!(meta.footprint[0] >= bounds[0] && meta.footprint[3] <= bounds[3]);
}

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

/// Every file in the store, with its bytes, to prove a failed run wrote nothing.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(snapshot(&p));
        } else {
            out.push((p.clone(), std::fs::read(&p).unwrap()));
        }
    }
    out.sort();
    out
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
            epsg: Some(4326),
            is_geographic: true,
            ..Default::default()
        },
        surface(30, 30, 6),
    );
    let other = inputs.add("other.tif", 30, 30, utm(32617), surface(30, 30, 7));
    let fresh = inputs.add("fresh.tif", 30, 30, utm(26917), surface(30, 30, 8));
    let empty = inputs.add("empty.tif", 0, 30, utm(26917), vec![]);
    let cases = [
        (
            geo,
            "geographic CRS EPSG:4326 (degrees) is not a metric frame",
        ),
        (
            other,
            "CRS EPSG:32617 differs from the collection's CRS EPSG:26917",
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

/// Not a unit test: builds a store from raw float32 rasters so that
/// `tools/check_zarr.py` can be run against GeoTIFFs before the GeoTIFF reader
/// is in this branch. `DSMSTREAM_RAW_DIR` holds `<id>.tif` (the source for
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

#[test]
fn store_types_cross_threads() {
    fn shared<T: Send + Sync>() {}
    fn owned<T: Send>() {}
    shared::<Store>();
    shared::<ChunkCache>();
    owned::<StoreGrid<'static>>();
}
