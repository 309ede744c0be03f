//! [`ChunkData`]: the samples of one cached chunk, kept outside the malloc heap
//! when large.
//!
//! Cached chunks (~1 MB each) live for a while and die in LRU order, on
//! whichever thread evicts them, while zarrs' decode buffers and the ICP's
//! vectors come and go around them in glibc's per-thread arenas. Freed chunk
//! slots then sit in the arenas as holes that the next allocations only partly
//! reuse, and the process grew ~100 MB past the cache budget on a 16-DSM align
//! (tools/bench_results.md). So a chunk of at least [`MAP_MIN_BYTES`] gets its
//! own anonymous memory map: eviction unmaps it and the pages go straight back
//! to the system, and the resident chunk bytes equal the cache's accounting.
//! Small chunks (tests, tiny rasters) stay in a `Vec`.

use std::fmt;
use std::ops::Deref;

/// Chunks of at least this many bytes are memory-mapped.
pub const MAP_MIN_BYTES: usize = 256 << 10;

/// Immutable `f32` samples of one chunk; derefs to `[f32]`.
pub struct ChunkData(Repr);

enum Repr {
    Heap(Vec<f32>),
    Mapped { map: memmap2::MmapMut, len: usize },
}

impl ChunkData {
    /// Takes the samples (copied into a private anonymous map when large; if
    /// the map cannot be made the vector is kept as is).
    pub fn from_vec(values: Vec<f32>) -> ChunkData {
        let bytes = std::mem::size_of_val(values.as_slice());
        if bytes < MAP_MIN_BYTES {
            return ChunkData(Repr::Heap(values));
        }
        match memmap2::MmapOptions::new().len(bytes).map_anon() {
            Ok(mut map) => {
                // SAFETY: the map is `bytes` long, page-aligned (so aligned for
                // f32), writable and exclusively ours; any bit pattern is an f32.
                let dst = unsafe {
                    std::slice::from_raw_parts_mut(map.as_mut_ptr().cast::<f32>(), values.len())
                };
                dst.copy_from_slice(&values);
                ChunkData(Repr::Mapped {
                    map,
                    len: values.len(),
                })
            }
            Err(e) => {
                tracing::debug!(error = %e, "chunk map failed; kept on the heap");
                ChunkData(Repr::Heap(values))
            }
        }
    }

    pub fn as_slice(&self) -> &[f32] {
        match &self.0 {
            Repr::Heap(v) => v,
            // SAFETY: `from_vec` initialised `len` f32 values at the start of
            // the page-aligned map, which lives (unchanged) as long as `self`.
            Repr::Mapped { map, len } => unsafe {
                std::slice::from_raw_parts(map.as_ptr().cast::<f32>(), *len)
            },
        }
    }

    /// True when the samples live in their own memory map.
    pub fn is_mapped(&self) -> bool {
        matches!(self.0, Repr::Mapped { .. })
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
    fn small_chunks_stay_on_the_heap() {
        let data = ChunkData::from(vec![1.0, 2.0, f32::NAN]);
        assert!(!data.is_mapped());
        assert_eq!(&data[..2], &[1.0, 2.0]);
        assert_eq!(ChunkData::from(vec![1.0; 4]), ChunkData::from(vec![1.0; 4]));
    }
}
