//! `fuse`: the registered mosaic. Every DSM is moved by its pose (poses.json),
//! sampled at the output pixel centres (see [`corrected`]) and combined per pixel
//! (median by default) into one Cloud-Optimized GeoTIFF.
//!
//! The output grid is the union of the corrected footprints at the finest input
//! cell (or `gsd_m`, reading the matching store overview). Tiles are rendered in
//! Morton order, a batch of `4 x threads` at a time on a rayon pool; each worker
//! reads through the shared chunk cache, and the compressed tiles go to the
//! [`CogWriter`] in that same order, so the file does not depend on the thread
//! count and memory is the cache budget plus a few tiles per thread.
//! `fuse_per_dsm` writes each corrected DSM alone on its own extent, on the
//! mosaic's cell and lattice. With `bounds`, every raster covers exactly that
//! box (snapped outward to the lattice); [`output`] says what each file holds
//! (sample type, no-data, band description and unit).

pub mod corrected;
pub mod layout;
pub mod limits;
pub mod output;
pub mod pose_set;
pub mod render;

use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;

use crate::cache::{CacheStats, ChunkCache};
use crate::geo::GeoTransform;
use crate::geotiff::writer::{CogWriter, GeoTiffWriteError};
use crate::poses::PosesError;
use crate::store::{Store, StoreError};
pub use corrected::{CorrectedSurface, PoseXf};
pub use layout::{OutputGrid, PlacedDsm};
pub use limits::MosaicTooLarge;
pub use pose_set::PoseSet;
use render::TileRenderer;

/// Output tile edge (the COG tile).
pub const TILE_SIZE: u32 = 256;

