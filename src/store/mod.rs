//! The collection store: one Zarr v3 group per collection, one multiscale group
//! per DSM, read through the shared chunk cache.
//!
//! Layout of `<store>.zarr/`:
//! ```text
//! zarr.json            group; attributes {"dsmstream": {version, crs, dsms: [ids]}}
//! <id>/zarr.json       group; attributes {"dsmstream": DsmMeta, "multiscales": {...}}
//! <id>/0, <id>/1, ...  float32 arrays ["y","x"], NaN fill, square chunks, zstd;
//!                      level k+1 = 2x2 mean of the valid pixels of level k;
//!                      attributes spatial:/proj: georeferencing (see geo_attrs)
//! ```
//! [`Store`] reads the catalog at open and opens the zarrs arrays lazily (kept
//! open up to a bound, `open_arrays`); [`StoreGrid`] gives pixel access to one level; `ingest`
//! writes the store from GeoTIFFs (or any [`source::RowSource`]).

mod alloc;
pub mod catalog;
pub mod check;
mod chunks;
mod commit;
mod files;
pub mod geo_attrs;
pub mod grid;
pub mod hgt;
pub mod ingest;
pub mod lock;
mod mean2x2;
mod open_arrays;
mod plan;
mod pyramid;
pub mod source;
mod stats;
pub mod validate;
pub mod view;
pub mod vrt;
pub mod warp;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use zarrs::array::Array;
use zarrs::filesystem::FilesystemStore;

pub use catalog::{
    Compression, DsmMeta, HeightStats, LevelMeta, SourceInfo, StorageSettings, STORE_VERSION,
};
pub use chunks::ChunkRecord;
pub use files::WRITE_PROBE_PREFIX;
pub use grid::{ChunkReadError, StoreGrid};
pub use ingest::{ingest, IngestError, IngestOptions, IngestReport};
pub use lock::StoreLock;
use open_arrays::{OpenArrays, MAX_OPEN_ARRAYS};
pub use view::StorePyramid;

use crate::geo::Crs;

/// One zarrs array of the store (one level of one DSM).
pub type LevelArray = Array<FilesystemStore>;

#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("{path}: not a dsmstream store ({reason})")]
    NotAStore { path: String, reason: String },
    #[error("{path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: bad JSON: {message}")]
    Json { path: String, message: String },
    #[error("{path}: {message}")]
    Zarr { path: String, message: String },
    /// Metadata that fails validation (damaged, hand-edited or implausible).
    #[error("{path}: {message}")]
    Invalid { path: String, message: String },
    /// A chunk of one DSM could not be read (missing or undecodable file).
    #[error("{store}: DSM '{id}': {source}")]
    Chunk {
        store: String,
        id: String,
        #[source]
        source: ChunkReadError,
    },
    /// The store cannot be written (permissions, read-only file system).
    #[error("{path}: the store is read-only ({source}); writing needs write access to it")]
    ReadOnly {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{store}: no DSM number {dsm} level {level}")]
    NoSuchLevel {
        store: String,
        dsm: usize,
        level: usize,
    },
}

impl StoreError {
    pub(crate) fn io(path: &Path, source: std::io::Error) -> StoreError {
        StoreError::Io {
            path: path.display().to_string(),
            source,
        }
    }

    pub(crate) fn json(path: &Path, err: serde_json::Error) -> StoreError {
        StoreError::Json {
            path: path.display().to_string(),
            message: err.to_string(),
        }
    }

    /// An I/O error while writing into the store at `root`: permission and
    /// read-only errors become [`StoreError::ReadOnly`], the rest [`StoreError::Io`].
    pub(crate) fn io_or_read_only(root: &Path, path: &Path, source: std::io::Error) -> StoreError {
        use std::io::ErrorKind::{PermissionDenied, ReadOnlyFilesystem};
        if matches!(source.kind(), PermissionDenied | ReadOnlyFilesystem) {
            StoreError::ReadOnly {
                path: root.display().to_string(),
                source,
            }
        } else {
            StoreError::io(path, source)
        }
    }

    pub(crate) fn invalid(path: &Path, message: impl Into<String>) -> StoreError {
        StoreError::Invalid {
            path: path.display().to_string(),
            message: message.into(),
        }
    }

    pub(crate) fn zarr(path: impl std::fmt::Display, err: impl std::fmt::Display) -> StoreError {
        StoreError::Zarr {
            path: path.to_string(),
            message: err.to_string(),
        }
    }

    /// True when the path given by the user is not a readable store.
    pub fn is_bad_input(&self) -> bool {
        matches!(
            self,
            StoreError::NotAStore { .. }
                | StoreError::Json { .. }
                | StoreError::Io { .. }
                | StoreError::Invalid { .. }
                | StoreError::ReadOnly { .. }
                | StoreError::Zarr { .. }
                | StoreError::Chunk { .. }
        )
    }
}

/// Apply the process-wide zarrs settings this crate relies on (idempotent):
/// no `_zarrs` attribute in array metadata, so files are plain Zarr v3.
pub(crate) fn configure_zarrs() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        zarrs::config::global_config_mut().set_include_zarrs_metadata(false);
    });
}

