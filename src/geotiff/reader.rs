//! TEMPORARY SHIM on branch h-store only: the contract signatures of the
//! streaming GeoTIFF reader (helper "tiff" writes the real one), so the store
//! compiles before it lands. It reads nothing: `open` always fails. The lead
//! replaces this file with the real reader when merging.

use std::path::{Path, PathBuf};

use crate::raster::{Crs, GeoTransform};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    F32,
}

impl SampleType {
    /// GDAL's name for the type ("Float32", "Int16", ...).
    pub fn gdal_name(self) -> &'static str {
        "Float32"
    }
}

#[derive(Clone, Debug)]
pub struct GeoTiffInfo {
    pub path: PathBuf,
    pub width: u64,
    pub height: u64,
    pub sample_type: SampleType,
    pub compression: String,
    pub tiled: bool,
    pub block_width: u32,
    pub block_height: u32,
    pub bigtiff: bool,
    pub geotransform: GeoTransform,
    pub crs: Crs,
    pub nodata: Option<f64>,
}

#[derive(Debug, thiserror::Error)]
pub enum GeoTiffError {
    #[error("{0}: the GeoTIFF reader is not in this branch yet (shim)")]
    NotBuilt(PathBuf),
}

impl GeoTiffError {
    pub fn is_bad_input(&self) -> bool {
        false
    }
}

pub struct GeoTiffReader {
    info: GeoTiffInfo,
}

impl GeoTiffReader {
    pub fn open(path: &Path) -> Result<GeoTiffReader, GeoTiffError> {
        Err(GeoTiffError::NotBuilt(path.to_path_buf()))
    }

    pub fn info(&self) -> &GeoTiffInfo {
        &self.info
    }

    pub fn read_rows(&mut self, _row0: u64, _rows: u64) -> Result<Vec<f32>, GeoTiffError> {
        Err(GeoTiffError::NotBuilt(self.info.path.clone()))
    }
}
