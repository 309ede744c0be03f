//! Agreement with an independent reference: a raster DSM (a GeoTIFF, a VRT
//! mosaic or an SRTM HGT tile, sampled at its pixel centres) or a lidar point
//! cloud (LAS/LAZ; point-to-surface). At each sample
//! dh = fused(x, y) - z_reference, where fused is the per-pixel median of the
//! corrected heights (see [`super::surfaces`]), before and after the poses.
//!
//! Samples are thinned to at most `max_samples` (a pixel stride of 2^k for a
//! raster, every k-th kept point for a cloud). The reference must be in the
//! store's CRS (a raster may also be in longitude and latitude or another
//! UTM zone on the datum of the store's zone: its pixel centres are
//! projected) and overlap it; otherwise the error is bad input.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::Serialize;

use super::las::LasSamples;
use super::stats::{diff_stats, DiffStats};
use super::surfaces::{Placement, Surfaces};
use super::{EvalConfig, EvalError};
use crate::cache::ChunkCache;
use crate::geo::Bounds;
use crate::store::Store;

/// Figures against the reference.
#[derive(Clone, Debug, Serialize)]
pub struct ReferenceEval {
    pub path: PathBuf,
    /// "geotiff", "vrt", "hgt" or "las".
    pub kind: String,
    /// Reference samples read (pixels at the stride, or kept points).
    pub reference_samples: u64,
    /// dh = fused - reference, identity poses.
    pub before: DiffStats,
    /// dh with the poses (None without poses).
    pub after: Option<DiffStats>,
    /// Remarks (CRS not recorded in the file, points filtered out, ...).
    pub notes: Vec<String>,
}

/// One reference sample location with its differences (NaN where no surface).
#[derive(Clone, Copy, Debug)]
pub struct DiffSample {
    pub x: f64,
    pub y: f64,
    pub dh_before: f32,
    pub dh_after: f32,
}

/// The figures and every sample (for the difference map).
pub struct ReferenceOutcome {
    pub eval: ReferenceEval,
    pub samples: Vec<DiffSample>,
}

/// Evaluate the fused surface against the reference at `path` (.tif/.tiff,
/// .vrt, .hgt/.zip or .las/.laz).
pub fn eval_reference(
    store: &Store,
    cache: &ChunkCache,
    before: &Placement,
    after: Option<&Placement>,
    config: &EvalConfig,
    path: &Path,
    pool: &rayon::ThreadPool,
) -> Result<ReferenceOutcome, EvalError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    let store_bounds = coverage(before, after);
    let (kind, points, notes) = match ext.as_str() {
        "tif" | "tiff" | "vrt" | "hgt" | "zip" => {
            let (points, notes) = raster_points(store, path, config, store_bounds)?;
            let kind = match ext.as_str() {
                "tif" | "tiff" => "geotiff",
                "vrt" => "vrt",
                _ => "hgt",
            };
            (kind, points, notes)
        }
        "las" | "laz" => {
            let s = LasSamples::read(store, path, config, store_bounds)?;
            ("las", s.points, s.notes)
        }
        _ => {
            let known = ".tif, .tiff, .vrt, .hgt, .hgt.zip, .las or .laz";
            let why = format!("unknown reference type (expected {known})");
            return Err(EvalError::Input(format!("{}: {why}", path.display())));
        }
    };
    let samples = pool.install(|| {
        points
            .par_chunks(4096)
            .map(|chunk| diff_chunk(store, cache, before, after, chunk))
            .collect::<Result<Vec<_>, _>>()
    })?;
    let samples: Vec<DiffSample> = samples.into_iter().flatten().collect();
    let mut dh_before: Vec<f32> = samples.iter().map(|s| s.dh_before).collect();
    let mut dh_after: Vec<f32> = samples.iter().map(|s| s.dh_after).collect();
    let before_stats = diff_stats(&mut dh_before, config.tau_m);
    let after_stats = after.map(|_| diff_stats(&mut dh_after, config.tau_m));
    if before_stats.samples == 0 && after_stats.is_none_or(|s| s.samples == 0) {
        return Err(EvalError::Input(format!(
            "{}: no reference sample falls on a valid pixel of the store's DSMs (does not overlap)",
            path.display()
        )));
    }
    Ok(ReferenceOutcome {
        eval: ReferenceEval {
            path: path.to_path_buf(),
            kind: kind.to_string(),
            reference_samples: points.len() as u64,
            before: before_stats,
            after: after_stats,
            notes,
        },
        samples,
    })
}