/// An opened collection store.
pub struct Store {
    root: PathBuf,
    fs: Arc<FilesystemStore>,
    crs: Option<Crs>,
    dsms: Vec<DsmMeta>,
    /// DSM id -> index in `dsms` ([`Store::find`] in O(1): callers look up
    /// every pose or pair by id, which a scan made O(N²) at 10^4+ DSMs).
    index: HashMap<String, usize>,
    /// Catalogued DSMs left out at open, with the reason (see [`Store::open`]).
    skipped: Vec<SkippedDsm>,
    /// Per DSM, which chunks were written (None: a store written before the record).
    records: Vec<Option<Arc<ChunkRecord>>>,
    arrays: Mutex<OpenArrays>,
}

/// A DSM listed in the catalog whose group could not be used.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SkippedDsm {
    pub id: String,
    /// One line naming the file and what is wrong with it.
    pub reason: String,
}

impl std::fmt::Debug for Store {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Store")
            .field("root", &self.root)
            .field("dsms", &self.dsms.len())
            .finish()
    }
}

impl Store {
    /// Open an existing store: reads the root catalog and every DSM's metadata,
    /// validated as strictly as user input. A catalog that names a DSM twice or
    /// names a path outside the store is refused; a DSM group whose metadata is
    /// unreadable or implausible is reported (a warning naming it) and left out,
    /// so one damaged DSM never makes the whole store unreadable.
    pub fn open(path: &Path) -> Result<Store, StoreError> {
        configure_zarrs();
        alloc::reuse_freed_buffers();
        if !path.join("zarr.json").is_file() {
            return Err(StoreError::NotAStore {
                path: path.display().to_string(),
                reason: "no zarr.json".into(),
            });
        }
        let root_attrs = catalog::read_root(path)?;
        validate::check_root(&root_attrs)
            .map_err(|m| StoreError::invalid(&path.join("zarr.json"), m))?;
        let (mut dsms, mut skipped) = (Vec::new(), Vec::new());
        for id in &root_attrs.dsms {
            match catalog::read_valid_dsm(path, id, root_attrs.crs.as_ref()) {
                Ok(meta) => dsms.push(meta),
                Err(e) => {
                    tracing::warn!("{e}; DSM \"{id}\" left out (run dsmstream check)");
                    skipped.push(SkippedDsm {
                        id: id.clone(),
                        reason: e.to_string(),
                    });
                }
            }
        }
        let records = dsms
            .iter()
            .map(|m: &DsmMeta| m.chunk_record.clone().map(Arc::new))
            .collect();
        let index = dsms
            .iter()
            .enumerate()
            .map(|(i, m)| (m.id.clone(), i))
            .collect();
        let fs = FilesystemStore::new(path).map_err(|e| StoreError::zarr(path.display(), e))?;
        Ok(Store {
            root: path.to_path_buf(),
            fs: Arc::new(fs),
            crs: root_attrs.crs,
            dsms,
            index,
            skipped,
            records,
            arrays: Mutex::new(OpenArrays::new(MAX_OPEN_ARRAYS)),
        })
    }

    /// Catalogued DSMs left out at open because their group is damaged.
    pub fn skipped(&self) -> &[SkippedDsm] {
        &self.skipped
    }

    /// The error of a chunk of DSM number `dsm` that could not be read.
    pub fn chunk_error(&self, dsm: usize, source: ChunkReadError) -> StoreError {
        StoreError::Chunk {
            store: self.root.display().to_string(),
            id: self
                .dsms
                .get(dsm)
                .map_or_else(String::new, |m| m.id.clone()),
            source,
        }
    }

    /// Which chunks of DSM number `dsm` were written (None for stores written
    /// before the record existed: a missing chunk then reads as no-data).
    pub fn chunk_record(&self, dsm: usize) -> Option<&Arc<ChunkRecord>> {
        self.records.get(dsm).and_then(Option::as_ref)
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn dsms(&self) -> &[DsmMeta] {
        &self.dsms
    }

    /// The collection's CRS (None for an empty store).
    pub fn crs(&self) -> Option<&Crs> {
        self.crs.as_ref()
    }

    /// Index of the DSM with this id.
    pub fn find(&self, id: &str) -> Option<usize> {
        self.index.get(id).copied()
    }

    /// The zarrs array of one level (opened on first use, then shared).
    pub fn array(&self, dsm: usize, level: usize) -> Result<Arc<LevelArray>, StoreError> {
        let no_such = || StoreError::NoSuchLevel {
            store: self.root.display().to_string(),
            dsm,
            level,
        };
        let meta = self.dsms.get(dsm).ok_or_else(no_such)?;
        if level >= meta.levels.len() {
            return Err(no_such());
        }
        let mut arrays = self.arrays.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(a) = arrays.get((dsm, level)) {
            return Ok(a);
        }
        let node = format!("/{}/{}", meta.id, level);
        let mut array = Array::open(self.fs.clone(), &node)
            .map_err(|e| StoreError::zarr(self.root.join(&node[1..]).display(), e))?;
        validate::check_array(&array, &meta.levels[level])
            .map_err(|m| StoreError::invalid(&self.root.join(&node[1..]).join("zarr.json"), m))?;
        // georeferencing attributes are for other tools; the catalog has them
        array.attributes_mut().clear();
        let array = Arc::new(array);
        arrays.insert((dsm, level), array.clone());
        Ok(array)
    }
}

#[cfg(test)]
mod tests_chunks;
#[cfg(test)]
mod tests_ingest;
#[cfg(test)]
mod tests_round_trip;
#[cfg(test)]
mod tests_support;
