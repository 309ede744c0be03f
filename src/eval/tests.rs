//! Eval on a small generated store with a known shift: pairs agree after the
//! poses, a reference raster of the truth scores the fused surface, and bad
//! references (other CRS, elsewhere) are refused as bad input.

use std::path::Path;

use nalgebra::Matrix4;

use super::*;
use crate::geo::{Crs, GeoTransform};
use crate::geotiff::writer::{write_geotiff_f32, CogOptions};
use crate::poses::{GaugeLabel, GraphKind, PoseEntry, PosesFile};
use crate::store::{ingest, ingest::NoProgress, IngestOptions};

fn crs(epsg: u32) -> Crs {
    Crs {
        epsg: Some(epsg),
        ..Default::default()
    }
}

fn truth(x: f64, y: f64) -> f64 {
    let (u, v) = (x - 500_000.0, y - 4_800_000.0);
    150.0 + 4.0 * (u / 13.0).sin() * (v / 19.0).cos() + 0.05 * v
}

/// A w x h raster at 0.5 m sampling the truth displaced by `shift`.
fn raster(path: &Path, ox: f64, oy: f64, w: u64, h: u64, shift: [f64; 3], epsg: u32) {
    let gt = GeoTransform::north_up(ox, oy, 0.5, 0.5);
    let mut data = Vec::new();
    for r in 0..h {
        for c in 0..w {
            let (x, y) = gt.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            data.push((truth(x - shift[0], y - shift[1]) + shift[2]) as f32);
        }
    }
    let options = CogOptions {
        geotransform: gt,
        crs: crs(epsg),
        ..Default::default()
    };
    write_geotiff_f32(path, w, h, options, &data).unwrap();
}

struct Fixture {
    dir: tempfile::TempDir,
    store: Store,
    poses: PoseSet,
}

fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("a.tif"), dir.path().join("b.tif"));
    raster(&a, 500_000.0, 4_800_000.0, 200, 160, [0.0; 3], 32617);
    raster(
        &b,
        500_050.0,
        4_799_990.0,
        200,
        160,
        [1.0, 0.5, -0.7],
        32617,
    );
    let store_path = dir.path().join("c.zarr");
    ingest(&[a, b], &store_path, &IngestOptions::default(), &NoProgress).unwrap();
    let store = Store::open(&store_path).unwrap();
    let mut m = Matrix4::identity();
    m[(0, 3)] = -1.0;
    m[(1, 3)] = -0.5;
    m[(2, 3)] = 0.7;
    let file = PosesFile {
        crs: "EPSG:32617".into(),
        poses: vec![
            PoseEntry {
                id: "a".into(),
                matrix_world: Matrix4::identity(),
                sigma: None,
                status: None,
            },
            PoseEntry {
                id: "b".into(),
                matrix_world: m,
                sigma: None,
                status: None,
            },
        ],
        edges: vec![],
        graph: GraphKind::Full,
        gauge: GaugeLabel::Mean,
        components: None,
        summary: None,
    };
    let poses = PoseSet::from_parsed(&store, Path::new("p.json"), file).unwrap();
    Fixture { dir, store, poses }
}

fn config() -> EvalConfig {
    EvalConfig {
        threads: 2,
        max_samples: 5_000,
        ..Default::default()
    }
}

#[test]
fn pairs_agree_after_the_poses() {
    let f = fixture();
    let cache = ChunkCache::new(16 << 20);
    let (report, plots) = evaluate(&f.store, &cache, Some(&f.poses), None, &config()).unwrap();
    assert_eq!(report.pairs.len(), 1);
    let p = &report.pairs[0];
    assert_eq!((p.i.as_str(), p.j.as_str()), ("a", "b"));
    assert!(
        p.stride_px >= 2,
        "5000 samples need a stride, got {}",
        p.stride_px
    );
    let after = p.after.unwrap();
    assert!(p.before.rmse_tau_m > 0.5, "{:?}", p.before);
    assert!(after.rmse_tau_m < 0.01, "{after:?}");
    assert!(after.samples <= 5_000 && after.samples > 1_000);
    assert_eq!(report.mean_after.unwrap().rmse_tau_m, after.rmse_tau_m);
    assert!(!plots.pairs_before.is_empty() && !plots.pairs_after.is_empty());
    // the raw collection: before only
    let (raw, _) = evaluate(&f.store, &cache, None, None, &config()).unwrap();
    assert!(raw.pairs[0].after.is_none());
    assert_eq!(raw.pairs[0].before, p.before);
    assert!(report.to_table().contains("a - b"));
}

#[test]
fn reference_raster_scores_the_fused_surface() {
    let f = fixture();
    let cache = ChunkCache::new(16 << 20);
    let reference = f.dir.path().join("ref.tif");
    raster(
        &reference,
        500_010.0,
        4_799_995.0,
        300,
        120,
        [0.0; 3],
        32617,
    );
    let (report, plots) = evaluate(
        &f.store,
        &cache,
        Some(&f.poses),
        Some(&reference),
        &config(),
    )
    .unwrap();
    let r = report.reference.unwrap();
    let after = r.after.unwrap();
    assert!(after.rmse_tau_m < 0.01, "{after:?}");
    assert!(r.before.rmse_tau_m > 0.2, "{:?}", r.before);
    assert!(r.reference_samples <= 5_000);
    assert_eq!(plots.reference.len() as u64, r.reference_samples);
}

#[test]
fn bad_references_are_bad_input() {
    let f = fixture();
    let cache = ChunkCache::new(16 << 20);
    let other_crs = f.dir.path().join("csrs.tif");
    raster(&other_crs, 500_010.0, 4_799_995.0, 50, 50, [0.0; 3], 2958);
    let far = f.dir.path().join("far.tif");
    raster(&far, 600_000.0, 4_799_995.0, 50, 50, [0.0; 3], 32617);
    let unknown = f.dir.path().join("ref.xyz");
    std::fs::write(&unknown, "1 2 3").unwrap();
    for (path, needle) in [
        (&other_crs, "differs from the store"),
        (&far, "does not overlap"),
        (&unknown, "unknown reference type"),
    ] {
        let err = evaluate(&f.store, &cache, Some(&f.poses), Some(path), &config())
            .err()
            .unwrap();
        assert!(err.is_bad_input(), "{err}");
        assert!(err.to_string().contains(needle), "{err}");
        assert!(
            err.to_string().contains(&path.display().to_string()),
            "{err}"
        );
    }
}
