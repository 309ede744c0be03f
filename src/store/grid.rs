//! [`StoreGrid`]: pixel access to one level of one stored DSM, the
//! [`Grid`](crate::grid::Grid) the algorithms read.
//!
//! Each worker owns its own `StoreGrid`. It pins the few chunks it used last
//! (most recent first; the hot path of the nearest-neighbour search is a
//! lookup in the last-used chunk) and fetches the others through the shared
//! [`ChunkCache`], which decodes misses with zarrs. Pixels outside the raster
//! are NaN. A chunk the DSM's [`ChunkRecord`] lists as empty is NaN without
//! touching the disk; any other chunk must have a file. A chunk that is
//! missing or fails to load reads as NaN and the error is kept for
//! [`StoreGrid::take_chunk_error`] (and, as a [`GridError`], [`Grid::take_error`]).

use std::path::PathBuf;
use std::sync::Arc;

use super::chunks::{chunk_grid, ChunkRecord};
use super::{LevelArray, Store, StoreError};
use crate::cache::{Chunk, ChunkCache, ChunkKey};
use crate::geo::GeoTransform;
use crate::grid::{Grid, GridError};

/// How many chunks a grid keeps pinned.
pub const PINNED_CHUNKS: usize = 8;

/// A chunk of the store that could not be read: the store is damaged (a bad
/// input, exit code 2), and `dsmstream check` says which DSM to re-ingest.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ChunkReadError {
    /// The record says the chunk holds data but its file is gone.
    #[error("{}: missing chunk file (the DSM's chunk record says it holds data; run dsmstream check)", .file.display())]
    Missing { file: PathBuf },
    /// The file is there but does not decode to a chunk.
    #[error("{}: unreadable chunk ({message})", .file.display())]
    Unreadable { file: PathBuf, message: String },
}

struct Pinned {
    chunk_y: i64,
    chunk_x: i64,
    chunk: Arc<Chunk>,
}

pub struct StoreGrid<'a> {
    cache: &'a ChunkCache,
    array: Arc<LevelArray>,
    dsm: u32,
    level: u8,
    width: i64,
    height: i64,
    chunk: i64,
    /// log2(chunk) when the chunk side is a power of two.
    chunk_shift: Option<u32>,
    geotransform: GeoTransform,
    /// Most recently used first.
    pinned: Vec<Pinned>,
    error: Option<ChunkReadError>,
    /// `<store>/<id>/<level>`, for errors that name the chunk's file.
    array_dir: PathBuf,
    /// Which chunks are empty (None: an old store, a missing file reads as no-data).
    record: Option<Arc<ChunkRecord>>,
    chunks_x: u64,
}

