//! Tiled Cloud-Optimized GeoTIFF writer for float32 DSMs (or a UInt16 band of
//! counts), in bounded memory.
//!
//! Tiles arrive in any order through [`CogWriter::write_tile`]; each is
//! compressed at once (Deflate + floating-point predictor 3, or horizontal
//! predictor 2 for UInt16) and appended to a
//! spill file next to the output. [`CogWriter::finish`] builds the 2x overviews
//! by reading back four tiles of the level above per overview tile, then writes
//! the COG to `<path>.tmp-<pid>` and renames it: header with GDAL's ghost area,
//! every IFD (full resolution, then overviews), then tile data from the smallest
//! overview to full resolution, row-major, each tile framed as GDAL's COG driver
//! does (size before, last 4 bytes repeated after). Classic TIFF, or BigTIFF when the file would pass
//! 4 GiB. Nothing holds the whole image: memory is a row of compressed tiles plus
//! four decoded tiles per thread. Temporary files are removed on error and when
//! an unfinished writer is dropped; `path` is only ever replaced whole.

mod assemble;
mod ifd;
mod metadata;
mod tile;

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::geo::{Crs, GeoTransform};
use assemble::{build_overview, write_cog, Level, SpillRef};
pub use metadata::GdalMetadata;

/// The stored sample type of the band (values are handed in as `f32` either way).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum CogSample {
    /// Heights: NaN is no-data, stored as `nodata` and tagged GDAL_NODATA.
    #[default]
    Float32,
    /// Counts: values rounded and clamped to 0..=65535; NaN and edge padding
    /// are stored as 0 and no GDAL_NODATA is written (0 is a real count).
    UInt16,
}

/// How to write the COG. For Float32, `nodata` is written as GDAL_NODATA and
/// NaN input pixels (and edge padding) are stored as `nodata`.
#[derive(Clone, Debug)]
pub struct CogOptions {
    /// Tile edge in pixels, a multiple of 16.
    pub tile_size: u32,
    pub geotransform: GeoTransform,
    pub crs: Crs,
    pub nodata: f32,
    /// Build 2x overviews until the image fits in one tile.
    pub overviews: bool,
    pub sample: CogSample,
    /// Band description, unit and dataset items (GDAL_METADATA tag).
    pub metadata: GdalMetadata,
}

impl Default for CogOptions {
    fn default() -> Self {
        CogOptions {
            tile_size: 256,
            geotransform: GeoTransform::north_up(0.0, 0.0, 1.0, 1.0),
            crs: Crs::default(),
            nodata: f32::NAN,
            overviews: true,
            sample: CogSample::Float32,
            metadata: GdalMetadata::default(),
        }
    }
}

/// Errors of the writer; each displays as one line naming the file.
#[derive(Debug, thiserror::Error)]
pub enum GeoTiffWriteError {
    #[error("{path}: {message}")]
    InvalidOptions { path: PathBuf, message: String },
    #[error("{path}: tile ({tx}, {ty}): {message}")]
    BadTile {
        path: PathBuf,
        tx: u64,
        ty: u64,
        message: String,
    },
    #[error("{path}: {missing} of {total} tiles were never written")]
    MissingTiles {
        path: PathBuf,
        missing: u64,
        total: u64,
    },
    #[error("{path}: {action}: {source}")]
    Io {
        path: PathBuf,
        action: &'static str,
        source: std::io::Error,
    },
}

/// A tile already compressed by [`CogWriter::encode_tile`] (can run on many threads).
pub struct EncodedTile {
    tx: u64,
    ty: u64,
    bytes: Vec<u8>,
}

/// Files removed when dropped (the spill file, the temporary output).
struct TempFiles(Vec<PathBuf>);

impl Drop for TempFiles {
    fn drop(&mut self) {
        for p in &self.0 {
            let _ = std::fs::remove_file(p);
        }
    }
}

static SPILL_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Streaming COG writer: `create`, `write_tile` for every tile, `finish`.
pub struct CogWriter {
    path: PathBuf,
    width: u64,
    height: u64,
    options: CogOptions,
    tiles_x: u64,
    tiles_y: u64,
    spill_path: PathBuf,
    spill: BufWriter<File>,
    spill_len: u64,
    level0: Vec<Option<SpillRef>>,
    written: u64,
    force_bigtiff: bool,
    temp: TempFiles,
}

fn sibling(path: &Path, suffix: &str) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(suffix);
    PathBuf::from(s)
}

