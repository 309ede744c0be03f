//! Synthetic DSMs with a known answer, deterministic by seed: a city-like
//! [`Surface`] evaluated point by point (terrain, buildings, trees, lakes,
//! changed buildings), a tile cutter that perturbs every tile by a known rigid
//! motion and adds noise, outliers and voids, and the writers of tile sets,
//! `truth.json` and truth grids; and `cut`, the same known-answer collections
//! cut from a real DSM. `tools/dsmgen/main.rs` is the command line over it.
//!
//! Parts: `crate::rng` (SplitMix64 and coordinate hashes) → `objects` (per-cell
//! buildings and trees) → `surface` (the height function) → `tiles` (layout,
//! perturbation, pixel-centre rendering) and `render` (gridding from scattered
//! points: lidar max/mean, IDW, TIN, smoothed) → `output` (COGs and truth.json); `cut` (a real
//! GeoTIFF through the same frames into COGs and truth.json); `points` (a lidar
//! point cloud gridded into a DSM, to register real DSMs against).

pub mod calibration;
pub mod cut;
pub mod objects;
pub mod output;
pub mod points;
pub mod render;
pub mod score;
pub mod surface;
pub mod tiles;

use std::path::PathBuf;

pub use cut::{cut_collection, CutParams, CutRecord, CutReport};
pub use output::{
    epsg_crs, write_raster, write_tile_set, write_truth, write_truth_grid, Truth, TruthTile,
};
pub use render::Rendering;
pub use score::{PairwiseError, PerDsmError};
pub use surface::{Sampler, Surface, SurfaceParams};
pub use tiles::{
    plan_tiles, render_window, rigid_about, solve_written_height, written_height, Layout,
    PixelEffects, TileSetParams, TileSpec,
};

/// Errors of the generator; each displays as one line.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    #[error("invalid generator parameters: {0}")]
    BadParams(String),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A source DSM that cannot be cut as asked (the message names the file).
    #[error("{0}")]
    BadSource(String),
    #[error("{path}: not a valid truth.json: {message}")]
    BadTruth { path: PathBuf, message: String },
    #[error(transparent)]
    Write(#[from] crate::geotiff::writer::GeoTiffWriteError),
    /// The source DSM of a cut could not be read.
    #[error(transparent)]
    Read(#[from] crate::geotiff::reader::GeoTiffError),
}

impl SynthError {
    /// A problem with the parameters or an input file (exit code 2).
    pub fn is_bad_input(&self) -> bool {
        match self {
            SynthError::BadParams(_) | SynthError::BadSource(_) | SynthError::BadTruth { .. } => {
                true
            }
            SynthError::Read(e) => e.is_bad_input(),
            _ => false,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tile set written to disk reads back as the rendered tiles, and its
    /// truth.json round-trips.
    #[test]
    fn tile_set_writes_tiles_and_truth() {
        let dir = tempfile::tempdir().unwrap();
        let params = TileSetParams {
            size_px: 64,
            cols: 2,
            ..Default::default()
        };
        let surface_params = SurfaceParams {
            seed: 9,
            ..Default::default()
        };
        let truth = write_tile_set(&params, &surface_params, dir.path(), 32).unwrap();
        assert_eq!(truth.tiles.len(), 2);
        let loaded = Truth::load(&dir.path().join("truth.json")).unwrap();
        assert_eq!(loaded.tiles[1].matrix_world, truth.tiles[1].matrix_world);
        assert_eq!(loaded.crs, "EPSG:32617");

        let specs = plan_tiles(&params, surface_params.base_elevation_m);
        let expected = render_window(
            &Surface::new(surface_params),
            &specs[1],
            &PixelEffects::from_params(&params),
            0,
            0,
            64,
            64,
        );
        let file = std::fs::File::open(dir.path().join("tile_01.tif")).unwrap();
        let mut d = tiff::decoder::Decoder::new(file).unwrap();
        let tiff::decoder::DecodingResult::F32(v) = d.read_image().unwrap() else {
            panic!("f32 expected")
        };
        assert!(v
            .iter()
            .zip(&expected)
            .all(|(a, b)| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())));

        let bad = TileSetParams {
            overlap: 1.5,
            ..params
        };
        let err = write_tile_set(&bad, &surface_params, dir.path(), 32).unwrap_err();
        assert!(err.to_string().contains("overlap"));
    }
}
