//! Fuse end to end on small generated stores: known shifts are undone by the
//! poses, identity reproduces the input, the file does not depend on threads.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;

use super::*;
use crate::geo::Crs;
use crate::geotiff::reader::GeoTiffReader;
use crate::geotiff::writer::{write_geotiff_f32, CogOptions};
use crate::poses::{GaugeLabel, GraphKind, PoseEntry, PosesFile};
use crate::store::{ingest, ingest::NoProgress, IngestOptions};

const GSD: f64 = 0.5;

fn crs() -> Crs {
    Crs {
        epsg: Some(32617),
        ..Default::default()
    }
}

/// The true surface: smooth hills, metres of relief.
fn truth(x: f64, y: f64) -> f64 {
    let (u, v) = (x - 500_000.0, y - 4_800_000.0);
    200.0 + 5.0 * (u / 17.0).sin() + 3.0 * (v / 11.0).cos() + 0.02 * u
}

/// A 300 x 200 px DSM whose top-left corner is at (ox, oy), sampled from the
/// truth displaced by `shift` (its content sits at truth(p) + shift, so the
/// correcting pose is a translation by -shift).
fn write_dsm(dir: &Path, name: &str, ox: f64, oy: f64, shift: [f64; 3]) -> PathBuf {
    let (w, h) = (300u64, 200u64);
    let gt = GeoTransform::north_up(ox, oy, GSD, GSD);
    let mut data = Vec::with_capacity((w * h) as usize);
    for r in 0..h {
        for c in 0..w {
            let (x, y) = gt.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            let hole = (c as i64 - 40).pow(2) + (r as i64 - 50).pow(2) < 60;
            data.push(if hole {
                f32::NAN
            } else {
                (truth(x - shift[0], y - shift[1]) + shift[2]) as f32
            });
        }
    }
    let path = dir.join(format!("{name}.tif"));
    let options = CogOptions {
        geotransform: gt,
        crs: crs(),
        ..Default::default()
    };
    write_geotiff_f32(&path, w, h, options, &data).unwrap();
    path
}

fn translation(t: [f64; 3]) -> Matrix4<f64> {
    let mut m = Matrix4::identity();
    for k in 0..3 {
        m[(k, 3)] = t[k];
    }
    m
}

fn poses_file(entries: &[(&str, [f64; 3])]) -> PosesFile {
    PosesFile {
        crs: "EPSG:32617".into(),
        poses: entries
            .iter()
            .map(|(id, t)| PoseEntry {
                id: id.to_string(),
                matrix_world: translation(*t),
                sigma: None,
                status: None,
            })
            .collect(),
        edges: vec![],
        graph: GraphKind::Full,
        gauge: GaugeLabel::Mean,
        components: None,
        summary: None,
    }
}

struct Fixture {
    dir: tempfile::TempDir,
    store: Store,
}

fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let a = write_dsm(dir.path(), "a", 500_000.0, 4_800_000.0, [0.0, 0.0, 0.0]);
    let b = write_dsm(dir.path(), "b", 500_080.0, 4_799_980.0, [1.5, -1.0, 0.8]);
    let store_path = dir.path().join("c.zarr");
    ingest(&[a, b], &store_path, &IngestOptions::default(), &NoProgress).unwrap();
    let store = Store::open(&store_path).unwrap();
    Fixture { dir, store }
}

fn read_all(path: &Path) -> (crate::geotiff::reader::GeoTiffInfo, Vec<f32>) {
    let mut r = GeoTiffReader::open(path).unwrap();
    let info = r.info().clone();
    let data = r.read_rows(0, info.height).unwrap();
    (info, data)
}

/// RMS of fused - truth over valid pixels, and their count.
fn rms_vs_truth(path: &Path) -> (f64, usize) {
    let (info, data) = read_all(path);
    let (mut sum, mut n) = (0.0, 0);
    for r in 0..info.height {
        for c in 0..info.width {
            let v = data[(r * info.width + c) as usize];
            if !v.is_nan() {
                let (x, y) = info
                    .geotransform
                    .pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
                sum += (v as f64 - truth(x, y)).powi(2);
                n += 1;
            }
        }
    }
    ((sum / n.max(1) as f64).sqrt(), n)
}

