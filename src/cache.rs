//! The chunk cache: decoded chunks shared by every worker under one byte budget.
//!
//! Keys are (DSM, level, chunk row, chunk column); values are `Arc<Chunk>` so a
//! reader keeps a chunk alive while the cache is free to forget it. The cache is
//! split into shards (one `Mutex<lru::LruCache>` each, picked by key hash) so
//! threads rarely contend, but the budget is global: one atomic byte counter is
//! reserved *before* an insert, and the least recently used entry over all
//! shards (every entry carries a global use tick) is evicted until the new chunk
//! fits. So the resident bytes never exceed the budget, and with one thread the
//! order is exact LRU. A chunk larger than the whole budget is returned but not
//! kept. Loads happen outside any lock; two threads missing the same key at once
//! may both decode it (the second insert replaces the first).

use std::hash::{BuildHasher, Hash};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use lru::LruCache;

mod data;
pub use data::{ChunkData, MapPool, MAP_MIN_BYTES};

/// Fixes glibc's mmap threshold at 128 KiB; every command calls it first in
/// `main`. Commands stream chunk-sized buffers; glibc raises its threshold past
/// the 1 MiB chunk buffers once the first one is freed, and from then on keeps
/// freed chunks in per-thread arenas: a fuse of 64 DSMs of 4096 px with a
/// 128 MiB cache peaked at 297 MB RSS, and at 149 MB with the threshold fixed
/// (same run time). With it fixed, every large buffer is its own mapping,
/// returned to the system when freed, so the resident size follows the cache
/// budget (the price: page faults on every large buffer, see
/// tools/results/bench_cache_results.md).
pub fn release_large_buffers_on_free() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn mallopt(param: i32, value: i32) -> i32;
        }
        const M_MMAP_THRESHOLD: i32 = -3;
        // SAFETY: mallopt only tunes the allocator (it takes its own locks); an
        // unsupported value is refused with a 0 return, which we can ignore.
        unsafe {
            mallopt(M_MMAP_THRESHOLD, 128 * 1024);
        }
    }
}

/// Identifies one chunk of one level of one DSM.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ChunkKey {
    pub dsm: u32,
    pub level: u8,
    pub chunk_y: u32,
    pub chunk_x: u32,
}

/// A decoded chunk, row-major, NaN for no-data. Edge chunks keep the full chunk
/// shape (the part outside the raster is NaN), as Zarr stores them.
#[derive(Clone, Debug, PartialEq)]
pub struct Chunk {
    pub width: usize,
    pub height: usize,
    /// Row-major samples (memory-mapped when large, see [`ChunkData`]).
    pub data: ChunkData,
}

impl Chunk {
    /// Bytes this chunk counts against the budget (its samples).
    pub fn size_bytes(&self) -> usize {
        self.data.len() * std::mem::size_of::<f32>()
    }
}

/// Counters since the cache was created.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct CacheStats {
    pub hits: u64,
    pub misses: u64,
    pub evictions: u64,
    /// Bytes produced by loaders (every miss, cached or not).
    pub bytes_decoded: u64,
    /// Bytes resident (or reserved for an insert in progress) right now.
    pub current_bytes: u64,
    /// Highest `current_bytes` ever seen; never above `budget_bytes`.
    pub peak_bytes: u64,
    pub budget_bytes: u64,
}

struct Entry {
    chunk: Arc<Chunk>,
    /// Global use tick of the last hit or insert (smaller = older).
    last_used: u64,
}

type Shard = Mutex<LruCache<ChunkKey, Entry>>;

/// Thread-safe LRU cache of decoded chunks with a hard byte budget.
pub struct ChunkCache {
    shards: Vec<Shard>,
    hasher: std::collections::hash_map::RandomState,
    budget_bytes: usize,
    current_bytes: AtomicUsize,
    peak_bytes: AtomicUsize,
    tick: AtomicU64,
    hits: AtomicU64,
    misses: AtomicU64,
    evictions: AtomicU64,
    bytes_decoded: AtomicU64,
    /// Maps of dropped chunks for the next loads (at most 1/16 of the budget).
    pool: Arc<MapPool>,
}

