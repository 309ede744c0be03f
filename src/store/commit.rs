//! Committing finished DSM groups: the rename into place (one per DSM, at
//! once) and the root catalog listing them (batched).
//!
//! The catalog lists every DSM, so writing it costs O(N) and writing it once
//! per ingested DSM made ingest O(N²): at 10^4 DSMs 1 GB of the 1.5 GB written
//! were catalog rewrites (10^5: ~100 GB). A [`CatalogBatch`] renames each group
//! into place under the store lock as before, but lists the renamed ids in the
//! catalog only when the time since its last catalog write is at least
//! [`SPACING`] times what that write took (so catalog I/O stays below ~5 % of
//! the run at any N), and always when the run ends or fails. Small stores
//! are still listed DSM by DSM (their writes take well under a millisecond,
//! apart from the fsync). A run killed between a rename and the catalog write
//! leaves complete groups that the next ingest adopts (see `files::recover`);
//! the catalog is re-read and merged under the lock at every write, so
//! concurrent ingests lose nothing.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use super::catalog;
use super::files::OLD_TAG;
use super::StoreError;
use crate::geo::Crs;

/// The time between catalog writes is at least this many times the last write's duration.
pub const SPACING: u32 = 20;

/// Renamed groups not yet listed in the root catalog of one store.
pub struct CatalogBatch {
    root: PathBuf,
    pending: Vec<String>,
    /// The collection's CRS once known (it never changes after that).
    crs: Option<Crs>,
    last_write: Instant,
    last_cost: Duration,
}

impl CatalogBatch {
    pub fn new(root: &Path) -> CatalogBatch {
        CatalogBatch {
            root: root.to_path_buf(),
            pending: Vec::new(),
            crs: None,
            last_write: Instant::now(),
            last_cost: Duration::ZERO,
        }
    }

    /// Under the store lock: check the DSM's CRS against the collection's
    /// (re-read from the catalog until it is known), move the finished group
    /// `tmp` to `<root>/<id>` (replacing an existing one) and list it now or
    /// with a later batch (see the module doc).
    pub fn commit(&mut self, id: &str, tmp: &Path, crs: &Crs) -> Result<(), StoreError> {
        let root = self.root.clone();
        let _lock = super::StoreLock::acquire(&root)?;
        if self.crs.is_none() {
            self.crs = catalog::read_root(&root)?.crs;
        }
        if let Some(collection) = &self.crs {
            if !collection.same_as(crs) {
                return Err(StoreError::invalid(
                    tmp,
                    format!(
                        "CRS {} differs from the collection's CRS {} (set by another run meanwhile)",
                        crs.label(),
                        collection.label()
                    ),
                ));
            }
        }
        rename_into_place(&root, id, tmp)?;
        self.pending.push(id.to_string());
        self.crs.get_or_insert_with(|| crs.clone());
        if self.last_write.elapsed() >= self.last_cost * SPACING {
            self.write_locked()?;
        }
        Ok(())
    }

    /// List every renamed group in the catalog now (the end of a run, or
    /// before reporting an error).
    pub fn flush(&mut self) -> Result<(), StoreError> {
        if self.pending.is_empty() {
            return Ok(());
        }
        let _lock = super::StoreLock::acquire(&self.root)?;
        self.write_locked()
    }

    /// Re-read the catalog, add the pending ids it lacks, write it (the lock is held).
    fn write_locked(&mut self) -> Result<(), StoreError> {
        let started = Instant::now();
        let mut attrs = catalog::read_root(&self.root)?;
        let listed: HashSet<&str> = attrs.dsms.iter().map(String::as_str).collect();
        let new: Vec<String> = self
            .pending
            .iter()
            .filter(|id| !listed.contains(id.as_str()))
            .cloned()
            .collect();
        attrs.dsms.extend(new);
        if attrs.crs.is_none() {
            attrs.crs = self.crs.clone();
        }
        catalog::write_root(&self.root, &attrs)?;
        self.crs = attrs.crs;
        self.pending.clear();
        self.last_write = Instant::now();
        self.last_cost = started.elapsed();
        Ok(())
    }
}

