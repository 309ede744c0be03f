//! The collection store: one Zarr v3 group per collection, one multiscale group
//! per DSM, read through the shared chunk cache.
//!
//! Layout of `<store>.zarr/`:
//! ```text
//! zarr.json            group; attributes {"dsmstream": {version, crs, dsms: [ids]}}
//! <id>/zarr.json       group; attributes {"dsmstream": DsmMeta, "multiscales": [...]}
//! <id>/0, <id>/1, ...  float32 arrays ["y","x"], NaN fill, square chunks, zstd;
//!                      level k+1 = 2x2 mean of the valid pixels of level k
//! ```
//! [`Store`] reads the catalog at open and opens the zarrs arrays lazily (once
//! per DSM and level); [`StoreGrid`] gives pixel access to one level; `ingest`
//! writes the store from GeoTIFFs (or any [`source::RowSource`]).

pub mod catalog;
mod files;
pub mod grid;
pub mod ingest;
mod plan;
mod pyramid;
pub mod source;
mod stats;
pub mod view;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use zarrs::array::Array;
use zarrs::filesystem::FilesystemStore;

pub use catalog::{
    Compression, DsmMeta, HeightStats, LevelMeta, SourceInfo, StorageSettings, STORE_VERSION,
};
pub use grid::StoreGrid;
pub use ingest::{ingest, IngestError, IngestOptions, IngestReport};
pub use view::StorePyramid;

use crate::raster::Crs;

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
            StoreError::NotAStore { .. } | StoreError::Json { .. } | StoreError::Io { .. }
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
    arrays: Mutex<HashMap<(usize, usize), Arc<LevelArray>>>,
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
    /// Open an existing store: reads the root catalog and every DSM's metadata.
    pub fn open(path: &Path) -> Result<Store, StoreError> {
        configure_zarrs();
        if !path.join("zarr.json").is_file() {
            return Err(StoreError::NotAStore {
                path: path.display().to_string(),
                reason: "no zarr.json".into(),
            });
        }
        let root_attrs = catalog::read_root(path)?;
        let dsms = root_attrs
            .dsms
            .iter()
            .map(|id| catalog::read_dsm(&path.join(id)))
            .collect::<Result<Vec<_>, _>>()?;
        let fs = FilesystemStore::new(path).map_err(|e| StoreError::zarr(path.display(), e))?;
        Ok(Store {
            root: path.to_path_buf(),
            fs: Arc::new(fs),
            crs: root_attrs.crs,
            dsms,
            arrays: Mutex::new(HashMap::new()),
        })
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
        self.dsms.iter().position(|d| d.id == id)
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
        if let Some(a) = arrays.get(&(dsm, level)) {
            return Ok(a.clone());
        }
        let node = format!("/{}/{}", meta.id, level);
        let array = Array::open(self.fs.clone(), &node)
            .map_err(|e| StoreError::zarr(self.root.join(&node[1..]).display(), e))?;
        let array = Arc::new(array);
        arrays.insert((dsm, level), array.clone());
        Ok(array)
    }
}

#[cfg(test)]
mod tests;
