//! Streaming writer of one DSM's multiscale arrays: level 0 and its 2x
//! overviews are built in a single top-to-bottom pass.
//!
//! Rows of level 0 arrive a block at a time. Each level buffers at most one
//! chunk row of its own pixels; when a chunk row is complete it is written
//! (whole chunks, one rayon task per chunk: zarrs loses data when two partial
//! writes hit one chunk) and handed down at once, averaged 2x2 (valid pixels
//! only, NaN when none) into the next level. An odd row waits in `carry` for
//! its partner. A chunk row that arrives whole is written from the caller's
//! slice without a copy. Memory: the caller's rows plus, per level below, one
//! chunk row and one averaged input block (about 1.5x level 0's chunk row in all).
//! Chunks without a valid pixel have no file (Zarr's fill value); the writer
//! records them ([`ChunkRecord`](super::ChunkRecord)) so a missing file can be
//! told from an empty chunk.

use std::sync::Arc;

use rayon::prelude::*;
use zarrs::array::{codec::ZstdCodec, data_type, ArrayBuilder};
use zarrs::filesystem::FilesystemStore;

use super::catalog::{Compression, LevelMeta, StorageSettings};
use super::chunks::EmptyChunks;
use super::mean2x2::downsample_rows;
use super::{validate, LevelArray, StoreError};

/// Level shapes: level 0, then halved (rounding up) while the long side of the
/// previous level is above `min_overview_px`; each level's chunk side is
/// [`level_chunk`] of its size.
pub fn level_shapes(width: u64, height: u64, settings: &StorageSettings) -> Vec<LevelMeta> {
    let level = |width: u64, height: u64| LevelMeta {
        width,
        height,
        chunk: level_chunk(settings.chunk, width, height),
    };
    let mut levels = vec![level(width, height)];
    let (mut w, mut h) = (width, height);
    while w.max(h) > settings.min_overview_px.max(1) {
        w = w.div_ceil(2);
        h = h.div_ceil(2);
        levels.push(level(w, h));
    }
    levels
}

/// The chunk side of a `width` x `height` level: the requested side, or, on a
/// level smaller than that, its long side rounded up to a power of two (when
/// that adds at most a quarter) or else to a multiple of 16, at least 16. A
/// 64 px DSM is then one 64 px chunk (16 KiB decoded) instead of a 512 px one
/// (1 MiB) that every reader decodes and caches.
pub fn level_chunk(requested: u64, width: u64, height: u64) -> u64 {
    let side = width.max(height).max(1);
    if side >= requested {
        return requested;
    }
    let power_of_two = side.next_power_of_two();
    let rounded = if 4 * power_of_two <= 5 * side {
        power_of_two
    } else {
        side.div_ceil(16) * 16
    };
    rounded.max(validate::CHUNK_RANGE_PX.0).min(requested)
}

/// The `c` x `c` chunk whose first column is `col0` of `rows` (whole rows of
/// `width`, at most `c` of them), row-major, padded with NaN right and below.
/// Each value is written once (no NaN prefill of the whole chunk).
fn chunk_of(rows: &[f32], width: usize, col0: usize, c: usize) -> Vec<f32> {
    let cols = c.min(width - col0);
    let mut data = Vec::with_capacity(c * c);
    for row in rows.chunks_exact(width) {
        data.extend_from_slice(&row[col0..col0 + cols]);
        data.resize(data.len() + c - cols, f32::NAN);
    }
    data.resize(c * c, f32::NAN);
    data
}

struct LevelWriter {
    array: LevelArray,
    /// The level's directory, for errors that name the file.
    dir: std::path::PathBuf,
    width: usize,
    height: u64,
    chunk: usize,
    /// Pending rows of this level (fewer than `chunk` rows between calls;
    /// stays empty when the rows arrive a whole chunk row at a time).
    buf: Vec<f32>,
    /// Reused output of the 2x2 averaging into this level.
    scratch: Vec<f32>,
    /// Chunk rows written so far.
    chunk_rows_written: u64,
    rows_written: u64,
    /// An input row (of the level above) waiting for its 2x2 partner.
    carry: Option<Vec<f32>>,
    /// Chunks written without a valid pixel (Zarr stores no file for them).
    empty: EmptyChunks,
}

