//! Fuzzing that stays (issue 15): proptest mutations of real inputs for the
//! GeoTIFF reader, the store's metadata (DSM and root `zarr.json`) and
//! poses.json. Nothing may panic; every refusal is one line. Each test runs a
//! few hundred cases in a few seconds (release build), so `cargo test` keeps
//! them; `PROPTEST_CASES=N` runs longer campaigns.

use std::path::{Path, PathBuf};

use dsmstream::cache::ChunkCache;
use dsmstream::geotiff::reader::GeoTiffReader;
use dsmstream::grid::Grid;
use dsmstream::poses::PosesFile;
use dsmstream::store::ingest::NoProgress;
use dsmstream::store::{ingest, IngestOptions, StorageSettings, Store, StoreGrid};
use proptest::prelude::*;
use serde_json::Value;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

const TIFFS: [&str; 12] = [
    "geotiff/f32_tile_deflate_p3.tif",
    "geotiff/i16_strip_lzw_bigtiff.tif",
    "geotiff/u16_tile_zstd.tif",
    "geotiff/f64_strip_packbits.tif",
    "geotiff/f32_model_transformation.tif",
    "synth/grid2x2/tile_00.tif",
    "geotiff/f32_tile_lerc.tif",
    "geotiff/f32_tile_lerc_zstd.tif",
    "geotiff/i16_tile_lerc_deflate.tif",
    "geotiff/f32_tile_deflate_mask.tif",
    "geotiff/i16_scale_offset.tif",
    "geotiff/f16_strip_lzw_p3_bigendian.tif",
];

/// One byte mutation: position (as a fraction of the span) and new byte.
fn mutations() -> impl Strategy<Value = Vec<(f64, u8, bool)>> {
    prop::collection::vec((0.0..1.0f64, any::<u8>(), any::<bool>()), 1..8)
}

fn mutate(bytes: &mut [u8], muts: &[(f64, u8, bool)]) {
    for &(at, byte, head) in muts {
        // Half the mutations hit the header and IFDs, where parsing happens.
        let span = if head {
            bytes.len().min(1024)
        } else {
            bytes.len()
        };
        let i = ((at * span as f64) as usize).min(span - 1);
        bytes[i] = byte;
    }
}

/// Cases per test: `PROPTEST_CASES` when set (long campaigns), else `default`.
fn cases(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn one_line(e: &impl std::fmt::Display) -> bool {
    !e.to_string().contains('\n')
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(400), ..ProptestConfig::default() })]

    #[test]
    fn geotiff_reader_never_panics(file in 0..TIFFS.len(), muts in mutations()) {
        let dir = tempfile::tempdir().unwrap();
        let mut bytes = std::fs::read(fixtures().join(TIFFS[file])).unwrap();
        mutate(&mut bytes, &muts);
        let path = dir.path().join("m.tif");
        std::fs::write(&path, &bytes).unwrap();
        match GeoTiffReader::open(&path) {
            Err(e) => prop_assert!(one_line(&e) && e.to_string().contains("m.tif"), "{e}"),
            Ok(mut r) => {
                let h = r.info().height;
                if let Err(e) = r.read_rows(0, h) {
                    prop_assert!(one_line(&e), "{e}");
                }
            }
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(300), ..ProptestConfig::default() })]

    /// A zipped SRTM tile with bytes changed in its local header, its data or
    /// its central directory: refused in one line naming the file, or read
    /// whole with the heights of the tile as it was (a change that reaches
    /// the heights is caught by Deflate or by the CRC-32 at the member's end,
    /// never read as heights).
    #[test]
    fn zipped_hgt_reader_never_panics(muts in prop::collection::vec((0.0..1.0f64, any::<u8>(), 0..3u8), 1..6)) {
        use dsmstream::store::hgt::HgtSource;
        use dsmstream::store::source::RowSource;
        let dir = tempfile::tempdir().unwrap();
        let mut bytes = std::fs::read(fixtures().join("hgt/N39E040.SRTMGL3.hgt.zip")).unwrap();
        let n = bytes.len();
        for (at, byte, part) in muts {
            // the local header, the central directory and end record, anywhere
            let (start, span) = match part {
                0 => (0, 64),
                1 => (n - 128, 128),
                _ => (0, n),
            };
            bytes[start + ((at * span as f64) as usize).min(span - 1)] = byte;
        }
        let path = dir.path().join("N39E040.hgt.zip");
        std::fs::write(&path, &bytes).unwrap();
        let named = |e: &dsmstream::store::source::SourceError| {
            one_line(e) && e.message.contains("N39E040.hgt.zip")
        };
        match HgtSource::open(&path) {
            Err(e) => prop_assert!(named(&e), "{}", e.message),
            Ok(mut source) => {
                let h = source.raster().height;
                let (mut row0, mut all) = (0, Vec::new());
                while row0 < h {
                    let rows = 100.min(h - row0);
                    match source.read_rows(row0, rows) {
                        Ok(band) => all.extend(band),
                        Err(e) => {
                            prop_assert!(named(&e), "{}", e.message);
                            return Ok(());
                        }
                    }
                    row0 += rows;
                }
                let same = all.len() == hgt_heights().len()
                    && all.iter().zip(hgt_heights()).all(|(a, b)| a.to_bits() == b.to_bits());
                prop_assert!(same, "read whole, but not the tile's heights");
            }
        }
    }
}

/// The heights of the zipped SRTM fixture, read once per test process.
fn hgt_heights() -> &'static [f32] {
    use dsmstream::store::source::RowSource;
    static HEIGHTS: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    HEIGHTS.get_or_init(|| {
        let path = fixtures().join("hgt/N39E040.SRTMGL3.hgt.zip");
        let mut source = dsmstream::store::hgt::HgtSource::open(&path).unwrap();
        let h = source.raster().height;
        source.read_rows(0, h).unwrap()
    })
}