impl<'a> StoreGrid<'a> {
    /// A view of level `level` of DSM number `dsm` (cheap: the array is opened once per store).
    pub fn new(
        store: &Store,
        cache: &'a ChunkCache,
        dsm: usize,
        level: usize,
    ) -> Result<StoreGrid<'a>, StoreError> {
        let array = store.array(dsm, level)?;
        let meta = &store.dsms()[dsm];
        let lm = meta.levels[level];
        let chunk = lm.chunk as i64;
        let record = store.chunk_record(dsm).cloned();
        Ok(StoreGrid {
            cache,
            array,
            dsm: dsm as u32,
            level: level as u8,
            width: lm.width as i64,
            height: lm.height as i64,
            chunk,
            chunk_shift: (chunk as u64)
                .is_power_of_two()
                .then(|| chunk.trailing_zeros()),
            geotransform: meta.level_geotransform(level),
            pinned: Vec::with_capacity(PINNED_CHUNKS),
            error: None,
            array_dir: store.root().join(&meta.id).join(level.to_string()),
            record,
            chunks_x: chunk_grid(&lm).0,
        })
    }

    #[inline]
    fn chunk_of(&self, col: i64, row: i64) -> (i64, i64) {
        match self.chunk_shift {
            Some(s) => (row >> s, col >> s),
            None => (row / self.chunk, col / self.chunk),
        }
    }

    /// The chunk (chunk_y, chunk_x), moved to the front of the pinned set.
    #[inline(never)]
    fn fetch(&mut self, chunk_y: i64, chunk_x: i64) -> &Chunk {
        let hit = self
            .pinned
            .iter()
            .position(|p| p.chunk_y == chunk_y && p.chunk_x == chunk_x);
        match hit {
            Some(i) => self.pinned[..=i].rotate_right(1),
            None => {
                let chunk = self.load(chunk_y, chunk_x);
                if self.pinned.len() == PINNED_CHUNKS {
                    self.pinned.pop();
                }
                self.pinned.insert(
                    0,
                    Pinned {
                        chunk_y,
                        chunk_x,
                        chunk,
                    },
                );
            }
        }
        &self.pinned[0].chunk
    }

    fn load(&mut self, chunk_y: i64, chunk_x: i64) -> Arc<Chunk> {
        let key = ChunkKey {
            dsm: self.dsm,
            level: self.level,
            chunk_y: chunk_y as u32,
            chunk_x: chunk_x as u32,
        };
        let side = self.chunk as usize;
        let (cy, cx) = (chunk_y as u64, chunk_x as u64);
        let file = self.array_dir.join(format!("c/{chunk_y}/{chunk_x}"));
        let record = self.record.as_deref();
        let recorded_empty =
            record.is_some_and(|r| r.is_empty(self.level as usize, self.chunks_x, cy, cx));
        let (array, cache) = (&self.array, self.cache);
        let loaded = self.cache.get_or_load(key, || {
            if recorded_empty {
                let data = vec![f32::NAN; side * side];
                return Ok(Chunk {
                    width: side,
                    height: side,
                    data: cache.chunk_data(data),
                });
            }
            if record.is_some() && !file.is_file() {
                return Err(ChunkReadError::Missing { file: file.clone() });
            }
            let unreadable = |message: String| ChunkReadError::Unreadable {
                file: file.clone(),
                message,
            };
            let data: Vec<f32> = array
                .retrieve_chunk(&[cy, cx])
                .map_err(|e| unreadable(e.to_string()))?;
            if data.len() != side * side {
                return Err(unreadable(format!(
                    "chunk has {} values, expected {}",
                    data.len(),
                    side * side
                )));
            }
            Ok(Chunk {
                width: side,
                height: side,
                data: cache.chunk_data(data),
            })
        });
        loaded.unwrap_or_else(|error| {
            if self.error.is_none() {
                self.error = Some(error);
            }
            // Pinned but not cached, so the failure is not retried per pixel.
            Arc::new(Chunk {
                width: side,
                height: side,
                data: vec![f32::NAN; side * side].into(),
            })
        })
    }

    /// The first chunk that could not be read since the last call (its
    /// pixels read as NaN).
    pub fn take_chunk_error(&mut self) -> Option<ChunkReadError> {
        self.error.take()
    }
}

impl Grid for StoreGrid<'_> {
    fn width(&self) -> i64 {
        self.width
    }

    fn height(&self) -> i64 {
        self.height
    }

    fn geotransform(&self) -> GeoTransform {
        self.geotransform
    }

    #[inline]
    fn get(&mut self, col: i64, row: i64) -> f32 {
        if (col as u64) >= self.width as u64 || (row as u64) >= self.height as u64 {
            return f32::NAN; // negatives wrap to huge values
        }
        let (cy, cx) = self.chunk_of(col, row);
        let (dy, dx) = (
            (row - cy * self.chunk) as usize,
            (col - cx * self.chunk) as usize,
        );
        if let Some(p) = self.pinned.first() {
            if p.chunk_y == cy && p.chunk_x == cx {
                return p.chunk.data[dy * p.chunk.width + dx];
            }
        }
        let chunk = self.fetch(cy, cx);
        chunk.data[dy * chunk.width + dx]
    }

    fn take_error(&mut self) -> Option<GridError> {
        self.error.take().map(GridError::Chunk)
    }

    /// Whole rows copied from each chunk.
    fn read_window(&mut self, col0: i64, row0: i64, w: usize, h: usize) -> Vec<f32> {
        let mut out = vec![f32::NAN; w * h];
        let c0 = col0.max(0);
        let c1 = (col0 + w as i64).min(self.width);
        let r0 = row0.max(0);
        let r1 = (row0 + h as i64).min(self.height);
        if c0 >= c1 || r0 >= r1 {
            return out;
        }
        let (cy0, cx0) = self.chunk_of(c0, r0);
        let (cy1, cx1) = self.chunk_of(c1 - 1, r1 - 1);
        let c = self.chunk;
        for cy in cy0..=cy1 {
            for cx in cx0..=cx1 {
                let (ys, ye) = ((cy * c).max(r0), ((cy + 1) * c).min(r1));
                let (xs, xe) = ((cx * c).max(c0), ((cx + 1) * c).min(c1));
                let chunk = self.fetch(cy, cx);
                for row in ys..ye {
                    let src = ((row - cy * c) as usize) * chunk.width + (xs - cx * c) as usize;
                    let dst = ((row - row0) as usize) * w + (xs - col0) as usize;
                    let n = (xe - xs) as usize;
                    out[dst..dst + n].copy_from_slice(&chunk.data[src..src + n]);
                }
            }
        }
        out
    }
}
