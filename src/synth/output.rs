//! Files the generator writes: rendered rasters as COGs (tile by tile, bounded
//! memory), whole tile sets with their `truth.json`, and the noise-free truth
//! grid over a bounding box for evaluating fuse.

use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::surface::{Surface, SurfaceParams};
use super::tiles::{plan_tiles, render_window, PixelEffects, TileSetParams, TileSpec};
use super::SynthError;
use crate::geo::{Crs, GeoTransform};
use crate::geotiff::writer::{CogOptions, CogWriter};

/// The expected answer for a tile set (truth.json). A synthetic set (`dsmgen
/// tiles`) carries `generation` and `surface`, from which the true surface can
/// be rendered; a set cut from a real DSM (`dsmgen cut`) carries `cut` instead
/// (the source DSM is then the true surface).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Truth {
    pub crs: String,
    pub gsd: f64,
    pub layout: super::tiles::Layout,
    pub seed: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generation: Option<TileSetParams>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub surface: Option<SurfaceParams>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cut: Option<super::cut::CutRecord>,
    /// Height of the rotation pivots, and of the test points of
    /// [`Truth::pairwise_error`]; absent: 200 m (the synthetic base elevation).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pivot_z_m: Option<f64>,
    pub tiles: Vec<TruthTile>,
}

/// One tile of truth.json. `matrix_world` (row-major 4x4) maps a point of the
/// written tile (x, y, height in CRS units) to its true position; it is what
/// `dsmstream align` must output for this tile (up to the gauge).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TruthTile {
    pub id: String,
    pub file: String,
    pub matrix_world: [[f64; 4]; 4],
    pub width: u64,
    pub height: u64,
    pub geotransform: [f64; 6],
    pub shift_m: [f64; 3],
    pub rot_deg: [f64; 3],
}

impl TruthTile {
    pub fn from_spec(s: &TileSpec) -> TruthTile {
        TruthTile {
            id: s.id.clone(),
            file: format!("{}.tif", s.id),
            matrix_world: std::array::from_fn(|r| std::array::from_fn(|c| s.m_world[(r, c)])),
            width: s.width,
            height: s.height,
            geotransform: s.geotransform.0,
            shift_m: s.shift_m,
            rot_deg: s.rot_deg,
        }
    }
}