impl ChunkCache {
    /// A cache holding at most `budget_bytes` of chunk samples, 16 shards.
    pub fn new(budget_bytes: usize) -> ChunkCache {
        ChunkCache::with_shards(budget_bytes, 16)
    }

    /// A cache with an explicit number of shards (at least one).
    pub fn with_shards(budget_bytes: usize, shards: usize) -> ChunkCache {
        let shards = (0..shards.max(1))
            .map(|_| Mutex::new(LruCache::unbounded()))
            .collect();
        ChunkCache {
            shards,
            hasher: Default::default(),
            budget_bytes,
            current_bytes: AtomicUsize::new(0),
            peak_bytes: AtomicUsize::new(0),
            tick: AtomicU64::new(0),
            hits: AtomicU64::new(0),
            misses: AtomicU64::new(0),
            evictions: AtomicU64::new(0),
            bytes_decoded: AtomicU64::new(0),
            pool: MapPool::new(budget_bytes / 16),
        }
    }

    /// Decoded samples as chunk data, in a recycled map when one of their size
    /// is free (see [`MapPool`]). Loaders should build their chunks with this.
    pub fn chunk_data(&self, values: Vec<f32>) -> ChunkData {
        self.pool.data(values)
    }

    pub fn budget_bytes(&self) -> usize {
        self.budget_bytes
    }

    fn shard_of(&self, key: &ChunkKey) -> usize {
        (self.hasher.hash_one(key) as usize) % self.shards.len()
    }

    fn next_tick(&self) -> u64 {
        self.tick.fetch_add(1, Ordering::Relaxed)
    }

    /// The cached chunk for `key`, or the result of `loader` (then cached if it
    /// fits in the budget). A loader error is returned and nothing is cached.
    pub fn get_or_load<E>(
        &self,
        key: ChunkKey,
        loader: impl FnOnce() -> Result<Chunk, E>,
    ) -> Result<Arc<Chunk>, E> {
        let shard = self.shard_of(&key);
        {
            let mut lru = self.shards[shard].lock().unwrap_or_else(|p| p.into_inner());
            if let Some(entry) = lru.get_mut(&key) {
                entry.last_used = self.next_tick();
                self.hits.fetch_add(1, Ordering::Relaxed);
                return Ok(entry.chunk.clone());
            }
        }
        self.misses.fetch_add(1, Ordering::Relaxed);
        let chunk = Arc::new(loader()?);
        let bytes = chunk.size_bytes();
        self.bytes_decoded
            .fetch_add(bytes as u64, Ordering::Relaxed);
        if bytes <= self.budget_bytes && self.reserve(bytes) {
            let entry = Entry {
                chunk: chunk.clone(),
                last_used: self.next_tick(),
            };
            let replaced = {
                let mut lru = self.shards[shard].lock().unwrap_or_else(|p| p.into_inner());
                lru.put(key, entry)
            };
            if let Some(old) = replaced {
                self.current_bytes
                    .fetch_sub(old.chunk.size_bytes(), Ordering::AcqRel);
            }
        }
        Ok(chunk)
    }

    /// Reserve `bytes` of the budget, evicting least recently used entries as
    /// needed. False when nothing is left to evict (other inserts in flight).
    fn reserve(&self, bytes: usize) -> bool {
        loop {
            let current = self.current_bytes.load(Ordering::Acquire);
            if current + bytes <= self.budget_bytes {
                if self
                    .current_bytes
                    .compare_exchange(
                        current,
                        current + bytes,
                        Ordering::AcqRel,
                        Ordering::Acquire,
                    )
                    .is_ok()
                {
                    self.peak_bytes.fetch_max(current + bytes, Ordering::AcqRel);
                    return true;
                }
                continue;
            }
            if !self.evict_oldest() {
                return false;
            }
        }
    }

