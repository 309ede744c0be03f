//! Streaming GeoTIFF reader: opens a single-band elevation GeoTIFF (stripped or
//! tiled; none, LZW, Deflate, ZSTD, PackBits or LERC; predictors 2 and 3;
//! classic or BigTIFF; 8/16/32-bit integers or 32/64-bit floats), reports its
//! size, georeferencing and no-data as GDAL would, and hands out rows as `f32`
//! with no-data as NaN.
//!
//! `read_rows` decodes only the strips or tiles that touch the requested rows,
//! in parallel with rayon (one `tiff` decoder per worker, all reading one
//! memory map of the file), each block straight into the caller's rows.
//! Besides the output, memory is one block per worker plus one kept block row:
//! the block row a request covers only partly is kept, so reading a file top
//! to bottom in any row step decodes each block once. A file stored as one
//! giant strip is one block: it decodes in one call, and a partial read keeps
//! the whole image. Multi-band files give band 1. As GDAL reads them, GDAL's
//! internal mask band makes its masked pixels NaN, and band 1's scale and
//! offset (GDAL metadata) make the values `raw * scale + offset`. Georeferencing
//! beside the file (`.aux.xml`, a world file, `.prj`) is read as GDAL reads
//! it (`super::sidecar`).
//! Submodules: `layout` (tags to block grid and metadata), `decode` (blocks
//! to `f32`), `convert` (samples to `f32`), `direct` (Deflate f32 blocks,
//! predictor none or 3, decoded without the `tiff` crate: the fast ingest
//! path), `lerc` (LERC blocks), `mask` (the internal mask band).

mod convert;
mod decode;
mod direct;
mod layout;
mod lerc;
mod mask;
#[cfg(test)]
mod tests;

use std::fs::File;
use std::path::{Path, PathBuf};

use crate::geo::{Crs, GeoTransform};
use crate::geotiff::gdal_metadata::BandMetadata;
use crate::geotiff::geokeys::GeoKeyError;
use decode::{BlockDecoder, MapBytes, RowSink};

/// Every way opening or reading a GeoTIFF can fail. Display: one line naming the file.
#[derive(Debug, thiserror::Error)]
pub enum GeoTiffError {
    #[error("{}: cannot read file: {source}", .path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{}: not a TIFF file ({detail})", .path.display())]
    NotTiff { path: PathBuf, detail: String },
    #[error("{}: truncated file: {detail}", .path.display())]
    Truncated { path: PathBuf, detail: String },
    #[error("{}: corrupt TIFF: {detail}", .path.display())]
    Corrupt { path: PathBuf, detail: String },
    #[error("{}: unsupported compression {name} (TIFF code {code}); supported: none, LZW, Deflate, ZSTD, PackBits, LERC (alone, with Deflate or ZSTD)", .path.display())]
    UnsupportedCompression {
        path: PathBuf,
        name: String,
        code: u16,
    },
    #[error("{}: unsupported sample format: {detail}; supported: 8/16/32-bit integers, 32/64-bit floats", .path.display())]
    UnsupportedSampleFormat { path: PathBuf, detail: String },
    #[error("{}: unsupported image layout: {detail}", .path.display())]
    UnsupportedLayout { path: PathBuf, detail: String },
    #[error("{}: zero-size image ({width} x {height} pixels)", .path.display())]
    ZeroSize {
        path: PathBuf,
        width: u64,
        height: u64,
    },
    #[error("{}: no georeferencing (needs ModelPixelScale + ModelTiepoint or ModelTransformation, a world file such as .tfw, or a GeoTransform in its .aux.xml)", .path.display())]
    NoGeoreferencing { path: PathBuf },
    /// A side file (`.aux.xml`, world file, `.prj`) that cannot be read; `path` is the side file.
    #[error("{}: {detail}", .path.display())]
    Sidecar { path: PathBuf, detail: String },
    #[error("{}: geotransform {geotransform:?} is rotated, sheared or not north-up; only north-up rasters are supported", .path.display())]
    NotNorthUp {
        path: PathBuf,
        geotransform: [f64; 6],
    },
    #[error("{}: bad georeferencing tags: {detail}", .path.display())]
    BadGeoTags { path: PathBuf, detail: String },
    #[error("{}: needs {bytes} bytes of memory to decode, more than is available (corrupt size tags?)", .path.display())]
    TooLarge { path: PathBuf, bytes: u64 },
    #[error("{}: rows {row0}..{} requested but the raster has {height} rows", .path.display(), .row0 + .rows)]
    RowsOutOfRange {
        path: PathBuf,
        row0: u64,
        rows: u64,
        height: u64,
    },
}

