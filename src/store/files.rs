//! The file-system side of ingest: expanding inputs into (id, path), stating
//! sources, committing a finished DSM group by rename, and repairing what a
//! killed run left behind.
//!
//! A DSM is written as `<id>.tmp-<pid>-<host>/` (no lock held: concurrent
//! ingests write in parallel) and, under the store lock, renamed to `<id>/`
//! and added to a freshly re-read root catalog (in batches: see `commit`); a
//! replaced group is first moved aside to `<id>.old-<pid>/`. On the next run (under the lock),
//! temporaries of dead processes of this host are deleted (another host's are
//! left alone: its processes cannot be seen from here), a moved-aside group
//! whose replacement never arrived is moved back, catalog temporaries
//! (`.zarr.json.<pid>.tmp`, only ever written under the lock) are removed,
//! and a complete group missing from the catalog is adopted.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use super::catalog::{self, RootAttrs, SourceInfo};
use super::lock::LOCK_FILE;
use super::{validate, StoreError};
use crate::atomic::process_alive;

pub const TMP_TAG: &str = ".tmp-";

/// Prefix of the empty file a command creates and removes at once to test
/// that the store folder is writable (followed by its pid).
pub const WRITE_PROBE_PREFIX: &str = ".dsmstream-write-probe-";
pub const OLD_TAG: &str = ".old-";

/// One input file and the DSM id it becomes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InputFile {
    pub id: String,
    /// Absolute (canonical) path.
    pub path: PathBuf,
}

/// Files named on the command line plus the `*.tif` / `*.tiff` files and
/// SRTM tiles (`*.hgt`, `*.hgt.zip`) directly inside named directories
/// (sorted). Errors are one line naming the path.
pub fn expand_inputs(inputs: &[PathBuf]) -> Result<Vec<InputFile>, String> {
    let mut files = Vec::new();
    for input in inputs {
        let meta = std::fs::metadata(input).map_err(|e| format!("{}: {e}", input.display()))?;
        if meta.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(input)
                .map_err(|e| format!("{}: {e}", input.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_file() && is_input_name(p))
                .collect();
            if found.is_empty() {
                return Err(format!(
                    "{}: no .tif, .tiff, .hgt or .hgt.zip files in this directory",
                    input.display()
                ));
            }
            found.sort();
            files.extend(found);
        } else {
            files.push(input.clone());
        }
    }
    let mut seen: HashMap<String, PathBuf> = HashMap::new();
    let mut out = Vec::with_capacity(files.len());
    for file in files {
        let path = std::fs::canonicalize(&file).map_err(|e| format!("{}: {e}", file.display()))?;
        let name = file.file_name().map(|s| s.to_string_lossy().into_owned());
        let id = match name {
            Some(name) if name.to_ascii_lowercase().ends_with(".zip") => {
                super::hgt::id_of_zip(&name)
            }
            _ => (file.file_stem())
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
        };
        check_id(&id, &file)?;
        if let Some(other) = seen.get(&id) {
            if *other == path {
                continue; // the same file named twice
            }
            return Err(format!(
                "{} and {} have the same stem \"{id}\" (DSM ids must be unique); rename one",
                other.display(),
                path.display()
            ));
        }
        seen.insert(id.clone(), path.clone());
        out.push(InputFile { id, path });
    }
    Ok(out)
}

fn is_input_name(p: &Path) -> bool {
    let name = (p.file_name())
        .map(|n| n.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    [".tif", ".tiff", ".hgt", ".hgt.zip"]
        .iter()
        .any(|tail| name.ends_with(tail))
}

/// An id must be usable as a Zarr node name and not look like our temporaries.
fn check_id(id: &str, file: &Path) -> Result<(), String> {
    if validate::check_id(id).is_err() {
        return Err(format!(
            "{}: file stem \"{id}\" cannot be a DSM id (empty, starts with '.' or \"__\", or contains \"{TMP_TAG}\"/\"{OLD_TAG}\"); rename the file",
            file.display()
        ));
    }
    Ok(())
}

/// Path, size and mtime of a source file and of its side files.
pub fn source_info(path: &Path) -> Result<SourceInfo, StoreError> {
    let mut info = file_info(path)?;
    for side in crate::geotiff::sidecar::paths(path) {
        info.side_files.push(file_info(&side)?);
    }
    Ok(info)
}

fn file_info(path: &Path) -> Result<SourceInfo, StoreError> {
    let meta = std::fs::metadata(path).map_err(|e| StoreError::io(path, e))?;
    let mtime_unix_ns = meta
        .modified()
        .ok()
        .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
        .map(|d| d.as_nanos() as i64)
        .unwrap_or(0);
    Ok(SourceInfo {
        path: path.display().to_string(),
        size: meta.len(),
        mtime_unix_ns,
        side_files: Vec::new(),
    })
}

/// Total size of the files under `dir`.
pub fn dir_bytes(dir: &Path) -> u64 {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return 0;
    };
    entries
        .filter_map(Result::ok)
        .map(|e| match e.file_type() {
            Ok(t) if t.is_dir() => dir_bytes(&e.path()),
            _ => e.metadata().map(|m| m.len()).unwrap_or(0),
        })
        .sum()
}

