//! `dsmstream check`: verify a store end to end and say what to re-ingest.
//!
//! Per DSM of the catalog: the metadata (validated as at open), each level's
//! Zarr array metadata against it, every chunk (a file for each chunk the
//! chunk record says holds data, decodable to a full chunk; no file where it
//! says empty), and the statistics recomputed from level 0 (valid count,
//! height min/max/mean/std, footprint) against the catalog. Level 0 is read a
//! chunk row at a time, so memory is one chunk row of level 0. The catalog
//! itself (ids, duplicates) is checked first; a DSM with an unsafe id is not
//! read at all.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use rayon::prelude::*;
use serde::Serialize;
use zarrs::array::Array;
use zarrs::filesystem::FilesystemStore;

use super::catalog::{self, DsmMeta};
use super::chunks::chunk_grid;
use super::stats::HeightAccumulator;
use super::{configure_zarrs, validate, LevelArray, StoreError};

/// Most problems listed per DSM (the count says how many there were).
const MAX_LISTED: usize = 12;

/// The verdict on one DSM.
#[derive(Clone, Debug, Serialize)]
pub struct DsmCheck {
    pub id: String,
    /// The source file recorded at ingest (when the metadata was readable).
    pub source: Option<String>,
    pub ok: bool,
    /// Chunk files read and decoded.
    pub chunks_read: u64,
    /// Problems found (at most [`MAX_LISTED`] listed), one line each.
    pub problems: Vec<String>,
    pub problem_count: usize,
    /// A note that is not damage (e.g. a store written before chunk records).
    pub note: Option<String>,
}

/// The verdict on the whole store.
#[derive(Clone, Debug, Serialize)]
pub struct CheckReport {
    pub store: PathBuf,
    /// Problems of the root catalog itself (duplicate or unsafe ids).
    pub catalog_problems: Vec<String>,
    pub dsms: Vec<DsmCheck>,
}

impl CheckReport {
    /// True when nothing is damaged.
    pub fn ok(&self) -> bool {
        self.catalog_problems.is_empty() && self.dsms.iter().all(|d| d.ok)
    }

    /// The damaged DSMs.
    pub fn damaged(&self) -> impl Iterator<Item = &DsmCheck> {
        self.dsms.iter().filter(|d| !d.ok)
    }
}

/// Problems of one DSM, capped at [`MAX_LISTED`] lines.
#[derive(Default)]
struct Problems {
    listed: Vec<String>,
    count: usize,
}

impl Problems {
    fn add(&mut self, problem: String) {
        self.count += 1;
        if self.listed.len() < MAX_LISTED {
            self.listed.push(problem);
        }
    }
}

/// Check the store at `root` (see the module doc). Errors only when `root`
/// is not a store at all; damage is reported in the [`CheckReport`].
pub fn check_store(root: &Path) -> Result<CheckReport, StoreError> {
    configure_zarrs();
    let attrs = catalog::read_root(root)?;
    let mut catalog_problems = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut ids = Vec::new();
    for id in &attrs.dsms {
        if let Err(m) = validate::check_id(id) {
            catalog_problems.push(format!("{}: {m}", root.join("zarr.json").display()));
        } else if !seen.insert(id.clone()) {
            catalog_problems.push(format!(
                "{}: the catalog lists DSM \"{id}\" twice; remove one entry",
                root.join("zarr.json").display()
            ));
        } else {
            ids.push(id.clone());
        }
    }
    let fs = Arc::new(FilesystemStore::new(root).map_err(|e| StoreError::zarr(root.display(), e))?);
    let dsms = ids
        .iter()
        .map(|id| check_dsm(root, &fs, id, attrs.crs.as_ref()))
        .collect();
    Ok(CheckReport {
        store: root.to_path_buf(),
        catalog_problems,
        dsms,
    })
}

fn check_dsm(
    root: &Path,
    fs: &Arc<FilesystemStore>,
    id: &str,
    crs: Option<&crate::geo::Crs>,
) -> DsmCheck {
    let mut problems = Problems::default();
    let mut chunks_read = 0;
    let mut note = None;
    let source = catalog::read_dsm(&root.join(id))
        .ok()
        .map(|m| m.source.path);
    match catalog::read_valid_dsm(root, id, crs) {
        Err(e) => problems.add(e.to_string()),
        Ok(meta) => {
            if meta.chunk_record.is_none() {
                note = Some(
                    "no chunk record (ingested by an older version): a missing chunk file cannot be told from an empty chunk; re-ingest with --force to add one".into(),
                );
            }
            chunks_read = check_levels(root, fs, &meta, &mut problems);
        }
    }
    tracing::info!(
        dsm = id,
        problems = problems.count,
        chunks_read,
        "dsm checked"
    );
    DsmCheck {
        id: id.to_string(),
        source,
        ok: problems.count == 0,
        chunks_read,
        problems: problems.listed,
        problem_count: problems.count,
        note,
    }
}

