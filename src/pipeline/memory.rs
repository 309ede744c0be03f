//! The pipeline's memory: the chunk cache budget covers the chunks the grids
//! pin as well. Each [`StoreGrid`](crate::store::StoreGrid) pins its last
//! [`PINNED_CHUNKS`] chunks, and a chunk the cache has evicted stays alive while
//! a grid pins it; so `--cache-mb` is split into the pins of every thread and
//! the cache proper, and memory stays at the budget plus a constant.

use crate::store::grid::PINNED_CHUNKS;
use crate::store::Store;

/// Grids a pipeline thread keeps open at once: the moving grid of the pair it
/// registers (or the two grids that score a pair) and the reference grid of
/// the block of correspondences it matches.
pub const PINNED_GRIDS_PER_THREAD: usize = 2;

/// The pins take at most this share of the budget; the cache gets the rest.
pub const MAX_PINNED_SHARE: f64 = 0.5;

/// The threads and the cache budget of one run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemoryPlan {
    pub threads: usize,
    pub cache_budget_bytes: usize,
    pub pinned_bytes: usize,
}

/// Bytes one thread's grids pin at most, for the largest chunk of the store.
pub fn pinned_bytes_per_thread(store: &Store) -> usize {
    let chunk_bytes = store
        .dsms()
        .iter()
        .flat_map(|d| d.levels.iter().map(|l| (l.chunk * l.chunk) as usize * 4))
        .max()
        .unwrap_or(0);
    PINNED_GRIDS_PER_THREAD * PINNED_CHUNKS * chunk_bytes
}

/// Splits `budget_bytes` into the pins of `threads` threads and the cache.
/// When the pins would take more than [`MAX_PINNED_SHARE`] of the budget, a
/// default thread count (`explicit` false) is lowered to fit; an explicit one,
/// or a budget too small for one thread, is refused with what to change.
pub fn plan_memory(
    budget_bytes: usize,
    per_thread_bytes: usize,
    threads: usize,
    explicit: bool,
) -> Result<MemoryPlan, String> {
    let allowed = (budget_bytes as f64 * MAX_PINNED_SHARE) as usize;
    let fitting = allowed.checked_div(per_thread_bytes).unwrap_or(usize::MAX);
    let threads = threads.max(1);
    let mib = |b: usize| b.div_ceil(1 << 20);
    let needed = |t: usize| mib(2 * t * per_thread_bytes);
    let threads = if threads <= fitting {
        threads
    } else if explicit {
        return Err(format!(
            "--cache-mb {} is too small for --threads {threads}: their grids pin up to {} MiB of chunks, which may take at most half the budget; use --cache-mb {} or fewer threads",
            mib(budget_bytes),
            mib(threads * per_thread_bytes),
            needed(threads)
        ));
    } else if fitting == 0 {
        return Err(format!(
            "--cache-mb {} is too small: one thread's grids pin up to {} MiB of chunks, which may take at most half the budget; use --cache-mb {} or more",
            mib(budget_bytes),
            mib(per_thread_bytes),
            needed(1)
        ));
    } else {
        fitting
    };
    let pinned_bytes = threads * per_thread_bytes;
    Ok(MemoryPlan {
        threads,
        cache_budget_bytes: budget_bytes - pinned_bytes,
        pinned_bytes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const MIB: usize = 1 << 20;

    #[test]
    fn pins_come_out_of_the_budget() {
        let plan = plan_memory(256 * MIB, 16 * MIB, 4, true).unwrap();
        assert_eq!(plan.threads, 4);
        assert_eq!(plan.pinned_bytes, 64 * MIB);
        assert_eq!(plan.cache_budget_bytes, 192 * MIB);
        // exactly half the budget still fits
        assert_eq!(
            plan_memory(256 * MIB, 16 * MIB, 8, true).unwrap().threads,
            8
        );
    }

    #[test]
    fn a_default_thread_count_is_lowered_an_explicit_one_refused() {
        let plan = plan_memory(256 * MIB, 16 * MIB, 64, false).unwrap();
        assert_eq!(plan.threads, 8);
        assert_eq!(plan.cache_budget_bytes, 128 * MIB);
        let err = plan_memory(256 * MIB, 16 * MIB, 64, true).unwrap_err();
        assert!(
            err.contains("--cache-mb 256 is too small for --threads 64"),
            "{err}"
        );
        assert!(err.contains("use --cache-mb 2048"), "{err}");
        let err = plan_memory(16 * MIB, 16 * MIB, 2, false).unwrap_err();
        assert!(err.contains("use --cache-mb 32 or more"), "{err}");
    }
}
