//! The poses of every DSM of a store, by store index: read from poses.json (or any
//! file with `{"poses": [{"id", "matrix_world"}]}`, see [`PoseList`]) and
//! checked against the store (every DSM has exactly one pose, no pose names an
//! unknown DSM, same CRS), or the identity for the raw collection.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use super::corrected::PoseXf;
use super::FuseError;
use crate::poses::{PoseList, PosesFile};
use crate::store::Store;

/// One pose per DSM of the store (index = store index).
#[derive(Clone, Debug)]
pub struct PoseSet {
    /// The file the poses came from; None for the identity set.
    pub source: Option<PathBuf>,
    pub poses: Vec<PoseXf>,
    /// The parsed file (edges and their residuals, for plots) when it is a
    /// complete poses.json.
    pub file: Option<PosesFile>,
}

impl PoseSet {
    /// Every DSM as it is (no correction).
    pub fn identity(store: &Store) -> PoseSet {
        PoseSet {
            source: None,
            poses: vec![PoseXf::identity(); store.dsms().len()],
            file: None,
        }
    }

    /// Read `path` and match its poses to the store's DSMs by id.
    pub fn from_file(store: &Store, path: &Path) -> Result<PoseSet, FuseError> {
        let list = PoseList::read(path)?;
        PoseSet::from_list(store, path, list)
    }

    /// Match an already parsed poses.json (named `path` in messages) to the store.
    pub fn from_parsed(store: &Store, path: &Path, file: PosesFile) -> Result<PoseSet, FuseError> {
        PoseSet::from_list(store, path, PoseList::from(file))
    }

    /// Match already read poses (named `path` in messages) to the store.
    pub fn from_list(store: &Store, path: &Path, file: PoseList) -> Result<PoseSet, FuseError> {
        let bad = |m: String| FuseError::Input(format!("{}: {m}", path.display()));
        if let (Some(crs), Some(file_crs)) = (store.crs(), &file.crs) {
            let label = crs.label();
            if *file_crs != label {
                return Err(bad(format!(
                    "poses are for CRS {file_crs} but the store {} is {label}",
                    store.root().display()
                )));
            }
        }
        let mut seen = HashSet::new();
        let mut poses = vec![None; store.dsms().len()];
        for p in &file.poses {
            let index = store.find(&p.id).ok_or_else(|| {
                bad(format!(
                    "pose '{}' names no DSM of the store {}",
                    p.id,
                    store.root().display()
                ))
            })?;
            if !seen.insert(p.id.as_str()) {
                return Err(bad(format!("pose '{}' given twice", p.id)));
            }
            poses[index] = Some(PoseXf::new(&p.matrix_world));
        }
        let poses = poses
            .into_iter()
            .zip(store.dsms())
            .map(|(p, d)| p.ok_or_else(|| bad(format!("no pose for DSM '{}' of the store", d.id))))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(PoseSet {
            source: Some(path.to_path_buf()),
            poses,
            file: file.full,
        })
    }

    /// Label for reports: the file name, or "none (identity)".
    pub fn label(&self) -> String {
        match &self.source {
            Some(p) => p.display().to_string(),
            None => "none (identity)".to_string(),
        }
    }
}
