//! The store lock: an exclusive `flock` on `<store>/.dsmstream.lock`, held by
//! a writer around every read-modify-write of the root catalog (and the
//! repair of leftovers), so concurrent `ingest` runs merge their DSMs instead
//! of overwriting each other's catalog.
//!
//! Why this works on shared file systems: `flock` is honoured across clients
//! on NFS (Linux maps it to POSIX byte-range locks, served by the NFS lock
//! manager) and on Lustre mounted with `-o flock`; every file the lock
//! protects is replaced by an atomic rename within one folder. A lock held
//! by a killed process is released by the kernel (or the NFS server's lease
//! expiry), so a crash never leaves the store locked. Readers (`align`,
//! `fuse`, `eval`) do not lock: they only ever see complete catalogs.

use std::fs::File;
use std::path::{Path, PathBuf};

use super::StoreError;

/// Name of the lock file in the store root.
pub const LOCK_FILE: &str = ".dsmstream.lock";

/// An exclusive lock on a store, released when dropped.
#[derive(Debug)]
pub struct StoreLock {
    file: File,
    path: PathBuf,
}

impl StoreLock {
    /// Block until this process holds the store's lock. The store folder must
    /// exist; the lock file is created when absent. A read-only store gives
    /// [`StoreError::ReadOnly`].
    pub fn acquire(root: &Path) -> Result<StoreLock, StoreError> {
        let path = root.join(LOCK_FILE);
        let file = File::options()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .map_err(|e| StoreError::io_or_read_only(root, &path, e))?;
        file.lock().map_err(|e| StoreError::io(&path, e))?;
        tracing::trace!(path = %path.display(), "store locked");
        Ok(StoreLock { file, path })
    }
}

impl Drop for StoreLock {
    fn drop(&mut self) {
        let _ = self.file.unlock();
        tracing::trace!(path = %self.path.display(), "store unlocked");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;

    /// Two holders never overlap: a counter raised inside the lock never
    /// sees another holder (each thread opens its own file, as processes do).
    #[test]
    fn the_lock_excludes_other_holders() {
        let dir = tempfile::tempdir().unwrap();
        let inside = Arc::new(AtomicUsize::new(0));
        std::thread::scope(|s| {
            for _ in 0..4 {
                let (root, inside) = (dir.path(), inside.clone());
                s.spawn(move || {
                    for _ in 0..20 {
                        let _lock = StoreLock::acquire(root).unwrap();
                        assert_eq!(inside.fetch_add(1, Ordering::SeqCst), 0);
                        std::thread::sleep(std::time::Duration::from_micros(200));
                        inside.fetch_sub(1, Ordering::SeqCst);
                    }
                });
            }
        });
        assert!(dir.path().join(LOCK_FILE).is_file());
    }
}
