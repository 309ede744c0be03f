//! Real data with a known answer: cut a real DSM (a GeoTIFF) into overlapping
//! tiles (a chain or a grid, as [`super::tiles`] lays them out), move each tile
//! by a known rigid motion, and write the tiles as COGs with the source's CRS
//! and no-data, plus a `truth.json` that [`Truth::load`] and
//! [`Truth::pairwise_error`] read. `dsmgen cut` is the command line over it.
//!
//! Frames as in [`super::tiles`]: `m_world` maps a point of the written tile to
//! its true position, M = T(c' + s) R T(-c') about the written tile's centre c'
//! at the pivot height (the mean valid height of the source). The written
//! tile's geotransform is its source window's moved by -s in x and y, so
//! without rotation every written pixel centre lands exactly on a source pixel
//! centre: the horizontal shift needs no resampling, and the written height is
//! the source's minus s_z. With a rotation, each written pixel solves
//! M (x', y', h') = (x, y, S(x, y)) by the fixed point of
//! [`solve_written_height`], S bilinear in the source where all four
//! neighbours are valid (else no data); a position within 1e-6 px of a pixel
//! centre takes that pixel's value.
//!
//! Memory: one streaming pass over the source (pivot height, height range, the
//! valid pixels of each window), then per tile only the source rows it reaches.

use std::path::{Path, PathBuf};

use nalgebra::{Vector3, Vector4};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

mod source;

pub use source::scan_source;
use source::{render_cut_window, SourceRows};

use super::output::{write_truth, Truth, TruthTile};
use super::tiles::{draw_perturbation, rigid_about, Layout, TileSpec};
use super::SynthError;
use crate::geo::GeoTransform;
use crate::geotiff::reader::{GeoTiffInfo, GeoTiffReader};
use crate::geotiff::writer::{CogOptions, CogWriter};
use crate::rng::derive_seed;

/// How to cut: layout, tile size, overlap and the perturbation limits.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CutParams {
    pub layout: Layout,
    pub rows: u32,
    pub cols: u32,
    pub size_px: u32,
    /// Fraction of a tile's width shared with its neighbour (0.6 = 60 %).
    pub overlap: f64,
    /// Top-left source pixel (col, row) of tile_00's window; None: the layout
    /// centred on the source (truth.json records the resolved value).
    pub origin_px: Option<[i64; 2]>,
    pub seed: u64,
    pub max_shift_xy_m: f64,
    pub max_shift_z_m: f64,
    pub max_rot_deg: f64,
    /// Leave tile_00 unperturbed (identity matrix_world).
    pub anchor_first: bool,
}

impl Default for CutParams {
    fn default() -> Self {
        CutParams {
            layout: Layout::Chain,
            rows: 1,
            cols: 4,
            size_px: 256,
            overlap: 0.6,
            origin_px: None,
            seed: 1,
            max_shift_xy_m: 3.0,
            max_shift_z_m: 2.0,
            max_rot_deg: 0.02,
            anchor_first: false,
        }
    }
}

/// What was cut, as truth.json's `cut` records it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CutRecord {
    pub source: PathBuf,
    pub source_width: u64,
    pub source_height: u64,
    pub source_geotransform: [f64; 6],
    pub params: CutParams,
}

/// One tile of the cut: its written grid and perturbation, and the source
/// window (top-left source pixel, `size_px` square) it shows.
#[derive(Clone, Debug)]
pub struct CutTile {
    pub spec: TileSpec,
    pub window_px: [i64; 2],
}

/// What [`cut_collection`] wrote: the truth and each tile's valid fraction.
#[derive(Clone, Debug)]
pub struct CutReport {
    pub truth: Truth,
    pub valid_fraction: Vec<f64>,
}

/// Heights of the source and the valid pixels of each window (one pass).
#[derive(Clone, Debug, PartialEq)]
pub struct SourceScan {
    pub mean_m: f64,
    pub min_m: f64,
    pub max_m: f64,
    pub window_valid: Vec<u64>,
}

