//! [`ChunkData`]: the samples of one cached chunk, kept outside the malloc heap
//! when large, and [`MapPool`], which recycles those maps.
//!
//! Cached chunks (~1 MB each) live for a while and die in LRU order, on
//! whichever thread evicts them, while zarrs' decode buffers and the ICP's
//! vectors come and go around them in glibc's per-thread arenas. Freed chunk
//! slots then sit in the arenas as holes that the next allocations only partly
//! reuse, and the process grew ~100 MB past the cache budget on a 16-DSM align.
//! So a chunk of at least [`MAP_MIN_BYTES`] gets its own anonymous memory map,
//! and the resident chunk bytes equal the cache's accounting. Small chunks
//! (tests, tiny rasters) stay in a `Vec`.
//!
//! A fresh map costs a page fault per 4 KiB page on first write and an unmap
//! on eviction: a third of the time of a cache miss (`bench_cache`, tools/bench/cache.rs). So a
//! dropped chunk's map goes back to the [`MapPool`] of its cache (bounded in
//! bytes), and the next chunk of the same size is copied into pages that are
//! already resident.

use std::fmt;
use std::ops::Deref;
use std::sync::{Arc, Mutex};

/// Chunks of at least this many bytes are memory-mapped.
pub const MAP_MIN_BYTES: usize = 256 << 10;

/// Immutable `f32` samples of one chunk; derefs to `[f32]`.
pub struct ChunkData(Repr);

enum Repr {
    Heap(Vec<f32>),
    Mapped {
        /// Always `Some` until `drop` hands it back to the pool.
        map: Option<memmap2::MmapMut>,
        len: usize,
        pool: Option<Arc<MapPool>>,
    },
}

/// Anonymous maps of dropped chunks, reused for the next chunk of the same
/// byte size; holds at most `max_bytes` (the rest are unmapped).
#[derive(Debug)]
pub struct MapPool {
    maps: Mutex<Vec<memmap2::MmapMut>>,
    max_bytes: usize,
}

impl MapPool {
    pub fn new(max_bytes: usize) -> Arc<MapPool> {
        Arc::new(MapPool {
            maps: Mutex::new(Vec::new()),
            max_bytes,
        })
    }

    /// The samples as chunk data, in a pooled map of their size when one is free.
    pub fn data(self: &Arc<MapPool>, values: Vec<f32>) -> ChunkData {
        ChunkData::build(values, Some(self))
    }

    /// A waiting map of exactly `bytes`.
    fn take(&self, bytes: usize) -> Option<memmap2::MmapMut> {
        let mut maps = self.maps.lock().unwrap_or_else(|p| p.into_inner());
        let k = maps.iter().rposition(|m| m.len() == bytes)?;
        Some(maps.swap_remove(k))
    }

    fn give_back(&self, map: memmap2::MmapMut) {
        let mut maps = self.maps.lock().unwrap_or_else(|p| p.into_inner());
        let held: usize = maps.iter().map(|m| m.len()).sum();
        if held + map.len() <= self.max_bytes {
            maps.push(map);
        }
    }

    /// Bytes of the maps waiting for reuse.
    pub fn held_bytes(&self) -> usize {
        let maps = self.maps.lock().unwrap_or_else(|p| p.into_inner());
        maps.iter().map(|m| m.len()).sum()
    }
}

impl ChunkData {
    /// Takes the samples (copied into a private anonymous map when large; if
    /// the map cannot be made the vector is kept as is).
    pub fn from_vec(values: Vec<f32>) -> ChunkData {
        ChunkData::build(values, None)
    }

    /// Large samples into a map (from `pool` when it has one of their size;
    /// it gets the map back when the data is dropped), small ones kept as is.
    fn build(values: Vec<f32>, pool: Option<&Arc<MapPool>>) -> ChunkData {
        let bytes = std::mem::size_of_val(values.as_slice());
        if bytes < MAP_MIN_BYTES {
            return ChunkData(Repr::Heap(values));
        }
        let map = match pool.and_then(|p| p.take(bytes)) {
            Some(map) => Ok(map),
            None => memmap2::MmapOptions::new().len(bytes).map_anon(),
        };
        match map {
            Ok(map) => ChunkData::mapped(map, &values, pool.cloned()),
            Err(e) => {
                tracing::debug!(error = %e, "chunk map failed; kept on the heap");
                ChunkData(Repr::Heap(values))
            }
        }
    }