impl Truth {
    pub fn load(path: &Path) -> Result<Truth, SynthError> {
        let text = std::fs::read_to_string(path).map_err(|source| SynthError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        serde_json::from_str(&text).map_err(|e| SynthError::BadTruth {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }

    /// The synthetic generator's parameters; None for a set cut from a real DSM.
    pub fn synthetic(&self) -> Option<(&TileSetParams, &SurfaceParams)> {
        self.generation.as_ref().zip(self.surface.as_ref())
    }

    /// Union of the written tiles' footprints [min_x, min_y, max_x, max_y].
    pub fn bbox(&self) -> [f64; 4] {
        let mut b = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
        for t in &self.tiles {
            let tb = GeoTransform(t.geotransform).bounds(t.width, t.height);
            b = [
                b[0].min(tb[0]),
                b[1].min(tb[1]),
                b[2].max(tb[2]),
                b[3].max(tb[3]),
            ];
        }
        b
    }
}

pub fn epsg_crs(epsg: u32) -> Crs {
    Crs {
        epsg: Some(epsg),
        ..Default::default()
    }
}

/// Render `spec` into a COG at `path`, one row of COG tiles at a time (tiles of
/// a row rendered and compressed in parallel). `on_row(done, total)` reports progress.
pub fn write_raster(
    surface: &Surface,
    spec: &TileSpec,
    fx: &PixelEffects,
    crs: &Crs,
    path: &Path,
    cog_tile_size: u32,
    on_row: &(dyn Fn(u64, u64) + Sync),
) -> Result<(), SynthError> {
    let options = CogOptions {
        tile_size: cog_tile_size,
        geotransform: spec.geotransform,
        crs: crs.clone(),
        nodata: f32::NAN,
        overviews: true,
        ..Default::default()
    };
    let mut writer = CogWriter::create(path, spec.width, spec.height, options)?;
    let t = cog_tile_size as u64;
    for ty in 0..writer.tiles_y() {
        let row = (0..writer.tiles_x())
            .into_par_iter()
            .map(|tx| {
                let values = render_window(surface, spec, fx, tx * t, ty * t, t, t);
                writer.encode_tile(tx, ty, &values)
            })
            .collect::<Result<Vec<_>, _>>()?;
        for tile in row {
            writer.write_encoded(tile)?;
        }
        on_row(ty + 1, writer.tiles_y());
    }
    writer.finish()?;
    Ok(())
}

/// Check a tile set's parameters; one line saying what is wrong.
pub fn validate(p: &TileSetParams) -> Result<(), SynthError> {
    let bad = |m: String| Err(SynthError::BadParams(m));
    if p.rows == 0 || p.cols == 0 {
        return bad(format!("empty layout {} x {}", p.rows, p.cols));
    }
    if p.size_px < 16 {
        return bad(format!("tile size {} px is below 16", p.size_px));
    }
    if !(p.gsd_m > 0.0 && p.gsd_m.is_finite()) {
        return bad(format!("gsd {} m must be positive", p.gsd_m));
    }
    let factor = p.odd_gsd_factor;
    if factor == 0 || !p.size_px.is_multiple_of(factor) || p.size_px / factor < 16 {
        return bad(format!(
            "odd tiles' pixel factor {factor} must divide the tile size {} px and leave 16 px",
            p.size_px
        ));
    }
    if !(0.0..0.95).contains(&p.overlap) {
        return bad(format!("overlap {} must be in [0, 0.95)", p.overlap));
    }
    let limits = [
        p.noise_sigma_m,
        p.max_shift_xy_m,
        p.max_shift_z_m,
        p.max_rot_deg,
    ];
    if limits.iter().any(|v| !(*v >= 0.0 && v.is_finite())) {
        return bad("noise, shifts and rotations must be finite and >= 0".to_string());
    }
    if !(0.0..=1.0).contains(&p.outlier_fraction) || !(0.0..=1.0).contains(&p.void_fraction) {
        return bad("outlier and void fractions must be in [0, 1]".to_string());
    }
    Ok(())
}

/// Write every tile of the set into `out_dir` (in parallel) and `truth.json`.
pub fn write_tile_set(
    params: &TileSetParams,
    surface_params: &SurfaceParams,
    out_dir: &Path,
    cog_tile_size: u32,
) -> Result<Truth, SynthError> {
    validate(params)?;
    std::fs::create_dir_all(out_dir).map_err(|source| SynthError::Io {
        path: out_dir.to_path_buf(),
        source,
    })?;
    let surface = Surface::new(*surface_params);
    let specs = plan_tiles(params, surface_params.base_elevation_m);
    let fx = PixelEffects::from_params(params);
    let crs = epsg_crs(params.epsg);
    specs.par_iter().try_for_each(|spec| {
        let path = out_dir.join(format!("{}.tif", spec.id));
        write_raster(&surface, spec, &fx, &crs, &path, cog_tile_size, &|_, _| {})
    })?;
    let truth = Truth {
        crs: crs.label(),
        gsd: params.gsd_m,
        layout: params.layout,
        seed: params.seed,
        generation: Some(params.clone()),
        surface: Some(*surface_params),
        cut: None,
        pivot_z_m: None,
        tiles: specs.iter().map(TruthTile::from_spec).collect(),
    };
    write_truth(&truth, out_dir)?;
    tracing::info!(tiles = specs.len(), dir = %out_dir.display(), "tile set written");
    Ok(truth)
}

/// Write `out_dir/truth.json` (pretty JSON) through a temporary name.
pub fn write_truth(truth: &Truth, out_dir: &Path) -> Result<(), SynthError> {
    let path: PathBuf = out_dir.join("truth.json");
    let text = serde_json::to_string_pretty(truth).expect("truth serialises") + "\n";
    crate::atomic::write_bytes_atomically(&path, text.as_bytes())
        .map_err(|source| SynthError::Io { path, source })
}

/// The noise-free, change-free, unperturbed surface over `bbox` at `gsd_m`
/// (pixel grid anchored at the bbox's top-left corner); NaN on lakes.
pub fn write_truth_grid(
    surface_params: &SurfaceParams,
    bbox: [f64; 4],
    gsd_m: f64,
    crs: &Crs,
    path: &Path,
) -> Result<(), SynthError> {
    let width = ((bbox[2] - bbox[0]) / gsd_m).round() as u64;
    let height = ((bbox[3] - bbox[1]) / gsd_m).round() as u64;
    if width == 0 || height == 0 || gsd_m <= 0.0 {
        return Err(SynthError::BadParams(format!(
            "empty truth grid: bbox {bbox:?} at {gsd_m} m"
        )));
    }
    let gt = GeoTransform::north_up(bbox[0], bbox[3], gsd_m, gsd_m);
    let spec = TileSpec::unperturbed("truth", width, height, gt, 0);
    let surface = Surface::new(*surface_params);
    write_raster(
        &surface,
        &spec,
        &PixelEffects::none(),
        crs,
        path,
        256,
        &|_, _| {},
    )
}