#[test]
fn poses_undo_known_shifts_and_identity_does_not() {
    let f = fixture();
    let cache = ChunkCache::new(16 << 20);
    let config = FuseConfig {
        threads: 2,
        ..Default::default()
    };
    let id = PoseSet::identity(&f.store);
    let out_id = f.dir.path().join("identity.tif");
    fuse(&f.store, &cache, &id, &config, &out_id, &|_, _| {}).unwrap();
    let file = poses_file(&[("a", [0.0; 3]), ("b", [-1.5, 1.0, -0.8])]);
    let poses = PoseSet::from_parsed(&f.store, Path::new("p.json"), file).unwrap();
    let out = f.dir.path().join("fused.tif");
    let report = fuse(&f.store, &cache, &poses, &config, &out, &|_, _| {}).unwrap();
    let (rms_id, _) = rms_vs_truth(&out_id);
    let (rms, n) = rms_vs_truth(&out);
    assert!(n > 50_000, "{n} valid pixels");
    assert!(rms < 0.02, "rms with poses {rms}");
    assert!(rms_id > 0.3, "rms without poses {rms_id}");
    // the grid: union of corrected footprints on the 0.5 m lattice of DSM a
    let (info, _) = read_all(&out);
    assert_eq!(info.geotransform.0[0], 500_000.0);
    assert_eq!(info.geotransform.0[3], 4_800_000.0);
    assert_eq!(info.width, ((80.0 - 1.5 + 150.0) / GSD) as u64);
    assert_eq!((report.width, report.height), (info.width, info.height));
    assert!(info.nodata.is_some_and(|v| v.is_nan()));
}

#[test]
fn identity_reproduces_a_single_dsm_exactly_and_threads_do_not_matter() {
    let f = fixture();
    let cache = ChunkCache::new(16 << 20);
    let id = PoseSet::identity(&f.store);
    let dir1 = f.dir.path().join("one");
    let dir3 = f.dir.path().join("three");
    for (dir, threads) in [(&dir1, 1), (&dir3, 3)] {
        let config = FuseConfig {
            threads,
            ..Default::default()
        };
        fuse_per_dsm(&f.store, &cache, &id, &config, dir, &|_, _| {}).unwrap();
    }
    let a1 = std::fs::read(dir1.join("a.tif")).unwrap();
    assert_eq!(a1, std::fs::read(dir3.join("a.tif")).unwrap());
    let (_, source) = read_all(&f.dir.path().join("a.tif"));
    let (info, fused) = read_all(&dir1.join("a.tif"));
    assert_eq!((info.width, info.height), (300, 200));
    let same = source
        .iter()
        .zip(&fused)
        .all(|(a, b)| a == b || (a.is_nan() && b.is_nan()));
    assert!(same, "identity per-DSM output differs from the input");
}

#[test]
fn coarser_gsd_reads_an_overview_and_count_counts() {
    let f = fixture();
    let cache = ChunkCache::new(16 << 20);
    let id = PoseSet::identity(&f.store);
    let out = f.dir.path().join("count.tif");
    let config = FuseConfig {
        gsd_m: Some(1.0),
        method: FuseMethod::Count,
        ..Default::default()
    };
    let report = fuse(&f.store, &cache, &id, &config, &out, &|_, _| {}).unwrap();
    assert_eq!(report.gsd_m, 1.0);
    let (info, data) = read_all(&out);
    let max = data.iter().copied().fold(0.0f32, f32::max);
    assert_eq!(max, 2.0);
    assert_eq!(info.geotransform.gsd_x(), 1.0);
}

#[test]
fn poses_must_match_the_store() {
    let f = fixture();
    let p = Path::new("p.json");
    let missing = poses_file(&[("a", [0.0; 3])]);
    let err = PoseSet::from_parsed(&f.store, p, missing).unwrap_err();
    assert!(err.is_bad_input());
    assert!(
        err.to_string().contains("p.json: no pose for DSM 'b'"),
        "{err}"
    );
    let unknown = poses_file(&[("a", [0.0; 3]), ("b", [0.0; 3]), ("zz", [0.0; 3])]);
    let err = PoseSet::from_parsed(&f.store, p, unknown).unwrap_err();
    assert!(err.to_string().contains("pose 'zz' names no DSM"), "{err}");
    let mut other_crs = poses_file(&[("a", [0.0; 3]), ("b", [0.0; 3])]);
    other_crs.crs = "EPSG:32616".into();
    let err = PoseSet::from_parsed(&f.store, p, other_crs).unwrap_err();
    assert!(err.to_string().contains("EPSG:32616"), "{err}");
}

#[test]
fn morton_order_visits_every_tile_once() {
    let order = morton_order(5, 3);
    assert_eq!(order.len(), 15);
    let mut sorted = order.clone();
    sorted.sort();
    sorted.dedup();
    assert_eq!(sorted.len(), 15);
    assert_eq!(&order[..4], &[(0, 0), (1, 0), (0, 1), (1, 1)]);
}