    /// Evict the entry with the oldest use tick over all shards; one lock at a time.
    fn evict_oldest(&self) -> bool {
        let mut oldest: Option<(u64, usize)> = None;
        for (i, shard) in self.shards.iter().enumerate() {
            let lru = shard.lock().unwrap_or_else(|p| p.into_inner());
            if let Some((_, entry)) = lru.peek_lru() {
                if oldest.is_none_or(|(tick, _)| entry.last_used < tick) {
                    oldest = Some((entry.last_used, i));
                }
            }
        }
        let Some((_, shard)) = oldest else {
            return false;
        };
        let popped = {
            let mut lru = self.shards[shard].lock().unwrap_or_else(|p| p.into_inner());
            lru.pop_lru()
        };
        match popped {
            Some((key, entry)) => {
                self.current_bytes
                    .fetch_sub(entry.chunk.size_bytes(), Ordering::AcqRel);
                self.evictions.fetch_add(1, Ordering::Relaxed);
                tracing::trace!(
                    dsm = key.dsm,
                    level = key.level,
                    chunk_y = key.chunk_y,
                    chunk_x = key.chunk_x,
                    "chunk evicted"
                );
                true
            }
            // Another thread emptied that shard meanwhile: look again.
            None => true,
        }
    }

    /// Whether `key` is resident (does not count as a use).
    pub fn contains(&self, key: &ChunkKey) -> bool {
        let lru = self.shards[self.shard_of(key)]
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        lru.contains(key)
    }

    pub fn stats(&self) -> CacheStats {
        CacheStats {
            hits: self.hits.load(Ordering::Relaxed),
            misses: self.misses.load(Ordering::Relaxed),
            evictions: self.evictions.load(Ordering::Relaxed),
            bytes_decoded: self.bytes_decoded.load(Ordering::Relaxed),
            current_bytes: self.current_bytes.load(Ordering::Relaxed) as u64,
            peak_bytes: self.peak_bytes.load(Ordering::Relaxed) as u64,
            budget_bytes: self.budget_bytes as u64,
        }
    }

