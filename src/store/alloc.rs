//! Allocator tuning for ingest and every reader of the store. Writing a chunk
//! (and reading one: a decoded chunk is 1 MiB at 512 px) allocates a few short-lived
//! MiB-sized buffers (the chunk, its bytes, the zstd output); glibc serves
//! such sizes with fresh `mmap`s (or trims them back to the kernel) and every
//! one costs a page fault and a zeroed page per 4 KiB: about 2 million faults,
//! ~20 % of the CPU time, for a 20000² DSM. Raising the mmap and trim
//! thresholds lets freed buffers be reused from the heap instead; the resident
//! set stays the ingest's working set (the same buffers, reused).

/// Keep freed blocks below 32 MiB in the process heap (glibc only; elsewhere
/// a no-op). Process-wide and idempotent.
pub(crate) fn reuse_freed_buffers() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        extern "C" {
            fn mallopt(param: std::ffi::c_int, value: std::ffi::c_int) -> std::ffi::c_int;
        }
        const M_TRIM_THRESHOLD: std::ffi::c_int = -1;
        const M_MMAP_THRESHOLD: std::ffi::c_int = -3;
        // SAFETY: mallopt only changes allocator parameters; both values are
        // in glibc's accepted range (the mmap threshold's maximum is 32 MiB).
        unsafe {
            mallopt(M_MMAP_THRESHOLD, 32 << 20);
            mallopt(M_TRIM_THRESHOLD, 256 << 20);
        }
    }
}