/// Every level's array and chunks, then level 0's statistics; returns the
/// number of chunks read.
fn check_levels(
    root: &Path,
    fs: &Arc<FilesystemStore>,
    meta: &DsmMeta,
    problems: &mut Problems,
) -> u64 {
    let mut read = 0;
    let mut stats = HeightAccumulator::default();
    for (k, level) in meta.levels.iter().enumerate() {
        let dir = root.join(&meta.id).join(k.to_string());
        let array = match Array::open(fs.clone(), &format!("/{}/{k}", meta.id)) {
            Ok(a) => a,
            Err(e) => {
                problems.add(format!("{}: {e}", dir.join("zarr.json").display()));
                continue;
            }
        };
        if let Err(m) = validate::check_array(&array, level) {
            problems.add(format!("{}: {m}", dir.join("zarr.json").display()));
            continue;
        }
        let (chunks_x, chunks_y) = chunk_grid(level);
        for cy in 0..chunks_y {
            let row = read_chunk_row(&array, meta, k, &dir, cy, chunks_x, problems);
            read += row.read;
            if k == 0 {
                let mut data = row.values;
                stats.add_rows(&mut data, level.width as usize, cy * level.chunk);
            }
        }
    }
    if problems.count == 0 {
        compare_stats(
            &root.join(&meta.id).join("zarr.json"),
            meta,
            &stats,
            problems,
        );
    }
    read
}

/// One chunk read: its values (None when empty), or the problem; and
/// whether a file was read.
type ChunkResult = (Result<Option<Vec<f32>>, String>, bool);

struct ChunkRow {
    /// Whole image rows of the chunk row, row-major (NaN where unreadable).
    values: Vec<f32>,
    read: u64,
}

/// Read chunk row `cy` of a level (chunks in parallel), checking each chunk
/// against the record; returns the pixels as image rows.
fn read_chunk_row(
    array: &LevelArray,
    meta: &DsmMeta,
    level: usize,
    dir: &Path,
    cy: u64,
    chunks_x: u64,
    problems: &mut Problems,
) -> ChunkRow {
    let lm = &meta.levels[level];
    let c = lm.chunk as usize;
    let (w, rows) = (
        lm.width as usize,
        lm.chunk.min(lm.height - cy * lm.chunk) as usize,
    );
    let record = meta.chunk_record.as_ref();
    let results: Vec<ChunkResult> = (0..chunks_x)
        .into_par_iter()
        .map(|cx| {
            let file = dir.join(format!("c/{cy}/{cx}"));
            let empty = record.is_some_and(|r| r.is_empty(level, chunks_x, cy, cx));
            let exists = file.is_file();
            let result = match (empty, exists, record.is_some()) {
                (true, true, _) => Err(format!(
                    "{}: chunk file present where the chunk record says empty",
                    file.display()
                )),
                (true, false, _) | (false, false, false) => Ok(None),
                (false, false, true) => Err(format!("{}: missing chunk file", file.display())),
                (false, true, _) => match array.retrieve_chunk::<Vec<f32>>(&[cy, cx]) {
                    Ok(v) if v.len() == c * c => Ok(Some(v)),
                    Ok(v) => Err(format!(
                        "{}: {} values, expected {}",
                        file.display(),
                        v.len(),
                        c * c
                    )),
                    Err(e) => Err(format!("{}: unreadable chunk ({e})", file.display())),
                },
            };
            (result, exists && !empty)
        })
        .collect();
    let mut values = vec![f32::NAN; w * rows];
    let mut read = 0;
    for (cx, (result, attempted)) in results.into_iter().enumerate() {
        read += u64::from(attempted);
        match result {
            Err(p) => problems.add(p),
            Ok(None) => {}
            Ok(Some(chunk)) => {
                let col0 = cx * c;
                let cols = c.min(w - col0);
                for r in 0..rows {
                    values[r * w + col0..r * w + col0 + cols]
                        .copy_from_slice(&chunk[r * c..r * c + cols]);
                }
            }
        }
    }
    ChunkRow { values, read }
}

/// Statistics recomputed from level 0 against the catalog's.
fn compare_stats(file: &Path, meta: &DsmMeta, stats: &HeightAccumulator, problems: &mut Problems) {
    let file = file.display();
    if stats.valid_count() != meta.valid_count {
        problems.add(format!(
            "{file}: level 0 has {} valid pixels, the catalog says {}",
            stats.valid_count(),
            meta.valid_count
        ));
        return;
    }
    let Some(s) = stats.height_stats() else {
        return;
    };
    let want = &meta.height_stats;
    let scale = want.min.abs().max(want.max.abs()) + 1.0;
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * scale + 1e-12;
    let close_std = |a: f64, b: f64| (a - b).abs() <= 1e-6 * (b.abs() + 1e-3);
    if s.min != want.min
        || s.max != want.max
        || !close(s.mean, want.mean)
        || !close_std(s.std, want.std)
    {
        problems.add(format!(
            "{file}: level 0 heights {s:?} differ from the catalog's {want:?}"
        ));
    }
    let footprint = stats.footprint(&meta.geotransform, meta.width, meta.height);
    if footprint != meta.footprint {
        problems.add(format!(
            "{file}: level 0 footprint {:?} differs from the catalog's {:?}",
            footprint.to_array(),
            meta.footprint.to_array()
        ));
    }
}