impl LevelWriter {
    /// Write `rows` (whole rows, at most `chunk` of them) as chunk row
    /// `chunk_rows_written`, whole chunks in parallel.
    fn write_rows(&mut self, rows: &[f32]) -> Result<(), StoreError> {
        let (w, c) = (self.width, self.chunk);
        let n_rows = rows.len() / w;
        let cy = self.chunk_rows_written;
        let (array, dir) = (&self.array, &self.dir);
        let chunks_x = w.div_ceil(c);
        let empty: Vec<Option<u64>> = (0..chunks_x)
            .into_par_iter()
            .map(|cx| {
                let data = chunk_of(rows, w, cx * c, c);
                // Zarr leaves out chunks equal to the fill value, bit for bit.
                let nan = f32::NAN.to_bits();
                let is_empty = data.iter().all(|v| v.to_bits() == nan);
                // A slice, not the Vec: zarrs copies a `Vec<f32>` into a new
                // `Vec<u8>` (their alignments differ) but borrows a slice's bytes.
                array
                    .store_chunk(&[cy, cx as u64], &data[..])
                    .map_err(|e| StoreError::zarr(dir.join(format!("c/{cy}/{cx}")).display(), e))?;
                Ok(is_empty.then_some(cy * chunks_x as u64 + cx as u64))
            })
            .collect::<Result<_, StoreError>>()?;
        for index in empty.into_iter().flatten() {
            self.empty.add(index);
        }
        self.chunk_rows_written += 1;
        self.rows_written += n_rows as u64;
        Ok(())
    }

    /// 2x2-average rows of the level above (width `2*width` or `2*width-1`)
    /// into `out` (cleared first), keeping an odd last row in `carry`.
    fn downsample_input(&mut self, rows_above: &[f32], width_above: usize, out: &mut Vec<f32>) {
        out.clear();
        let mut rows = rows_above.chunks_exact(width_above);
        if let Some(first) = self.carry.take() {
            match rows.next() {
                Some(second) => downsample_rows(&first, Some(second), out),
                None => {
                    self.carry = Some(first);
                    return;
                }
            }
        }
        loop {
            match (rows.next(), rows.next()) {
                (Some(a), Some(b)) => downsample_rows(a, Some(b), out),
                (Some(a), None) => {
                    self.carry = Some(a.to_vec());
                    break;
                }
                _ => break,
            }
        }
    }
}

/// Feed whole rows into `levels[0]`: every completed chunk row is written and
/// handed down (2x2-averaged) to the levels below before the next one is taken.
/// A chunk row that arrives whole is written straight from `rows`, uncopied.
fn push(levels: &mut [LevelWriter], rows: &[f32]) -> Result<(), StoreError> {
    let Some((level, below)) = levels.split_first_mut() else {
        return Ok(());
    };
    let width = level.width;
    let chunk_len = level.chunk * width;
    let mut rest = rows;
    while !rest.is_empty() {
        if level.buf.is_empty() && rest.len() >= chunk_len {
            let (whole, tail) = rest.split_at(chunk_len);
            level.write_rows(whole)?;
            cascade(below, whole, width)?;
            rest = tail;
            continue;
        }
        let take = (chunk_len - level.buf.len()).min(rest.len());
        level.buf.extend_from_slice(&rest[..take]);
        rest = &rest[take..];
        if level.buf.len() == chunk_len {
            flush_buffer(level, below)?;
        }
    }
    Ok(())
}

/// Write the buffered rows of `level` (a full or, at the end, partial chunk
/// row) and hand them down.
fn flush_buffer(level: &mut LevelWriter, below: &mut [LevelWriter]) -> Result<(), StoreError> {
    if level.buf.is_empty() {
        return Ok(());
    }
    let mut buf = std::mem::take(&mut level.buf);
    let result = level
        .write_rows(&buf)
        .and_then(|()| cascade(below, &buf, level.width));
    buf.clear();
    level.buf = buf;
    result
}

/// Average `rows` (of width `width_above`) into `below[0]` and push them on.
fn cascade(below: &mut [LevelWriter], rows: &[f32], width_above: usize) -> Result<(), StoreError> {
    let Some(next) = below.first_mut() else {
        return Ok(());
    };
    let mut down = std::mem::take(&mut next.scratch);
    next.downsample_input(rows, width_above, &mut down);
    let result = push(below, &down);
    below[0].scratch = down;
    result
}

/// All levels of one DSM being written.
pub struct PyramidWriter {
    levels: Vec<LevelWriter>,
}