#[derive(Debug, thiserror::Error)]
pub enum FuseError {
    /// Bad input (poses that do not match the store, bad options): exit code 2.
    #[error("{0}")]
    Input(String),
    /// The poses file could not be read or parsed.
    #[error(transparent)]
    Poses(#[from] PosesError),
    /// The store could not be read (damaged metadata, missing or bad chunks).
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The poses imply a mosaic beyond the limits: refused before writing.
    #[error(transparent)]
    TooLarge(#[from] MosaicTooLarge),
    #[error(transparent)]
    Write(#[from] GeoTiffWriteError),
    #[error("{}: {action}: {source}", .path.display())]
    Io {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("thread pool: {0}")]
    ThreadPool(#[from] rayon::ThreadPoolBuildError),
}

impl FuseError {
    /// The user's input (options, poses, the store) is at fault: exit code 2.
    pub fn is_bad_input(&self) -> bool {
        match self {
            FuseError::Input(_) | FuseError::TooLarge(_) => true,
            FuseError::Poses(PosesError::Io { source, .. }) => matches!(
                source.kind(),
                std::io::ErrorKind::NotFound
                    | std::io::ErrorKind::PermissionDenied
                    | std::io::ErrorKind::IsADirectory
            ),
            FuseError::Poses(e) => e.is_bad_input(),
            FuseError::Store(e) => e.is_bad_input(),
            FuseError::Write(_) | FuseError::Io { .. } | FuseError::ThreadPool(_) => false,
        }
    }
}

/// How the corrected heights of overlapping DSMs become one value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FuseMethod {
    Median,
    Mean,
    Min,
    Max,
    /// Number of DSMs with a valid height (0 where none), written as a UInt16 band.
    Count,
    /// Largest minus smallest corrected height where two or more DSMs overlap
    /// (no-data elsewhere): where the registered DSMs still disagree.
    Spread,
}

/// What to fuse and how.
#[derive(Clone, Debug)]
pub struct FuseConfig {
    /// Output cell; None = the finest level-0 cell of the store.
    pub gsd_m: Option<f64>,
    pub method: FuseMethod,
    pub threads: usize,
    pub tile_size: u32,
    /// Output extent [xmin, ymin, xmax, ymax] in CRS units, snapped outward to
    /// the mosaic's lattice; None = the union of the corrected footprints
    /// (the mosaic) or the DSM's own corrected footprint (per-DSM outputs).
    pub bounds: Option<[f64; 4]>,
    /// No-data value of Float32 outputs (count outputs have none).
    pub nodata: f32,
}

impl Default for FuseConfig {
    fn default() -> Self {
        FuseConfig {
            gsd_m: None,
            method: FuseMethod::Median,
            threads: 1,
            tile_size: TILE_SIZE,
            bounds: None,
            nodata: f32::NAN,
        }
    }
}

/// One written raster.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FuseReport {
    pub path: PathBuf,
    pub width: u64,
    pub height: u64,
    pub geotransform: GeoTransform,
    pub gsd_m: f64,
    pub tiles: u64,
    pub dsms: usize,
    pub valid_pixels: u64,
    pub seconds: f64,
    pub cache: CacheStats,
}

/// Progress callback: (tiles done, tiles total) of the raster being written.
pub type Progress<'p> = &'p (dyn Fn(u64, u64) + Sync);

/// Fuse every DSM of the store into one COG at `out`.
pub fn fuse(
    store: &Store,
    cache: &ChunkCache,
    poses: &PoseSet,
    config: &FuseConfig,
    out: &Path,
    progress: Progress,
) -> Result<FuseReport, FuseError> {
    let all: Vec<usize> = (0..store.dsms().len()).collect();
    output::check_bounds_meet_data(store, poses, config)?;
    write_raster(
        store,
        cache,
        poses,
        config,
        Which {
            dsms: &all,
            lattice: &all,
            per_dsm: false,
        },
        out,
        progress,
    )
}

/// Write each corrected DSM alone as `<dir>/<id>.tif`, on its own corrected
/// footprint, at the mosaic's cell (or `gsd_m`) and on the mosaic's lattice.
/// Files written before an error are removed.
pub fn fuse_per_dsm(
    store: &Store,
    cache: &ChunkCache,
    poses: &PoseSet,
    config: &FuseConfig,
    dir: &Path,
    progress: Progress,
) -> Result<Vec<FuseReport>, FuseError> {
    output::check_bounds_meet_data(store, poses, config)?;
    std::fs::create_dir_all(dir).map_err(|source| FuseError::Io {
        path: dir.to_path_buf(),
        action: "creating folder",
        source,
    })?;
    let mut reports: Vec<FuseReport> = Vec::new();
    let all: Vec<usize> = (0..store.dsms().len()).collect();
    for (index, meta) in store.dsms().iter().enumerate() {
        let path = dir.join(format!("{}.tif", meta.id));
        match write_raster(
            store,
            cache,
            poses,
            config,
            Which {
                dsms: &[index],
                lattice: &all,
                per_dsm: true,
            },
            &path,
            progress,
        ) {
            Ok(r) => reports.push(r),
            Err(e) => {
                for r in &reports {
                    let _ = std::fs::remove_file(&r.path);
                }
                return Err(e);
            }
        }
    }
    Ok(reports)
}

/// The output grid of `dsms` after their poses (None when the list is empty).
pub fn plan_grid(
    store: &Store,
    poses: &PoseSet,
    dsms: &[usize],
    gsd_m: Option<f64>,
) -> Option<(OutputGrid, Vec<PlacedDsm>)> {
    plan_grid_on(store, poses, dsms, dsms, gsd_m)
}

/// The output grid covering `dsms`, its cell (unless `gsd_m`) and lattice those
/// of the finest DSM of `lattice`: per-DSM outputs on the mosaic's lattice
/// line up pixel for pixel with the mosaic and each other (as `gdalwarp -tap`).
pub fn plan_grid_on(
    store: &Store,
    poses: &PoseSet,
    dsms: &[usize],
    lattice: &[usize],
    gsd_m: Option<f64>,
) -> Option<(OutputGrid, Vec<PlacedDsm>)> {
    let placed: Vec<PlacedDsm> = dsms
        .iter()
        .map(|&i| PlacedDsm::new(i, &store.dsms()[i], &poses.poses[i]))
        .collect();
    let bounds = layout::union_bounds(placed.iter().map(|p| p.corrected_bounds))?;
    let (finest, anchor) = layout::finest_lattice(store, lattice)?;
    let grid = OutputGrid::covering(bounds, gsd_m.unwrap_or(finest), anchor);
    Some((grid, placed))
}

/// The DSMs a raster holds, and those whose finest cell sets its lattice.
#[derive(Clone, Copy)]
struct Which<'a> {
    dsms: &'a [usize],
    lattice: &'a [usize],
    /// One DSM's own file (its id goes in the metadata).
    per_dsm: bool,
}

fn write_raster(
    store: &Store,
    cache: &ChunkCache,
    poses: &PoseSet,
    config: &FuseConfig,
    which: Which<'_>,
    out: &Path,
    progress: Progress,
) -> Result<FuseReport, FuseError> {
    let Which {
        dsms,
        lattice,
        per_dsm,
    } = which;
    output::check_options(config)?;
    if let Some(g) = config.gsd_m {
        if !(g.is_finite() && g > 0.0) {
            return Err(FuseError::Input(format!(
                "--gsd {g} must be a positive number"
            )));
        }
    }
    let started = Instant::now();
    let (grid, placed) =
        plan_grid_on(store, poses, dsms, lattice, config.gsd_m).ok_or_else(|| {
            FuseError::Input(format!(
                "{}: the store holds no DSM",
                store.root().display()
            ))
        })?;
    let grid = output::extent(grid, config.bounds);
    limits::check_mosaic(store, poses, &placed, &grid, cache.budget_bytes())?;
    let removed = crate::atomic::remove_stale_siblings(out, &[".spill-", ".tmp-"]);
    if removed > 0 {
        tracing::warn!(path = %out.display(), removed, "temporaries of killed runs removed");
    }
    let crs = store.crs().cloned().unwrap_or_default();
    let content = output::RasterContent {
        method: config.method,
        dsm_id: per_dsm.then(|| store.dsms()[dsms[0]].id.as_str()),
    };
    let options = output::cog_options(config, &grid, crs, content);
    let mut writer = CogWriter::create(out, grid.width, grid.height, options)?;
    let renderer = TileRenderer::new(
        store,
        cache,
        &poses.poses,
        placed,
        grid,
        config.tile_size as usize,
        config.method,
    );
    let order = morton_order(writer.tiles_x(), writer.tiles_y());
    let total = order.len() as u64;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(config.threads.max(1))
        .build()?;
    let batch = 4 * config.threads.max(1);
    let (mut done, mut valid_pixels) = (0u64, 0u64);
    for tiles in order.chunks(batch) {
        let encoded = pool.install(|| {
            tiles
                .par_iter()
                .map(|&(tx, ty)| {
                    let tile = renderer.render(tx, ty)?;
                    let enc = writer.encode_tile(tx, ty, &tile.data)?;
                    Ok::<_, FuseError>((enc, tile.valid_pixels))
                })
                .collect::<Result<Vec<_>, _>>()
        })?;
        for (enc, valid) in encoded {
            writer.write_encoded(enc)?;
            valid_pixels += valid;
        }
        done += tiles.len() as u64;
        progress(done, total);
    }
    writer.finish()?;
    let report = FuseReport {
        path: out.to_path_buf(),
        width: grid.width,
        height: grid.height,
        geotransform: grid.geotransform,
        gsd_m: grid.gsd_m(),
        tiles: total,
        dsms: dsms.len(),
        valid_pixels,
        seconds: started.elapsed().as_secs_f64(),
        cache: cache.stats(),
    };
    tracing::info!(path = %out.display(), width = grid.width, height = grid.height,
        dsms = dsms.len(), seconds = report.seconds, "mosaic fused");
    Ok(report)
}

/// Tile coordinates of a tx x ty grid in Morton (Z-order) order, so consecutive
/// tiles share source chunks whatever the mosaic's width.
pub fn morton_order(tiles_x: u64, tiles_y: u64) -> Vec<(u64, u64)> {
    let mut order: Vec<(u64, u64)> = (0..tiles_y)
        .flat_map(|ty| (0..tiles_x).map(move |tx| (tx, ty)))
        .collect();
    order.sort_by_key(|&(tx, ty)| interleave(tx) | (interleave(ty) << 1));
    order
}

fn interleave(v: u64) -> u64 {
    let mut v = v & 0xffff_ffff;
    v = (v | (v << 16)) & 0x0000_ffff_0000_ffff;
    v = (v | (v << 8)) & 0x00ff_00ff_00ff_00ff;
    v = (v | (v << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
    v = (v | (v << 2)) & 0x3333_3333_3333_3333;
    (v | (v << 1)) & 0x5555_5555_5555_5555
}

#[cfg(test)]
mod tests;