/// This machine's name as used in temporary names (letters, digits, `-`, `.`).
pub fn host_tag() -> String {
    let raw = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .unwrap_or_default();
    let tag: String = raw
        .trim()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if tag.is_empty() {
        "localhost".into()
    } else {
        tag
    }
}

/// The folder a DSM is written to before its commit: `<id>.tmp-<pid>-<host>`.
pub fn tmp_name(id: &str) -> String {
    format!("{id}{TMP_TAG}{}-{}", std::process::id(), host_tag())
}

/// True when the temporary tagged `tag` (after `.tmp-`: `<pid>` or
/// `<pid>-<host>`) may belong to a live process: one of this host that is
/// alive, or any process of another host.
fn writer_may_live(tag: &str) -> bool {
    let (pid, host) = match tag.split_once('-') {
        Some((pid, host)) => (pid, Some(host)),
        None => (tag, None),
    };
    if host.is_some_and(|h| h != host_tag()) {
        return true;
    }
    let pid: u32 = pid.parse().unwrap_or(0);
    pid != std::process::id() && process_alive(pid)
}

/// Remove catalog temporaries (`.zarr.json.<pid>.tmp`) left in the store
/// root by killed runs. Call only under the store lock: the catalog is only
/// written by the lock's holder, so every such file is stale.
fn remove_catalog_temporaries(root: &Path) -> Result<(), StoreError> {
    let entries = std::fs::read_dir(root).map_err(|e| StoreError::io(root, e))?;
    for entry in entries.filter_map(Result::ok) {
        let name = entry.file_name().to_string_lossy().into_owned();
        if name.starts_with(".zarr.json.") && name.ends_with(".tmp") {
            let path = entry.path();
            std::fs::remove_file(&path).map_err(|e| StoreError::io_or_read_only(root, &path, e))?;
            tracing::info!(path = %path.display(), "stale temporary removed");
        }
    }
    Ok(())
}

/// True when `dir` holds nothing but what a store under creation (or a
/// killed creation) holds: the lock file, catalog and DSM temporaries, and
/// the write probes of runs starting now (concurrent ingests into a new store
/// must not take each other's probe for foreign content).
pub fn only_leftovers(dir: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    entries.filter_map(Result::ok).all(|e| {
        let name = e.file_name().to_string_lossy().into_owned();
        name == LOCK_FILE
            || name.starts_with(WRITE_PROBE_PREFIX)
            || (name.starts_with(".zarr.json.") && name.ends_with(".tmp"))
            || name.contains(TMP_TAG)
    })
}

/// Names of the folders directly inside `dir`, sorted.
fn subdirectories(dir: &Path) -> Result<Vec<String>, StoreError> {
    let entries = std::fs::read_dir(dir).map_err(|e| StoreError::io(dir, e))?;
    let mut names: Vec<String> = entries
        .filter_map(Result::ok)
        .filter(|e| e.file_type().map(|t| t.is_dir()).unwrap_or(false))
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    Ok(names)
}