/// Check the parameters; one line saying what is wrong.
pub fn validate(p: &CutParams) -> Result<(), SynthError> {
    let bad = |m: String| Err(SynthError::BadParams(m));
    if p.rows == 0 || p.cols == 0 {
        return bad(format!("empty layout {} x {}", p.rows, p.cols));
    }
    if p.layout == Layout::Chain && p.rows != 1 {
        return bad(format!("a chain has one row, not {}", p.rows));
    }
    if p.size_px < 16 {
        return bad(format!("tile size {} px is below 16", p.size_px));
    }
    if !(0.0..0.95).contains(&p.overlap) {
        return bad(format!("overlap {} must be in [0, 0.95)", p.overlap));
    }
    let limits = [p.max_shift_xy_m, p.max_shift_z_m, p.max_rot_deg];
    if limits.iter().any(|v| !(*v >= 0.0 && v.is_finite())) {
        return bad("shifts and rotations must be finite and >= 0".to_string());
    }
    if p.max_rot_deg > 1.0 {
        return bad(format!(
            "rotation limit {} deg is above 1 deg (small rotations only)",
            p.max_rot_deg
        ));
    }
    Ok(())
}

/// Top-left source pixels of the tile windows, row-major.
pub fn layout_windows(p: &CutParams, source_width: u64, source_height: u64) -> Vec<[i64; 2]> {
    let size = p.size_px as i64;
    let step = ((size as f64) * (1.0 - p.overlap)).round().max(1.0) as i64;
    let origin = p.origin_px.unwrap_or_else(|| {
        let extent = |n: u32| size + (n as i64 - 1) * step;
        [
            (source_width as i64 - extent(p.cols)).div_euclid(2),
            (source_height as i64 - extent(p.rows)).div_euclid(2),
        ]
    });
    (0..p.rows as i64)
        .flat_map(|r| (0..p.cols as i64).map(move |c| (r, c)))
        .map(|(r, c)| [origin[0] + c * step, origin[1] + r * step])
        .collect()
}

/// The tiles with their perturbations drawn from the seed. `source_gt` must be
/// north-up; rotations pivot at `pivot_z_m`.
pub fn plan_cut(
    p: &CutParams,
    source_width: u64,
    source_height: u64,
    source_gt: &GeoTransform,
    pivot_z_m: f64,
) -> Vec<CutTile> {
    let (gsd_x, gsd_y) = (source_gt.gsd_x(), source_gt.gsd_y());
    let side = p.size_px as f64;
    layout_windows(p, source_width, source_height)
        .into_iter()
        .enumerate()
        .map(|(index, window_px)| {
            let (shift_m, rot_deg) = draw_perturbation(
                derive_seed(p.seed, 3000 + index as u64),
                [p.max_shift_xy_m, p.max_shift_z_m, p.max_rot_deg],
                p.anchor_first && index == 0,
            );
            let (wx, wy) = source_gt.pixel_to_world(window_px[0] as f64, window_px[1] as f64);
            let (ox, oy) = (wx - shift_m[0], wy - shift_m[1]);
            let centre = Vector3::new(ox + side * gsd_x / 2.0, oy - side * gsd_y / 2.0, pivot_z_m);
            let spec = TileSpec {
                id: format!("tile_{index:02}"),
                index,
                width: p.size_px as u64,
                height: p.size_px as u64,
                geotransform: GeoTransform::north_up(ox, oy, gsd_x, gsd_y),
                m_world: rigid_about(centre, shift_m, rot_deg),
                seed: derive_seed(p.seed, 4000 + index as u64),
                shift_m,
                rot_deg,
            };
            CutTile { spec, window_px }
        })
        .collect()
}

/// Cut `source` into `out_dir`: the tiles (in parallel) and `truth.json`.
pub fn cut_collection(
    source: &Path,
    params: &CutParams,
    out_dir: &Path,
    cog_tile_size: u32,
) -> Result<CutReport, SynthError> {
    validate(params)?;
    let mut reader = GeoTiffReader::open(source)?;
    let info = reader.info().clone();
    check_source(&info)?;
    let mut params = params.clone();
    params.origin_px = Some(layout_windows(&params, info.width, info.height)[0]);
    let windows = layout_windows(&params, info.width, info.height);
    let scan = scan_source(&mut reader, &windows, params.size_px as i64)?;
    drop(reader);
    let tiles = plan_cut(
        &params,
        info.width,
        info.height,
        &info.geotransform,
        scan.mean_m,
    );
    check_windows(source, &tiles, &scan.window_valid, params.size_px)?;
    std::fs::create_dir_all(out_dir).map_err(|source| SynthError::Io {
        path: out_dir.to_path_buf(),
        source,
    })?;
    let slack_m = params.max_shift_z_m + 1.0;
    let z_range = [scan.min_m - slack_m, scan.max_m + slack_m];
    tiles.par_iter().try_for_each(|tile| {
        let path = out_dir.join(format!("{}.tif", tile.spec.id));
        write_cut_tile(&info, tile, z_range, &path, cog_tile_size)
    })?;
    let pixels = (params.size_px as f64).powi(2);
    let truth = Truth {
        crs: info.crs.label(),
        gsd: info.geotransform.gsd_x(),
        layout: params.layout,
        seed: params.seed,
        generation: None,
        surface: None,
        cut: Some(CutRecord {
            source: source.to_path_buf(),
            source_width: info.width,
            source_height: info.height,
            source_geotransform: info.geotransform.0,
            params,
        }),
        pivot_z_m: Some(scan.mean_m),
        tiles: tiles
            .iter()
            .map(|t| TruthTile::from_spec(&t.spec))
            .collect(),
    };
    write_truth(&truth, out_dir)?;
    tracing::info!(tiles = tiles.len(), dir = %out_dir.display(), "cut written");
    let valid_fraction = scan
        .window_valid
        .iter()
        .map(|&v| v as f64 / pixels)
        .collect();
    Ok(CutReport {
        truth,
        valid_fraction,
    })
}

