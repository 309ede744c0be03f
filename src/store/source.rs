//! Where ingest reads rasters from: the [`RowSource`] seam, its GeoTIFF
//! implementation (the streaming reader of `crate::geotiff::reader`) and an
//! in-memory one for tests and tools.
//!
//! A source describes itself once ([`SourceRaster`]) and hands out block rows
//! as f32, NaN for no-data, so ingest never holds more than a chunk row.

use std::path::{Path, PathBuf};

use crate::geo::{Crs, GeoTransform};
use crate::geotiff::reader::GeoTiffReader;

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
    /// The unit GDAL's band metadata names for the heights ("m", "ft"...).
    pub height_unit: Option<String>,
    /// The side files its georeferencing was read from (world file,
    /// `.aux.xml`, `.prj`); empty when the file's tags say it all.
    pub georeferenced_by: Vec<PathBuf>,
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

    /// As [`read_rows`](Self::read_rows), into `out` (replaced), so a caller
    /// streaming a large raster can reuse one buffer.
    fn read_rows_into(
        &mut self,
        row0: u64,
        rows: u64,
        out: &mut Vec<f32>,
    ) -> Result<(), SourceError> {
        *out = self.read_rows(row0, rows)?;
        Ok(())
    }

    /// What this source was before it was put into a UTM zone, if it was
    /// ([`super::warp::WarpSource`]).
    fn warped(&self) -> Option<super::warp::Warped> {
        None
    }
}

/// Opens a source from a path (the GeoTIFF opener, or a test double).
pub type SourceOpener<'a> = dyn Fn(&Path) -> Result<Box<dyn RowSource>, SourceError> + 'a;

/// Bytes of decoded rows after which a [`GeoTiffSource`] maps its file afresh.
const REMAP_DECODED_BYTES: u64 = 64 << 20;

/// A GeoTIFF read through the crate's streaming reader.
///
/// The reader memory-maps the file, and every page it has touched counts in
/// the process's resident set until the map is dropped: streaming a 1 GB file
/// top to bottom would end with 1 GB "resident" (clean page cache, but it is
/// what RSS and the OOM accounting see). So the source opens the file again
/// (a new map; tags only, a few milliseconds) after about
/// [`REMAP_DECODED_BYTES`] of rows; at worst the block row straddling the
/// request boundary is decoded twice. The kernel's page cache keeps the data.
pub struct GeoTiffSource {
    reader: GeoTiffReader,
    raster: SourceRaster,
    /// Rows read since the file was last (re)opened.
    rows_since_open: u64,
    remap_rows: u64,
}

fn source_error(e: crate::geotiff::reader::GeoTiffError) -> SourceError {
    SourceError {
        message: e.to_string(),
        bad_input: e.is_bad_input(),
    }
}

impl GeoTiffSource {
    pub fn open(path: &Path) -> Result<GeoTiffSource, SourceError> {
        let reader = GeoTiffReader::open(path).map_err(source_error)?;
        let info = reader.info();
        let row_bytes = (info.width * 4).max(1);
        let remap_rows = (REMAP_DECODED_BYTES / row_bytes).max(1);
        let raster = SourceRaster {
            path: path.to_path_buf(),
            width: info.width,
            height: info.height,
            geotransform: info.geotransform,
            crs: info.crs.clone(),
            nodata: info.nodata,
            dtype: info.sample_type.gdal_name().to_string(),
            height_unit: info.band.unit.clone(),
            georeferenced_by: info.georeferenced_by.clone(),
        };
        Ok(GeoTiffSource {
            reader,
            raster,
            rows_since_open: 0,
            remap_rows,
        })
    }

    /// Re-open (re-map) the file when enough rows were read since the last open.
    fn remap_if_due(&mut self, row0: u64) -> Result<(), SourceError> {
        if self.rows_since_open >= self.remap_rows {
            self.reader = GeoTiffReader::open(&self.raster.path).map_err(source_error)?;
            self.rows_since_open = 0;
            tracing::trace!(path = %self.raster.path.display(), row0, "geotiff remapped");
        }
        Ok(())
    }
}

impl RowSource for GeoTiffSource {
    fn raster(&self) -> &SourceRaster {
        &self.raster
    }

    fn read_rows(&mut self, row0: u64, rows: u64) -> Result<Vec<f32>, SourceError> {
        let mut out = Vec::new();
        self.read_rows_into(row0, rows, &mut out)?;
        Ok(out)
    }

    fn read_rows_into(
        &mut self,
        row0: u64,
        rows: u64,
        out: &mut Vec<f32>,
    ) -> Result<(), SourceError> {
        self.remap_if_due(row0)?;
        self.reader
            .read_rows_into(row0, rows, out)
            .map_err(source_error)?;
        self.rows_since_open += rows;
        Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Reading through a source that re-maps its file every block row gives
    /// the same rows as one reader, for strips and tiles and any band height.
    #[test]
    fn remapped_reads_equal_one_reader() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/geotiff");
        for name in ["f32_strip_deflate.tif", "f32_tile_deflate.tif"] {
            let path = dir.join(name);
            let mut reader = GeoTiffReader::open(&path).unwrap();
            let height = reader.info().height;
            let whole = reader.read_rows(0, height).unwrap();
            for band in [1, 5, 7, 16, 45] {
                let mut source = GeoTiffSource::open(&path).unwrap();
                source.remap_rows = 1;
                let (mut row0, mut got, mut buf, mut remaps) = (0, Vec::new(), Vec::new(), 0);
                while row0 < height {
                    let rows = band.min(height - row0);
                    let before = source.rows_since_open;
                    source.read_rows_into(row0, rows, &mut buf).unwrap();
                    remaps += usize::from(source.rows_since_open < before + rows);
                    got.extend_from_slice(&buf);
                    row0 += rows;
                }
                assert_eq!(got.len(), whole.len());
                let same = got
                    .iter()
                    .zip(&whole)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{name}, bands of {band} rows");
                if band < height {
                    assert!(remaps > 0, "{name}, bands of {band} rows: not re-mapped");
                }
            }
        }
    }
}