/// Repair after a killed run (see the module doc); returns the updated
/// catalog. Call under the store lock, with the catalog read under it.
pub fn recover(root: &Path, mut attrs: RootAttrs) -> Result<RootAttrs, StoreError> {
    let mut changed = false;
    remove_catalog_temporaries(root)?;
    for name in &subdirectories(root)? {
        let path = root.join(name);
        if let Some((id, tag)) = name.split_once(TMP_TAG) {
            if writer_may_live(tag) {
                continue; // another ingest is writing it
            }
            std::fs::remove_dir_all(&path).map_err(|e| StoreError::io(&path, e))?;
            tracing::info!(dsm = id, path = %path.display(), "stale temporary removed");
        } else if let Some((id, _)) = name.split_once(OLD_TAG) {
            let live = root.join(id);
            if live.join("zarr.json").is_file() {
                std::fs::remove_dir_all(&path).map_err(|e| StoreError::io(&path, e))?;
            } else {
                if live.exists() {
                    std::fs::remove_dir_all(&live).map_err(|e| StoreError::io(&live, e))?;
                }
                std::fs::rename(&path, &live).map_err(|e| StoreError::io(&live, e))?;
                tracing::warn!(dsm = id, "interrupted replacement rolled back");
            }
        }
    }
    // Complete groups the catalog does not list yet (killed before the catalog write).
    let listed: std::collections::HashSet<String> = attrs.dsms.iter().cloned().collect();
    for name in subdirectories(root)?
        .iter()
        .filter(|n| !n.contains(TMP_TAG) && !n.contains(OLD_TAG))
    {
        if listed.contains(name) {
            continue;
        }
        if validate::check_id(name).is_err() {
            continue;
        }
        let Ok(meta) = catalog::read_valid_dsm(root, name, attrs.crs.as_ref()) else {
            continue;
        };
        let crs_ok = attrs.crs.as_ref().is_none_or(|c| c.same_as(&meta.crs));
        if meta.id == *name && crs_ok {
            attrs.crs.get_or_insert(meta.crs.clone());
            attrs.dsms.push(name.clone());
            changed = true;
            tracing::warn!(dsm = %name, "uncatalogued DSM adopted");
        }
    }
    if changed {
        catalog::write_root(root, &attrs)?;
    }
    Ok(attrs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::catalog::{tests::sample_meta, write_group_attributes, STORE_VERSION};

    #[test]
    fn inputs_expand_sorted_and_reject_duplicate_stems() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        for name in ["b.tif", "a.TIFF", "notes.txt"] {
            std::fs::write(d.join(name), b"x").unwrap();
        }
        std::fs::create_dir(d.join("sub")).unwrap();
        std::fs::write(d.join("sub/a.tif"), b"x").unwrap();
        let files = expand_inputs(&[d.to_path_buf()]).unwrap();
        let ids: Vec<_> = files.iter().map(|f| f.id.as_str()).collect();
        assert_eq!(ids, ["a", "b"]);
        assert!(files[0].path.is_absolute());
        let err = expand_inputs(&[d.to_path_buf(), d.join("sub/a.tif")]).unwrap_err();
        assert!(err.contains("same stem \"a\""), "{err}");
        let err = expand_inputs(&[d.join("missing.tif")]).unwrap_err();
        assert!(err.contains("missing.tif"), "{err}");
        let err = expand_inputs(&[d.join("sub"), d.join("notes.txt")]);
        assert!(err.is_ok(), "a file named explicitly is taken as is");
        std::fs::write(d.join("x.tmp-1.tif"), b"x").unwrap();
        assert!(expand_inputs(&[d.join("x.tmp-1.tif")]).is_err());
    }

    #[test]
    fn recover_removes_stale_temporaries_rolls_back_and_adopts() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        let attrs = RootAttrs {
            version: STORE_VERSION,
            crs: None,
            dsms: vec![],
        };
        catalog::write_root(root, &attrs).unwrap();
        // A temporary of a dead process (pid 0 never exists as a directory in /proc).
        std::fs::create_dir_all(root.join("a.tmp-0/0")).unwrap();
        // A replacement interrupted after moving the old group aside.
        std::fs::create_dir(root.join("b.old-0")).unwrap();
        write_group_attributes(&root.join("b.old-0"), &sample_meta("b").to_attributes()).unwrap();
        // A complete group renamed into place but never catalogued.
        std::fs::create_dir(root.join("c")).unwrap();
        write_group_attributes(&root.join("c"), &sample_meta("c").to_attributes()).unwrap();
        let attrs = recover(root, attrs).unwrap();
        assert!(!root.join("a.tmp-0").exists());
        assert!(!root.join("b.old-0").exists());
        assert!(root.join("b/zarr.json").is_file());
        assert_eq!(attrs.dsms, ["b", "c"]);
        assert_eq!(catalog::read_root(root).unwrap(), attrs);
        assert!(attrs.crs.is_some());
    }

    /// What runs creating a store leave in it for a moment (the lock, a
    /// catalog or DSM temporary, a write probe) does not make the folder
    /// foreign; anything else does.
    #[test]
    fn a_store_under_creation_holds_only_leftovers() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        assert!(only_leftovers(root), "an empty folder");
        for name in [
            LOCK_FILE.to_string(),
            ".zarr.json.77.tmp".into(),
            format!("{WRITE_PROBE_PREFIX}77"),
        ] {
            std::fs::write(root.join(name), b"").unwrap();
        }
        std::fs::create_dir(root.join(tmp_name("d0"))).unwrap();
        assert!(only_leftovers(root));
        std::fs::write(root.join("notes.txt"), b"x").unwrap();
        assert!(!only_leftovers(root));
    }
}