impl CogWriter {
    /// Start a `width` x `height` COG at `path`; creates the spill file beside it.
    pub fn create(
        path: &Path,
        width: u64,
        height: u64,
        options: CogOptions,
    ) -> Result<CogWriter, GeoTiffWriteError> {
        let invalid = |message: String| GeoTiffWriteError::InvalidOptions {
            path: path.to_path_buf(),
            message,
        };
        let t = options.tile_size;
        if !(16..=4096).contains(&t) || !t.is_multiple_of(16) {
            return Err(invalid(format!(
                "tile size {t} must be a multiple of 16 in 16..=4096"
            )));
        }
        if width == 0 || height == 0 || width > u32::MAX as u64 || height > u32::MAX as u64 {
            return Err(invalid(format!(
                "image size {width} x {height} is not writable"
            )));
        }
        let g = &options.geotransform.0;
        if g.iter().any(|v| !v.is_finite()) || g[1] * g[5] - g[2] * g[4] == 0.0 {
            return Err(invalid(format!("degenerate geotransform {g:?}")));
        }
        let tiles_x = width.div_ceil(t as u64);
        let tiles_y = height.div_ceil(t as u64);
        let n = SPILL_COUNTER.fetch_add(1, Ordering::Relaxed);
        let spill_path = sibling(path, &format!(".spill-{}-{n}", std::process::id()));
        let file = File::options()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&spill_path)
            .map_err(|source| GeoTiffWriteError::Io {
                path: spill_path.clone(),
                action: "creating spill file",
                source,
            })?;
        Ok(CogWriter {
            path: path.to_path_buf(),
            width,
            height,
            tiles_x,
            tiles_y,
            temp: TempFiles(vec![spill_path.clone()]),
            spill_path,
            spill: BufWriter::with_capacity(1 << 20, file),
            spill_len: 0,
            level0: vec![None; (tiles_x * tiles_y) as usize],
            written: 0,
            force_bigtiff: false,
            options,
        })
    }

    /// Tiles per row of the full-resolution image.
    pub fn tiles_x(&self) -> u64 {
        self.tiles_x
    }

    /// Tile rows of the full-resolution image.
    pub fn tiles_y(&self) -> u64 {
        self.tiles_y
    }

    pub fn tile_size(&self) -> u32 {
        self.options.tile_size
    }

    /// Write BigTIFF even when the file would fit in classic TIFF (tests, tools).
    pub fn force_bigtiff(&mut self) {
        self.force_bigtiff = true;
    }

    /// Compress tile (tx, ty) without touching the writer's state, so several
    /// threads can encode at once; pass the result to [`CogWriter::write_encoded`].
    pub fn encode_tile(
        &self,
        tx: u64,
        ty: u64,
        data: &[f32],
    ) -> Result<EncodedTile, GeoTiffWriteError> {
        let t = self.options.tile_size as u64;
        let bad = |message: String| GeoTiffWriteError::BadTile {
            path: self.path.clone(),
            tx,
            ty,
            message,
        };
        if tx >= self.tiles_x || ty >= self.tiles_y {
            return Err(bad(format!(
                "outside the {} x {} tile grid",
                self.tiles_x, self.tiles_y
            )));
        }
        if data.len() as u64 != t * t {
            return Err(bad(format!(
                "{} values given, expected {}",
                data.len(),
                t * t
            )));
        }
        let valid_w = (self.width - tx * t).min(t) as usize;
        let valid_h = (self.height - ty * t).min(t) as usize;
        let valid = tile::Valid {
            width: valid_w,
            height: valid_h,
        };
        let bytes = tile::encode_tile(data, t as usize, valid, &self.options)
            .map_err(|e| bad(format!("compression failed: {e}")))?;
        Ok(EncodedTile { tx, ty, bytes })
    }

    /// Append an encoded tile to the spill file; each tile exactly once.
    pub fn write_encoded(&mut self, tile: EncodedTile) -> Result<(), GeoTiffWriteError> {
        let index = (tile.ty * self.tiles_x + tile.tx) as usize;
        if self.level0[index].is_some() {
            return Err(GeoTiffWriteError::BadTile {
                path: self.path.clone(),
                tx: tile.tx,
                ty: tile.ty,
                message: "written twice".to_string(),
            });
        }
        self.spill
            .write_all(&tile.bytes)
            .map_err(|source| GeoTiffWriteError::Io {
                path: self.spill_path.clone(),
                action: "writing spill file",
                source,
            })?;
        let len = tile.bytes.len() as u64;
        self.level0[index] = Some(SpillRef {
            offset: self.spill_len,
            len,
        });
        self.spill_len += len;
        self.written += 1;
        Ok(())
    }

    /// Compress and store tile (tx, ty): `tile_size`² values, row-major, NaN = no-data;
    /// values past the image edge are ignored (stored as no-data).
    pub fn write_tile(&mut self, tx: u64, ty: u64, data: &[f32]) -> Result<(), GeoTiffWriteError> {
        let tile = self.encode_tile(tx, ty, data)?;
        self.write_encoded(tile)
    }

    /// Build the overviews and write the COG to `path` (through a temporary name).
    pub fn finish(mut self) -> Result<(), GeoTiffWriteError> {
        let total = self.tiles_x * self.tiles_y;
        if self.written != total {
            return Err(GeoTiffWriteError::MissingTiles {
                path: self.path.clone(),
                missing: total - self.written,
                total,
            });
        }
        let spill_io = |source| GeoTiffWriteError::Io {
            path: self.spill_path.clone(),
            action: "writing spill file",
            source,
        };
        self.spill.flush().map_err(spill_io)?;
        let spill = self.spill.get_ref();
        let mut levels = vec![self.full_resolution_level()];
        let t = self.options.tile_size as u64;
        while self.options.overviews {
            let last = levels.last().expect("level 0 exists");
            if last.width <= t && last.height <= t {
                break;
            }
            let level = build_overview(spill, last, &mut self.spill_len, &self.options)
                .map_err(spill_io)?;
            levels.push(level);
        }
        let tmp_path = sibling(&self.path, &format!(".tmp-{}", std::process::id()));
        self.temp.0.push(tmp_path.clone());
        let bytes = write_cog(&tmp_path, spill, &levels, &self.options, self.force_bigtiff)
            .map_err(|source| GeoTiffWriteError::Io {
                path: tmp_path.clone(),
                action: "writing",
                source,
            })?;
        std::fs::rename(&tmp_path, &self.path).map_err(|source| GeoTiffWriteError::Io {
            path: self.path.clone(),
            action: "renaming temporary file into place",
            source,
        })?;
        // as GDAL's Create: the PAM sidecar of the file replaced would
        // override the new file's georeferencing and no-data when read
        let pam = PathBuf::from(format!("{}.aux.xml", self.path.display()));
        if pam.is_file() {
            std::fs::remove_file(&pam).map_err(|source| GeoTiffWriteError::Io {
                path: pam.clone(),
                action: "removing the replaced file's side file",
                source,
            })?;
            tracing::warn!(path = %pam.display(), "stale side file removed");
        }
        tracing::info!(
            path = %self.path.display(),
            width = self.width,
            height = self.height,
            overviews = levels.len() - 1,
            bytes,
            "cog written"
        );
        Ok(())
    }

    fn full_resolution_level(&self) -> Level {
        let refs: Vec<SpillRef> = self
            .level0
            .iter()
            .map(|r| r.expect("all written"))
            .collect();
        Level {
            width: self.width,
            height: self.height,
            tiles_x: self.tiles_x,
            tiles_y: self.tiles_y,
            refs,
        }
    }
}

/// Write a small in-memory raster (`width * height` values, row-major) as a COG
/// through [`CogWriter`].
pub fn write_geotiff_f32(
    path: &Path,
    width: u64,
    height: u64,
    options: CogOptions,
    data: &[f32],
) -> Result<(), GeoTiffWriteError> {
    if data.len() as u64 != width * height {
        return Err(GeoTiffWriteError::InvalidOptions {
            path: path.to_path_buf(),
            message: format!("{} values given for {width} x {height}", data.len()),
        });
    }
    let mut writer = CogWriter::create(path, width, height, options)?;
    let t = writer.tile_size() as u64;
    let mut buf = vec![f32::NAN; (t * t) as usize];
    for ty in 0..writer.tiles_y() {
        for tx in 0..writer.tiles_x() {
            buf.fill(f32::NAN);
            let (x0, y0) = (tx * t, ty * t);
            let w = (width - x0).min(t) as usize;
            for r in 0..(height - y0).min(t) {
                let src = ((y0 + r) * width + x0) as usize;
                buf[(r * t) as usize..][..w].copy_from_slice(&data[src..src + w]);
            }
            writer.write_tile(tx, ty, &buf)?;
        }
    }
    writer.finish()
}

#[cfg(test)]
mod tests;