impl GeoTiffError {
    /// True for every problem with the file itself (the CLI exits with code 2);
    /// false only for a caller's mistake (rows out of range).
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, GeoTiffError::RowsOutOfRange { .. })
    }

    pub(crate) fn from_geokeys(path: &Path, e: GeoKeyError) -> GeoTiffError {
        let path = path.to_path_buf();
        match e {
            GeoKeyError::NoGeoreferencing => GeoTiffError::NoGeoreferencing { path },
            GeoKeyError::NotNorthUp(geotransform) => {
                GeoTiffError::NotNorthUp { path, geotransform }
            }
            e @ GeoKeyError::Malformed { .. } => GeoTiffError::BadGeoTags {
                path,
                detail: e.to_string(),
            },
        }
    }
}

/// The stored sample type of band 1 (every type is handed out as `f32`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    /// IEEE half precision (GDAL writes it for Float32 with NBITS=16; GDAL
    /// 3.11 names it Float16).
    F16,
    F32,
    F64,
}

impl SampleType {
    pub fn bytes(self) -> usize {
        match self {
            SampleType::U8 | SampleType::I8 => 1,
            SampleType::U16 | SampleType::I16 | SampleType::F16 => 2,
            SampleType::U32 | SampleType::I32 | SampleType::F32 => 4,
            SampleType::F64 => 8,
        }
    }

    /// GDAL's name for the type ("Float32", "Int16", ...).
    pub fn gdal_name(self) -> &'static str {
        match self {
            SampleType::U8 => "Byte",
            SampleType::I8 => "Int8",
            SampleType::U16 => "UInt16",
            SampleType::I16 => "Int16",
            SampleType::U32 => "UInt32",
            SampleType::I32 => "Int32",
            SampleType::F16 => "Float16",
            SampleType::F32 => "Float32",
            SampleType::F64 => "Float64",
        }
    }
}

/// What the file is: size, layout, georeferencing, no-data.
#[derive(Clone, Debug, PartialEq)]
pub struct GeoTiffInfo {
    pub path: PathBuf,
    pub width: u64,
    pub height: u64,
    pub sample_type: SampleType,
    /// "none", "lzw", "deflate", "zstd", "packbits", "lerc", "lerc_deflate"
    /// or "lerc_zstd" (GDAL's names).
    pub compression: String,
    pub tiled: bool,
    /// Tile size, or (width, rows per strip) for a stripped file.
    pub block_width: u32,
    pub block_height: u32,
    pub bigtiff: bool,
    /// Pixel-is-area, as GDAL reports it (pixel-is-point files are shifted by half a pixel).
    pub geotransform: GeoTransform,
    pub crs: Crs,
    /// GDAL_NODATA as stored (NaN when the file says "nan").
    pub nodata: Option<f64>,
    /// Samples per pixel in the file; only band 1 is read.
    pub band_count: u16,
    /// TIFF predictor: 1 none, 2 horizontal, 3 floating point.
    pub predictor: u16,
    /// The raster type geokey said pixel-is-point.
    pub pixel_is_point: bool,
    /// Band 1's scale, offset and unit from GDAL's metadata: values read are
    /// `raw * scale + offset` (no-data matched on the raw values first).
    pub band: BandMetadata,
    /// The file has GDAL's internal mask band (a transparency-mask IFD):
    /// pixels it masks are read as NaN.
    pub internal_mask: bool,
    /// The side files whose georeferencing was taken (`.aux.xml`, a world
    /// file, `.prj`); empty when the file's own tags say it all.
    pub georeferenced_by: Vec<PathBuf>,
}

/// One open GeoTIFF. `Send`, not meant to be shared: each worker opens its own.
pub struct GeoTiffReader {
    info: GeoTiffInfo,
    blocks: BlockDecoder,
    /// GDAL's internal mask band, when the file has one.
    mask: Option<mask::MaskBand>,
    /// The last block row decoded for a request that covered only part of it.
    kept: KeptBlockRow,
}

/// One decoded block row (`width * block_height` values, image-row-major).
struct KeptBlockRow {
    block_row: Option<u64>,
    values: Vec<f32>,
}

