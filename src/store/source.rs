//! Where ingest reads rasters from: the [`RowSource`] seam, its GeoTIFF
//! implementation (the streaming reader of `crate::geotiff::reader`) and an
//! in-memory one for tests and tools.
//!
//! A source describes itself once ([`SourceRaster`]) and hands out block rows
//! as f32, NaN for no-data, so ingest never holds more than a chunk row.

use std::path::{Path, PathBuf};

use crate::geotiff::reader::GeoTiffReader;
use crate::raster::{Crs, GeoTransform};

/// What ingest needs to know about a raster before reading it.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceRaster {
    pub path: PathBuf,
    pub width: u64,
    pub height: u64,
    pub geotransform: GeoTransform,
    pub crs: Crs,
    /// Declared no-data value (already mapped to NaN by `read_rows`).
    pub nodata: Option<f64>,
    /// Sample type of the file, GDAL names: "Float32", "Int16", ...
    pub dtype: String,
}

/// A failure to open or read a source; the message names the file.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct SourceError {
    pub message: String,
    /// True when the file itself is the problem (exit code 2), false for I/O trouble.
    pub bad_input: bool,
}

/// A raster read top to bottom, a block of rows at a time.
pub trait RowSource: Send {
    fn raster(&self) -> &SourceRaster;
    /// Rows `row0 .. row0 + rows`, row-major (`width * rows` values), NaN for no-data.
    fn read_rows(&mut self, row0: u64, rows: u64) -> Result<Vec<f32>, SourceError>;
}

/// Opens a source from a path (the GeoTIFF opener, or a test double).
pub type SourceOpener<'a> = dyn Fn(&Path) -> Result<Box<dyn RowSource>, SourceError> + 'a;

/// A GeoTIFF read through the crate's streaming reader.
pub struct GeoTiffSource {
    reader: GeoTiffReader,
    raster: SourceRaster,
}

impl GeoTiffSource {
    pub fn open(path: &Path) -> Result<GeoTiffSource, SourceError> {
        let reader = GeoTiffReader::open(path).map_err(|e| SourceError {
            message: e.to_string(),
            bad_input: e.is_bad_input(),
        })?;
        let info = reader.info();
        let raster = SourceRaster {
            path: path.to_path_buf(),
            width: info.width,
            height: info.height,
            geotransform: info.geotransform,
            crs: info.crs.clone(),
            nodata: info.nodata,
            dtype: info.sample_type.gdal_name().to_string(),
        };
        Ok(GeoTiffSource { reader, raster })
    }
}

impl RowSource for GeoTiffSource {
    fn raster(&self) -> &SourceRaster {
        &self.raster
    }

    fn read_rows(&mut self, row0: u64, rows: u64) -> Result<Vec<f32>, SourceError> {
        self.reader.read_rows(row0, rows).map_err(|e| SourceError {
            message: e.to_string(),
            bad_input: e.is_bad_input(),
        })
    }
}

/// The default opener: every input is a GeoTIFF.
pub fn open_geotiff(path: &Path) -> Result<Box<dyn RowSource>, SourceError> {
    Ok(Box::new(GeoTiffSource::open(path)?))
}

/// A raster held in memory (tests, generated data).
#[derive(Clone, Debug)]
pub struct MemSource {
    pub raster: SourceRaster,
    /// Row-major, `width * height` values, NaN for no-data.
    pub data: Vec<f32>,
}

impl RowSource for MemSource {
    fn raster(&self) -> &SourceRaster {
        &self.raster
    }

    fn read_rows(&mut self, row0: u64, rows: u64) -> Result<Vec<f32>, SourceError> {
        let w = self.raster.width as usize;
        let end = row0 + rows;
        if end > self.raster.height {
            return Err(SourceError {
                message: format!(
                    "{}: rows {row0}..{end} past the height {}",
                    self.raster.path.display(),
                    self.raster.height
                ),
                bad_input: false,
            });
        }
        Ok(self.data[row0 as usize * w..end as usize * w].to_vec())
    }
}
