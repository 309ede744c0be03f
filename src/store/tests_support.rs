//! Fixtures of the store's unit tests: in-memory rasters behind placeholder
//! input files, the ingest options and runner the tests use, and pixel checks.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::ingest::{ingest_with, DsmAction, IngestError, IngestOptions, NoProgress};
use super::source::{MemSource, RowSource, SourceError, SourceRaster};
use super::{Compression, StorageSettings};
use crate::geo::{Crs, GeoTransform};

pub(super) fn utm(epsg: u32) -> Crs {
    Crs {
        epsg: Some(epsg),
        ..Default::default()
    }
}

/// A surface with NaN holes (a disc, a stripe, scattered pixels); `seed` varies it.
pub(super) fn surface(w: u64, h: u64, seed: u32) -> Vec<f32> {
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
pub(super) struct Inputs {
    pub(super) dir: tempfile::TempDir,
    pub(super) rasters: HashMap<PathBuf, MemSource>,
}

impl Inputs {
    pub(super) fn new() -> Inputs {
        Inputs {
            dir: tempfile::tempdir().unwrap(),
            rasters: HashMap::new(),
        }
    }

    pub(super) fn add(&mut self, name: &str, w: u64, h: u64, crs: Crs, data: Vec<f32>) -> PathBuf {
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
            height_unit: None,
            georeferenced_by: Vec::new(),
        };
        self.rasters
            .insert(path.clone(), MemSource { raster, data });
        path
    }

    pub(super) fn open(&self, path: &Path) -> Result<Box<dyn RowSource>, SourceError> {
        Ok(Box::new(self.rasters[path].clone()))
    }
}

pub(super) fn options(chunk: u64) -> IngestOptions {
    IngestOptions {
        storage: StorageSettings {
            chunk,
            compression: Compression::Zstd { level: 3 },
            min_overview_px: 8,
        },
        force: false,
        target: None,
    }
}

pub(super) fn run(
    inputs: &Inputs,
    paths: &[PathBuf],
    store: &Path,
    opts: &IngestOptions,
) -> Result<Vec<DsmAction>, IngestError> {
    let report = ingest_with(paths, store, opts, &NoProgress, &|p: &Path| inputs.open(p))?;
    Ok(report.outcomes.iter().map(|o| o.action).collect())
}

pub(super) fn same(a: f32, b: f32) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

/// Level k+1 from level k by the 2x2 valid mean, computed directly.
pub(super) fn mean_2x2(prev: &[f32], w: usize, h: usize) -> Vec<f32> {
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

/// Every file in the store, with its bytes, to prove a failed run wrote nothing.
pub(super) fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
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