    /// One `info` event with the counters, for the end of a run.
    pub fn log_stats(&self) {
        let s = self.stats();
        let lookups = (s.hits + s.misses).max(1);
        tracing::info!(
            hits = s.hits,
            misses = s.misses,
            hit_rate = format!("{:.3}", s.hits as f64 / lookups as f64),
            evictions = s.evictions,
            decoded_mb = format!("{:.1}", s.bytes_decoded as f64 / 1e6),
            peak_mb = format!("{:.1}", s.peak_bytes as f64 / 1e6),
            budget_mb = format!("{:.1}", s.budget_bytes as f64 / 1e6),
            "cache stats reported"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::collections::VecDeque;

    fn key(i: u32) -> ChunkKey {
        ChunkKey {
            dsm: i % 3,
            level: (i % 2) as u8,
            chunk_y: i,
            chunk_x: i * 7,
        }
    }

    /// Deterministic content and size for key i (what an uncached read returns).
    fn load(i: u32) -> Chunk {
        let side = 1 + (i as usize * 5) % 8;
        Chunk {
            width: side,
            height: side,
            data: (0..side * side)
                .map(|k| i as f32 * 1000.0 + k as f32)
                .collect::<Vec<f32>>()
                .into(),
        }
    }

    /// Exact LRU model: front = most recent.
    struct Model {
        budget: usize,
        order: VecDeque<(u32, usize)>,
        evictions: u64,
    }

    impl Model {
        fn get(&mut self, i: u32) -> bool {
            if let Some(pos) = self.order.iter().position(|&(k, _)| k == i) {
                let e = self.order.remove(pos).unwrap();
                self.order.push_front(e);
                return true;
            }
            let bytes = load(i).size_bytes();
            if bytes <= self.budget {
                while self.order.iter().map(|e| e.1).sum::<usize>() + bytes > self.budget {
                    self.order.pop_back();
                    self.evictions += 1;
                }
                self.order.push_front((i, bytes));
            }
            false
        }
    }

    proptest! {
        #[test]
        fn cache_matches_lru_model(
            budget in 0usize..1200,
            shards in 1usize..6,
            ops in proptest::collection::vec(0u32..20, 1..200),
        ) {
            let cache = ChunkCache::with_shards(budget, shards);
            let mut model = Model { budget, order: VecDeque::new(), evictions: 0 };
            let mut loads = 0u64;
            for &i in &ops {
                let mut loaded = false;
                let got = cache
                    .get_or_load(key(i), || -> Result<Chunk, ()> { loaded = true; Ok(load(i)) })
                    .unwrap();
                if loaded { loads += 1; }
                prop_assert_eq!(&*got, &load(i));
                let model_hit = model.get(i);
                prop_assert_eq!(model_hit, !loaded, "hit/miss differs at key {}", i);
                let s = cache.stats();
                prop_assert!(s.current_bytes as usize <= budget);
                prop_assert!(s.peak_bytes as usize <= budget);
                let model_bytes: usize = model.order.iter().map(|e| e.1).sum();
                prop_assert_eq!(s.current_bytes as usize, model_bytes);
                for &(k, _) in &model.order {
                    prop_assert!(cache.contains(&key(k)));
                }
            }
            let s = cache.stats();
            prop_assert_eq!(s.misses, loads);
            prop_assert_eq!(s.hits + s.misses, ops.len() as u64);
            prop_assert_eq!(s.evictions, model.evictions);
        }
    }

    #[test]
    fn oversized_chunk_is_returned_but_not_cached() {
        let cache = ChunkCache::new(10);
        let chunk = cache
            .get_or_load(key(1), || -> Result<Chunk, ()> { Ok(load(1)) })
            .unwrap();
        assert_eq!(*chunk, load(1));
        assert!(!cache.contains(&key(1)));
        assert_eq!(cache.stats().current_bytes, 0);
    }

    #[test]
    fn loader_error_is_returned_and_not_cached() {
        let cache = ChunkCache::new(1 << 20);
        let err = cache
            .get_or_load(key(2), || -> Result<Chunk, &str> { Err("broken") })
            .unwrap_err();
        assert_eq!(err, "broken");
        assert!(!cache.contains(&key(2)));
        let ok = cache
            .get_or_load(key(2), || -> Result<Chunk, &str> { Ok(load(2)) })
            .unwrap();
        assert_eq!(*ok, load(2));
    }

    #[test]
    fn threads_share_the_budget() {
        let budget = 64 * 4 * 10;
        let cache = ChunkCache::new(budget);
        std::thread::scope(|s| {
            for t in 0..4u32 {
                let cache = &cache;
                s.spawn(move || {
                    for n in 0..2000u32 {
                        let i = (n * 31 + t * 17) % 50;
                        let k = ChunkKey {
                            dsm: 0,
                            level: 0,
                            chunk_y: i,
                            chunk_x: 0,
                        };
                        let c = cache
                            .get_or_load(k, || -> Result<Chunk, ()> {
                                Ok(Chunk {
                                    width: 8,
                                    height: 8,
                                    data: vec![i as f32; 64].into(),
                                })
                            })
                            .unwrap();
                        assert!(c.data.iter().all(|&v| v == i as f32));
                        assert!(cache.stats().current_bytes as usize <= budget);
                    }
                });
            }
        });
        let s = cache.stats();
        assert!(s.peak_bytes as usize <= budget);
        assert_eq!(s.hits + s.misses, 8000);
        assert!(s.evictions > 0);
    }
}