/// Every tile's window must hold a valid height.
fn check_windows(
    source: &Path,
    tiles: &[CutTile],
    window_valid: &[u64],
    size_px: u32,
) -> Result<(), SynthError> {
    match tiles.iter().zip(window_valid).find(|(_, v)| **v == 0) {
        Some((tile, _)) => Err(SynthError::BadSource(format!(
            "{}: the window of {} at source pixel {:?} ({size_px} px) holds no valid height",
            source.display(),
            tile.spec.id,
            tile.window_px,
        ))),
        None => Ok(()),
    }
}

/// A source must be north-up and in a metric CRS.
fn check_source(info: &GeoTiffInfo) -> Result<(), SynthError> {
    let path = info.path.display();
    if !info.geotransform.is_north_up() {
        return Err(SynthError::BadSource(format!(
            "{path}: not a north-up raster"
        )));
    }
    if info.crs.is_geographic {
        return Err(SynthError::BadSource(format!(
            "{path}: geographic CRS {} (degrees): shifts in metres need a projected CRS",
            info.crs.label()
        )));
    }
    Ok(())
}

/// Render one tile from the source rows it can reach and write it as a COG.
fn write_cut_tile(
    info: &GeoTiffInfo,
    tile: &CutTile,
    z_range_m: [f64; 2],
    path: &Path,
    cog_tile_size: u32,
) -> Result<(), SynthError> {
    let [r0, r1] = reachable_rows(info, &tile.spec, z_range_m);
    let mut reader = GeoTiffReader::open(&info.path)?;
    let source = SourceRows {
        geotransform: info.geotransform,
        width: info.width as i64,
        row0: r0 as i64,
        rows: (r1 - r0) as i64,
        data: reader.read_rows(r0, r1 - r0)?,
    };
    let options = CogOptions {
        tile_size: cog_tile_size,
        geotransform: tile.spec.geotransform,
        crs: info.crs.clone(),
        nodata: info.nodata.map_or(f32::NAN, |v| v as f32),
        overviews: true,
        ..Default::default()
    };
    let mut writer = CogWriter::create(path, tile.spec.width, tile.spec.height, options)?;
    let t = cog_tile_size as u64;
    for ty in 0..writer.tiles_y() {
        for tx in 0..writer.tiles_x() {
            let values = render_cut_window(&source, &tile.spec, tx * t, ty * t, t, t);
            writer.write_tile(tx, ty, &values)?;
        }
    }
    writer.finish()?;
    Ok(())
}

/// Source rows [r0, r1) that the written tile's pixels can map to, for
/// written heights in `z_range_m`: the box's 8 corners through M (affine, so
/// they bound it), two rows of margin, clipped to the source.
fn reachable_rows(info: &GeoTiffInfo, spec: &TileSpec, z_range_m: [f64; 2]) -> [u64; 2] {
    let b = spec.geotransform.bounds(spec.width, spec.height);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (x, y) in [(b[0], b[1]), (b[0], b[3]), (b[2], b[1]), (b[2], b[3])] {
        for z in z_range_m {
            let p = spec.m_world * Vector4::new(x, y, z, 1.0);
            let (_, row) = info.geotransform.world_to_pixel(p[0], p[1]);
            lo = lo.min(row);
            hi = hi.max(row);
        }
    }
    let clip = |r: f64| r.clamp(0.0, info.height as f64) as u64;
    [clip(lo.floor() - 2.0), clip(hi.ceil() + 2.0)]
}

#[cfg(test)]
mod tests;