impl GeoTiffReader {
    /// Open and validate the file; reads tags only, no pixel data.
    pub fn open(path: &Path) -> Result<GeoTiffReader, GeoTiffError> {
        let io = |source| GeoTiffError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = File::open(path).map_err(io)?;
        let file_len = file.metadata().map_err(io)?.len();
        if file_len < 8 {
            return Err(GeoTiffError::NotTiff {
                path: path.to_path_buf(),
                detail: format!("only {file_len} bytes"),
            });
        }
        // SAFETY: the map is read-only; like GDAL, we assume nobody truncates the
        // file while it is open (that would be a SIGBUS, not a wrong answer).
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(io)?;
        let map = MapBytes::new(map);
        layout::check_magic(path, map.as_ref())?;
        let mut decoder = decode::new_decoder(&map).map_err(|e| decode::tiff_error(path, e))?;
        let bigtiff = map.as_ref()[2..4] == [43, 0] || map.as_ref()[2..4] == [0, 43];
        let little_endian = &map.as_ref()[..2] == b"II";
        let mut parsed = layout::parse(path, &mut decoder, file_len, bigtiff, little_endian)?;
        let mask = mask::MaskBand::find(path, &map, parsed.info.width, parsed.info.height)?;
        parsed.info.internal_mask = mask.is_some();
        let blocks = BlockDecoder::new(path, map, parsed.layout, parsed.info.nodata, decoder);
        tracing::debug!(path = %path.display(), width = parsed.info.width, height = parsed.info.height,
            compression = %parsed.info.compression, "geotiff opened");
        Ok(GeoTiffReader {
            info: parsed.info,
            blocks,
            mask,
            kept: KeptBlockRow {
                block_row: None,
                values: Vec::new(),
            },
        })
    }

    pub fn info(&self) -> &GeoTiffInfo {
        &self.info
    }

    /// Rows `row0 .. row0 + rows`, row-major, `width * rows` values; no-data and
    /// NaN are NaN. Decodes only the blocks touching those rows.
    pub fn read_rows(&mut self, row0: u64, rows: u64) -> Result<Vec<f32>, GeoTiffError> {
        let mut out = Vec::new();
        self.read_rows_into(row0, rows, &mut out)?;
        Ok(out)
    }

    /// As [`read_rows`](Self::read_rows), into `out` (resized to `width * rows`),
    /// so a caller streaming a large file can reuse one buffer.
    pub fn read_rows_into(
        &mut self,
        row0: u64,
        rows: u64,
        out: &mut Vec<f32>,
    ) -> Result<(), GeoTiffError> {
        let (width, height) = (self.info.width, self.info.height);
        let end = row0
            .checked_add(rows)
            .filter(|&e| e <= height)
            .ok_or_else(|| GeoTiffError::RowsOutOfRange {
                path: self.info.path.clone(),
                row0,
                rows,
                height,
            })?;
        let len = usize::try_from(width.saturating_mul(rows)).unwrap_or(usize::MAX);
        decode::try_resize(&self.info.path, out, len, 0.0)?;
        if rows == 0 {
            return Ok(());
        }
        let layout = self.blocks.layout();
        let block_height = layout.block_height;
        let (first, last) = (row0 / block_height, (end - 1) / block_height);
        let whole =
            |r: u64| r * block_height >= row0 && ((r + 1) * block_height).min(height) <= end;
        // Block rows only partly requested go through the kept block row (the
        // trailing one stays kept for the next request); whole ones decode
        // straight into `out`.
        let mut full_first = first;
        if !whole(first) {
            self.copy_from_kept(first, row0, end, out)?;
            full_first = first + 1;
        }
        let mut full_last = last;
        if last >= full_first && !whole(last) {
            self.copy_from_kept(last, row0, end, out)?;
            full_last = last - 1;
        }
        if full_first <= full_last {
            let sink = RowSink::new(out, width as usize, row0);
            self.blocks
                .decode_block_rows(full_first..=full_last, &sink)?;
        }
        if let Some(mask) = self.mask.as_mut() {
            mask.apply(row0, out)?;
        }
        if self.info.band.rescales() {
            let (scale, offset) = (self.info.band.scale, self.info.band.offset);
            for v in out.iter_mut().filter(|v| !v.is_nan()) {
                *v = (f64::from(*v) * scale + offset) as f32;
            }
        }
        Ok(())
    }

    /// Copy rows `row0..end` of block row `r` into `out`, decoding it unless kept.
    fn copy_from_kept(
        &mut self,
        r: u64,
        row0: u64,
        end: u64,
        out: &mut [f32],
    ) -> Result<(), GeoTiffError> {
        let layout = self.blocks.layout();
        let (width, top) = (layout.width as usize, r * layout.block_height);
        let bottom = (top + layout.block_height).min(layout.height);
        if self.kept.block_row != Some(r) {
            self.kept.block_row = None;
            let len = width.saturating_mul((bottom - top) as usize);
            decode::try_resize(&self.info.path, &mut self.kept.values, len, 0.0)?;
            let sink = RowSink::new(&mut self.kept.values, width, top);
            self.blocks.decode_block_rows(r..=r, &sink)?;
            self.kept.block_row = Some(r);
        }
        let (y0, y1) = (top.max(row0), bottom.min(end));
        let src = &self.kept.values[(y0 - top) as usize * width..(y1 - top) as usize * width];
        out[(y0 - row0) as usize * width..(y1 - row0) as usize * width].copy_from_slice(src);
        Ok(())
    }
}