/// Move `tmp` to `<root>/<id>`; an existing group is moved aside first and
/// removed after.
fn rename_into_place(root: &Path, id: &str, tmp: &Path) -> Result<(), StoreError> {
    let live = root.join(id);
    if live.exists() {
        let old = root.join(format!("{id}{OLD_TAG}{}", std::process::id()));
        std::fs::rename(&live, &old).map_err(|e| StoreError::io(&live, e))?;
        std::fs::rename(tmp, &live).map_err(|e| StoreError::io(&live, e))?;
        std::fs::remove_dir_all(&old).map_err(|e| StoreError::io(&old, e))?;
    } else {
        std::fs::rename(tmp, &live).map_err(|e| StoreError::io(&live, e))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::catalog::{tests::sample_meta, RootAttrs, STORE_VERSION};
    use crate::store::lock::LOCK_FILE;

    fn empty_store(root: &Path) {
        let attrs = RootAttrs {
            version: STORE_VERSION,
            crs: None,
            dsms: vec![],
        };
        catalog::write_root(root, &attrs).unwrap();
    }

    fn make_tmp(root: &Path, name: &str, marker: &str) -> PathBuf {
        let tmp = root.join(name);
        std::fs::create_dir(&tmp).unwrap();
        std::fs::write(tmp.join("marker"), marker).unwrap();
        tmp
    }

    #[test]
    fn commit_replaces_an_existing_group() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        empty_store(root);
        let crs = sample_meta("a").crs;
        let mut batch = CatalogBatch::new(root);
        for round in 0..2 {
            let tmp = make_tmp(root, "a.tmp-7", &format!("{round}"));
            batch.commit("a", &tmp, &crs).unwrap();
            assert_eq!(
                std::fs::read_to_string(root.join("a/marker")).unwrap(),
                format!("{round}")
            );
        }
        batch.flush().unwrap();
        let attrs = catalog::read_root(root).unwrap();
        assert_eq!(attrs.dsms, ["a"]);
        assert!(attrs.crs.is_some());
        let names: Vec<_> = std::fs::read_dir(root)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .filter(|n| n != LOCK_FILE)
            .collect();
        assert_eq!(names.len(), 2, "a/ and zarr.json only: {names:?}");
    }

    #[test]
    fn batched_ids_are_merged_with_what_another_run_listed_meanwhile() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        empty_store(root);
        let crs = sample_meta("a").crs;
        let mut batch = CatalogBatch::new(root);
        // The first commit writes the catalog (nothing written yet: no cost).
        batch
            .commit("a", &make_tmp(root, "a.tmp-1", "a"), &crs)
            .unwrap();
        assert_eq!(catalog::read_root(root).unwrap().dsms, ["a"]);
        // Pretend the last write took an hour: the next ids wait for the flush.
        batch.last_cost = Duration::from_secs(3600);
        batch
            .commit("b", &make_tmp(root, "b.tmp-1", "b"), &crs)
            .unwrap();
        batch
            .commit("c", &make_tmp(root, "c.tmp-1", "c"), &crs)
            .unwrap();
        assert!(root.join("c/marker").is_file());
        assert_eq!(catalog::read_root(root).unwrap().dsms, ["a"]);
        // Another run lists "x" and, by adoption, "b".
        let mut other = catalog::read_root(root).unwrap();
        other.dsms.extend(["x".to_string(), "b".to_string()]);
        catalog::write_root(root, &other).unwrap();
        batch.flush().unwrap();
        assert_eq!(catalog::read_root(root).unwrap().dsms, ["a", "x", "b", "c"]);
        batch.flush().unwrap(); // nothing pending: no change
        assert_eq!(catalog::read_root(root).unwrap().dsms.len(), 4);
    }

    #[test]
    fn a_dsm_in_another_crs_than_the_collection_is_refused_and_not_moved() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        empty_store(root);
        let crs = sample_meta("a").crs;
        let mut batch = CatalogBatch::new(root);
        batch
            .commit("a", &make_tmp(root, "a.tmp-1", "a"), &crs)
            .unwrap();
        let mut other = crs.clone();
        other.epsg = Some(if crs.epsg == Some(32633) {
            32634
        } else {
            32633
        });
        other.wkt = None;
        other.geokeys.clear();
        let tmp = make_tmp(root, "b.tmp-1", "b");
        let err = batch.commit("b", &tmp, &other).unwrap_err().to_string();
        assert!(err.contains("differs from the collection"), "{err}");
        assert!(tmp.is_dir() && !root.join("b").exists());
    }
}