/// The box of every DSM before and after correction.
fn coverage(before: &Placement, after: Option<&Placement>) -> Bounds {
    let all = before
        .placed
        .iter()
        .chain(after.iter().flat_map(|a| a.placed.iter()))
        .map(|p| Bounds::from(p.corrected_bounds));
    Bounds::union_all(all).unwrap_or(Bounds::from([0.0; 4]))
}

fn diff_chunk(
    store: &Store,
    cache: &ChunkCache,
    before: &Placement,
    after: Option<&Placement>,
    points: &[[f64; 3]],
) -> Result<Vec<DiffSample>, EvalError> {
    let mut raw = Surfaces::new(store, cache, before);
    let mut corrected = after.map(|a| Surfaces::new(store, cache, a));
    let mut out = Vec::with_capacity(points.len());
    for &[x, y, z] in points {
        let dh_before = (raw.fused_height(x, y)? - z) as f32;
        let dh_after = match corrected.as_mut() {
            Some(s) => (s.fused_height(x, y)? - z) as f32,
            None => f32::NAN,
        };
        out.push(DiffSample {
            x,
            y,
            dh_before,
            dh_after,
        });
    }
    let errors = raw
        .take_error()
        .or_else(|| corrected.as_mut().and_then(|s| s.take_error()));
    if let Some(e) = errors {
        return Err(e.into());
    }
    Ok(out)
}

/// Valid pixel centres (x, y, z) of a reference GeoTIFF at a stride of 2^k px.
fn raster_points(
    store: &Store,
    path: &Path,
    config: &EvalConfig,
    store_bounds: Bounds,
) -> Result<(Vec<[f64; 3]>, Vec<String>), EvalError> {
    let mut source = crate::store::vrt::open_input(path)?;
    let info = source.raster().clone();
    let gt = info.geotransform;
    // a reference in longitude and latitude (SRTM, Copernicus), or in another
    // UTM zone, is projected point by point into a store in a UTM zone on its
    // datum
    let projection = store
        .crs()
        .and_then(|crs| crate::store::warp::projection_into(&info.crs, crs));
    if let (Some(crs), None) = (store.crs(), &projection) {
        if !info.crs.same_as(crs) {
            return Err(EvalError::Input(format!(
                "{}: CRS {} differs from the store's {}",
                path.display(),
                info.crs.label(),
                crs.label()
            )));
        }
    }
    let bounds = match &projection {
        Some(into) => {
            let [e0, n0, e1, n1] = into.bounds(&gt, info.width, info.height);
            Bounds::from_corners((e0, n0), (e1, n1))
        }
        None => gt.extent(info.width, info.height),
    };
    if !bounds.overlaps(&store_bounds) {
        return Err(EvalError::Input(format!(
            "{}: does not overlap the store (reference {:.1?}, store {:.1?})",
            path.display(),
            bounds.to_array(),
            store_bounds.to_array()
        )));
    }
    let mut stride = 1u64;
    while info.width.div_ceil(stride) * info.height.div_ceil(stride) > config.max_samples.max(1) {
        stride *= 2;
    }
    let mut points = Vec::new();
    let mut row = Vec::new();
    for r in (0..info.height).step_by(stride as usize) {
        source.read_rows_into(r, 1, &mut row)?;
        for c in (0..info.width).step_by(stride as usize) {
            let z = row[c as usize];
            if !z.is_nan() {
                let (x, y) = gt.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
                let (x, y) = projection.as_ref().map_or((x, y), |tm| tm.forward(x, y));
                points.push([x, y, z as f64]);
            }
        }
    }
    let mut notes = Vec::new();
    if stride > 1 {
        notes.push(format!("every {stride}th pixel in x and y sampled"));
    }
    if projection.is_some() {
        notes.push(format!(
            "reference pixel centres projected from {}",
            info.crs.label()
        ));
    }
    Ok((points, notes))
}