    /// `values` copied to the start of `map` (at least as long).
    fn mapped(mut map: memmap2::MmapMut, values: &[f32], pool: Option<Arc<MapPool>>) -> ChunkData {
        assert!(map.len() >= std::mem::size_of_val(values));
        // SAFETY: the map is at least `values` long, page-aligned (so aligned
        // for f32), writable and exclusively ours; any bit pattern is an f32.
        let dst =
            unsafe { std::slice::from_raw_parts_mut(map.as_mut_ptr().cast::<f32>(), values.len()) };
        dst.copy_from_slice(values);
        ChunkData(Repr::Mapped {
            map: Some(map),
            len: values.len(),
            pool,
        })
    }

    pub fn as_slice(&self) -> &[f32] {
        match &self.0 {
            Repr::Heap(v) => v,
            // SAFETY: `mapped` initialised `len` f32 values at the start of
            // the page-aligned map, which lives (unchanged) as long as `self`.
            Repr::Mapped { map, len, .. } => unsafe {
                let map = map.as_ref().expect("mapped until dropped");
                std::slice::from_raw_parts(map.as_ptr().cast::<f32>(), *len)
            },
        }
    }

    /// True when the samples live in their own memory map.
    pub fn is_mapped(&self) -> bool {
        matches!(self.0, Repr::Mapped { .. })
    }
}

impl Drop for ChunkData {
    fn drop(&mut self) {
        if let Repr::Mapped {
            map,
            pool: Some(pool),
            ..
        } = &mut self.0
        {
            if let Some(map) = map.take() {
                pool.give_back(map);
            }
        }
    }
}

impl Deref for ChunkData {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        self.as_slice()
    }
}

impl From<Vec<f32>> for ChunkData {
    fn from(values: Vec<f32>) -> ChunkData {
        ChunkData::from_vec(values)
    }
}

impl Clone for ChunkData {
    fn clone(&self) -> ChunkData {
        ChunkData::from_vec(self.as_slice().to_vec())
    }
}

impl PartialEq for ChunkData {
    fn eq(&self, other: &ChunkData) -> bool {
        self.as_slice() == other.as_slice()
    }
}

impl fmt::Debug for ChunkData {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("ChunkData")
            .field("len", &self.len())
            .field("mapped", &self.is_mapped())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_chunks_are_mapped_and_read_back_exactly() {
        let n = MAP_MIN_BYTES / 4 + 3;
        let values: Vec<f32> = (0..n).map(|i| i as f32 * 0.5 - 7.0).collect();
        let mut with_nan = values.clone();
        with_nan[5] = f32::NAN;
        let data = ChunkData::from_vec(with_nan.clone());
        assert!(data.is_mapped());
        assert_eq!(data.len(), n);
        assert!(data[5].is_nan());
        assert_eq!(data[n - 1], values[n - 1]);
        let same = data
            .iter()
            .zip(&with_nan)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same);
        let copy = data.clone();
        assert!(copy.is_mapped() && copy[..5] == values[..5]);
    }

    #[test]
    fn dropped_maps_are_reused_up_to_the_pool_bound() {
        let n = MAP_MIN_BYTES / 4;
        let pool = MapPool::new(2 * MAP_MIN_BYTES);
        let chunks: Vec<ChunkData> = (0..3).map(|k| pool.data(vec![k as f32; n])).collect();
        assert!(chunks.iter().all(ChunkData::is_mapped));
        let addresses: Vec<*const f32> = chunks.iter().map(|c| c.as_ptr()).collect();
        drop(chunks);
        // two fit in the pool, the third was unmapped
        assert_eq!(pool.held_bytes(), 2 * MAP_MIN_BYTES);
        let again = pool.data(vec![7.0; n]);
        assert!(addresses.contains(&again.as_ptr()));
        assert!(
            again.iter().all(|&v| v == 7.0),
            "the old samples are overwritten"
        );
        assert_eq!(pool.held_bytes(), MAP_MIN_BYTES);
        // another size does not take a pooled map
        let other = pool.data(vec![1.0; n + 1024]);
        assert!(!addresses.contains(&other.as_ptr()));
        assert_eq!(pool.held_bytes(), MAP_MIN_BYTES);
    }

    #[test]
    fn small_chunks_stay_on_the_heap() {
        let data = ChunkData::from(vec![1.0, 2.0, f32::NAN]);
        assert!(!data.is_mapped());
        assert_eq!(&data[..2], &[1.0, 2.0]);
        assert_eq!(ChunkData::from(vec![1.0; 4]), ChunkData::from(vec![1.0; 4]));
    }
}