impl PyramidWriter {
    /// Create (and store the metadata of, with `level_attributes(k)` as the
    /// attributes of level k) every level array in the group
    /// directory `group_dir` of the store (like `<store>/tile_01.tmp-123`).
    pub fn create(
        fs: Arc<FilesystemStore>,
        group_dir: &std::path::Path,
        shapes: &[LevelMeta],
        settings: &StorageSettings,
        level_attributes: &dyn Fn(usize) -> serde_json::Map<String, serde_json::Value>,
    ) -> Result<PyramidWriter, StoreError> {
        super::configure_zarrs();
        let group = group_dir.file_name().unwrap_or_default().to_string_lossy();
        let mut levels = Vec::with_capacity(shapes.len());
        for (k, shape) in shapes.iter().enumerate() {
            let node = format!("/{group}/{k}");
            let dir = group_dir.join(k.to_string());
            let mut builder = ArrayBuilder::new(
                vec![shape.height, shape.width],
                vec![shape.chunk, shape.chunk],
                data_type::float32(),
                f32::NAN,
            );
            builder.dimension_names(Some(["y", "x"]));
            builder.attributes(level_attributes(k));
            if let Compression::Zstd { level } = settings.compression {
                builder.bytes_to_bytes_codecs(vec![Arc::new(ZstdCodec::new(level, false))]);
            }
            let array = builder
                .build(fs.clone(), &node)
                .map_err(|e| StoreError::zarr(dir.display(), e))?;
            array
                .store_metadata()
                .map_err(|e| StoreError::zarr(dir.join("zarr.json").display(), e))?;
            levels.push(LevelWriter {
                array,
                dir,
                width: shape.width as usize,
                height: shape.height,
                chunk: shape.chunk as usize,
                buf: Vec::new(),
                scratch: Vec::new(),
                chunk_rows_written: 0,
                rows_written: 0,
                carry: None,
                empty: EmptyChunks::default(),
            });
        }
        Ok(PyramidWriter { levels })
    }

    /// Feed rows of level 0, in order (any number of whole rows per call;
    /// a whole chunk row per call avoids copying).
    pub fn push_rows(&mut self, rows: &[f32]) -> Result<(), StoreError> {
        push(&mut self.levels, rows)
    }

    /// Write the remaining partial chunk rows, top level first, and check that
    /// every level received exactly its height. Returns, per level, the runs
    /// of empty chunks (see [`ChunkRecord`](super::ChunkRecord)).
    pub fn finish(mut self) -> Result<Vec<Vec<[u64; 2]>>, StoreError> {
        for k in 0..self.levels.len() {
            let from_k = &mut self.levels[k..];
            if let Some(row) = from_k[0].carry.take() {
                let mut out = Vec::new();
                downsample_rows(&row, None, &mut out);
                push(from_k, &out)?;
            }
            let (level, below) = from_k.split_first_mut().expect("k < len");
            flush_buffer(level, below)?;
        }
        for level in &self.levels {
            if level.rows_written != level.height {
                return Err(StoreError::zarr(
                    level.dir.display(),
                    format!(
                        "wrote {} rows, expected {}",
                        level.rows_written, level.height
                    ),
                ));
            }
        }
        Ok(self
            .levels
            .into_iter()
            .map(|l| l.empty.into_runs())
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_halve_down_to_the_overview_floor() {
        let s = StorageSettings {
            chunk: 64,
            min_overview_px: 256,
            ..Default::default()
        };
        let dims: Vec<_> = level_shapes(1000, 300, &s)
            .iter()
            .map(|l| (l.width, l.height))
            .collect();
        assert_eq!(dims, vec![(1000, 300), (500, 150), (250, 75)]);
        assert_eq!(level_shapes(256, 10, &s).len(), 1);
        assert_eq!(level_shapes(257, 10, &s)[1].width, 129);
    }

    #[test]
    fn small_levels_get_chunks_of_their_size() {
        let s = StorageSettings::default();
        let chunks =
            |w, h| -> Vec<u64> { level_shapes(w, h, &s).iter().map(|l| l.chunk).collect() };
        assert_eq!(chunks(64, 64), vec![64]);
        assert_eq!(chunks(128, 100), vec![128, 64]);
        assert_eq!(chunks(1000, 300), vec![512, 512, 256, 128, 64]);
        // 300 px: a power of two would add 70 %, a multiple of 16 adds 1 %
        assert_eq!(level_chunk(512, 300, 20), 304);
        assert_eq!(level_chunk(512, 5, 3), 16);
        assert_eq!(
            level_chunk(48, 40, 40),
            48,
            "never above the requested side"
        );
        assert_eq!(level_chunk(512, 4096, 10), 512);
    }

    #[test]
    fn chunks_are_cut_from_rows_and_padded_with_nan() {
        // 3 rows of 5, chunk side 4: chunk 0 = cols 0..4, chunk 1 = col 4 + padding
        let rows: Vec<f32> = (0..15).map(|v| v as f32).collect();
        let c0 = chunk_of(&rows, 5, 0, 4);
        assert_eq!(
            &c0[..12],
            &[0., 1., 2., 3., 5., 6., 7., 8., 10., 11., 12., 13.]
        );
        assert!(c0[12..].iter().all(|v| v.is_nan()));
        let c1 = chunk_of(&rows, 5, 4, 4);
        assert_eq!((c1.len(), c1[0], c1[4], c1[8]), (16, 4.0, 9.0, 14.0));
        let valid = [0, 4, 8];
        assert!((0..16)
            .filter(|i| !valid.contains(i))
            .all(|i| c1[i].is_nan()));
    }
}