/// A store of two fixture DSMs (chunk 64), made once per test process.
fn template_store() -> &'static Path {
    static STORE: std::sync::OnceLock<(tempfile::TempDir, PathBuf)> = std::sync::OnceLock::new();
    let (_, path) = STORE.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let store = dir.path().join("t.zarr");
        let options = IngestOptions {
            storage: StorageSettings {
                chunk: 64,
                ..Default::default()
            },
            force: false,
            target: None,
        };
        let inputs = [
            fixtures().join("synth/grid2x2/tile_00.tif"),
            fixtures().join("synth/grid2x2/tile_01.tif"),
        ];
        ingest(&inputs, &store, &options, &NoProgress).unwrap();
        (dir, store)
    });
    path
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let p = e.unwrap().path();
        let target = to.join(p.file_name().unwrap());
        if p.is_dir() {
            copy_dir(&p, &target);
        } else {
            std::fs::copy(&p, &target).unwrap();
        }
    }
}

/// Replacement values for a JSON node: wrong types, extremes, escapes.
fn hostile_value() -> impl Strategy<Value = Value> {
    prop_oneof![
        Just(Value::Null),
        Just(Value::Bool(true)),
        Just(serde_json::json!(0)),
        Just(serde_json::json!(-1)),
        Just(serde_json::json!(1e308)),
        Just(serde_json::json!(-1e308)),
        Just(serde_json::json!(1e-300)),
        Just(serde_json::json!(u64::MAX)),
        Just(serde_json::json!(i64::MIN)),
        Just(serde_json::json!("../outside")),
        Just(serde_json::json!("nan")),
        Just(serde_json::json!([])),
        Just(serde_json::json!({})),
        Just(serde_json::json!([[0, 1]])),
        any::<i32>().prop_map(|v| serde_json::json!(v)),
    ]
}

/// Replace the `pick`-th node (in a depth-first walk) of `v` by `with`.
fn replace_nth(v: &mut Value, pick: &mut usize, with: &Value) -> bool {
    if *pick == 0 {
        *v = with.clone();
        return true;
    }
    *pick -= 1;
    match v {
        Value::Array(items) => items.iter_mut().any(|x| replace_nth(x, pick, with)),
        Value::Object(map) => map.values_mut().any(|x| replace_nth(x, pick, with)),
        _ => false,
    }
}

/// Open the store and read a few pixels of every level of every DSM.
fn exercise(store: &Path) {
    let Ok(store) = Store::open(store) else {
        return;
    };
    let cache = ChunkCache::new(1 << 20);
    for dsm in 0..store.dsms().len() {
        for level in 0..store.dsms()[dsm].levels.len() {
            if let Ok(mut g) = StoreGrid::new(&store, &cache, dsm, level) {
                let (w, h) = (g.width(), g.height());
                for (c, r) in [(0, 0), (w / 2, h / 2), (w - 1, h - 1), (w + 5, -3)] {
                    let _ = g.get(c, r);
                }
                let _ = g.take_error();
            }
        }
    }
    let _ = dsmstream::store::check::check_store(store.root());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(48), ..ProptestConfig::default() })]

    #[test]
    fn store_metadata_reader_never_panics(
        which in 0..4usize,
        edits in prop::collection::vec((0..400usize, hostile_value()), 1..4),
        raw in prop::option::of(mutations()),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let store = dir.path().join("s.zarr");
        copy_dir(template_store(), &store);
        let file = match which {
            0 => store.join("zarr.json"),
            1 => store.join("tile_00/zarr.json"),
            2 => store.join("tile_01/0/zarr.json"),
            _ => store.join("tile_01/zarr.json"),
        };
        let mut doc: Value = serde_json::from_slice(&std::fs::read(&file).unwrap()).unwrap();
        for (pick, with) in &edits {
            let mut pick = *pick;
            replace_nth(&mut doc, &mut pick, with);
        }
        let mut bytes = serde_json::to_vec_pretty(&doc).unwrap();
        if let Some(muts) = raw {
            mutate(&mut bytes, &muts);
        }
        std::fs::write(&file, &bytes).unwrap();
        exercise(&store);
    }

    #[test]
    fn poses_json_parser_never_panics(
        edits in prop::collection::vec((0..120usize, hostile_value()), 0..4),
        raw in prop::option::of(mutations()),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let mut doc = serde_json::json!({
            "crs": "EPSG:32617",
            "poses": [
                {"id": "tile_00", "matrix_world": [[1.0, 0.0, 0.0, 0.5], [0.0, 1.0, 0.0, -0.25], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]],
                 "sigma": {"shift_m": [0.01, 0.01, 0.02], "rotation_deg": [0.001, 0.001, 0.002]}},
                {"id": "tile_01", "matrix_world": [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]}
            ],
            "edges": [{"i": "tile_00", "j": "tile_01", "overlap": 0.4, "rmse": 0.6, "weight": 1.0, "iterations": 12, "inliers": 1000}],
            "graph": "full", "gauge": "mean"
        });
        for (pick, with) in &edits {
            let mut pick = *pick;
            replace_nth(&mut doc, &mut pick, with);
        }
        let mut bytes = serde_json::to_vec_pretty(&doc).unwrap();
        if let Some(muts) = raw {
            mutate(&mut bytes, &muts);
        }
        let path = dir.path().join("poses.json");
        std::fs::write(&path, &bytes).unwrap();
        if let Err(e) = PosesFile::read(&path) {
            prop_assert!(one_line(&e), "{e}");
        }
    }
}
