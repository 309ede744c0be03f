//! Ingest: convert input rasters into the collection store, once.
//!
//! Steps: expand the inputs into (id, file); decide per file whether it is new,
//! changed or unchanged (source size + mtime, skipped unless `force`); open and
//! validate the headers of *every* file to ingest (size, metric CRS, same CRS
//! as the collection, north-up) before writing anything; then stream each
//! file, a chunk row at a time, into `<id>.tmp-<pid>/` (level 0 and overviews
//! in one pass, see `pyramid`), rename it to `<id>/` and only then list it in
//! the root catalog (in batches whose cost stays a small part of the run, see
//! `commit`). A file that turns out to hold no valid pixel is refused
//! when its pass ends; DSMs committed before it stay.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use crossbeam::channel::bounded;
use zarrs::filesystem::FilesystemStore;

use super::catalog::{self, DsmMeta, StorageSettings};
use super::chunks::ChunkRecord;
use super::commit::CatalogBatch;
use super::files::{self, InputFile};
use super::plan::{
    check_options, create_store, empty_catalog, plan_all, read_existing, recover_locked,
    undo_create, validate_all,
};
use super::pyramid::{level_shapes, PyramidWriter};
use super::source::{RowSource, SourceError, SourceOpener};
use super::stats::HeightAccumulator;
use super::StoreError;

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct IngestOptions {
    pub storage: StorageSettings,
    /// Re-ingest DSMs whose source did not change (and replace same-id DSMs
    /// that came from another file).
    pub force: bool,
    /// The CRS DSMs in longitude and latitude or in other projected CRSs
    /// are put into (`--utm-zone`, `--crs`; default: the collection's, or
    /// the UTM zone of their centre).
    pub target: Option<super::warp::CrsChoice>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DsmAction {
    /// New in the store.
    Ingested,
    /// Was in the store; source changed or `force`.
    Replaced,
    /// Was in the store with the same source size and mtime.
    Skipped,
}

/// What happened to one input.
#[derive(Clone, Debug)]
pub struct DsmOutcome {
    pub id: String,
    pub path: PathBuf,
    pub action: DsmAction,
    pub width: u64,
    pub height: u64,
    pub levels: usize,
    pub valid_count: u64,
    /// Bytes of the DSM's group on disk.
    pub stored_bytes: u64,
    pub seconds: f64,
    /// The side files its georeferencing was read from (none when skipped).
    pub georeferenced_by: Vec<PathBuf>,
    /// Put from longitude and latitude into a UTM zone.
    pub warped: Option<super::warp::Warped>,
}

#[derive(Clone, Debug)]
pub struct IngestReport {
    pub store: PathBuf,
    pub outcomes: Vec<DsmOutcome>,
}

#[derive(Debug, thiserror::Error)]
pub enum IngestError {
    /// A problem with an input file or the store path (exit code 2).
    #[error("{0}")]
    BadInput(String),
    #[error(transparent)]
    Store(#[from] StoreError),
    /// Writing one input into the store failed (disk full, permissions...);
    /// the store keeps the DSMs ingested before it.
    #[error("ingesting {input}: {source}")]
    Write {
        input: String,
        #[source]
        source: StoreError,
    },
    /// Reading a source failed for a reason other than its content.
    #[error("{0}")]
    Source(SourceError),
}

impl IngestError {
    /// The input files or the store are the problem (exit code 2): a bad file,
    /// a damaged or read-only store.
    pub fn is_bad_input(&self) -> bool {
        match self {
            IngestError::BadInput(_) => true,
            IngestError::Store(e) | IngestError::Write { source: e, .. } => matches!(
                e,
                StoreError::ReadOnly { .. }
                    | StoreError::Invalid { .. }
                    | StoreError::NotAStore { .. }
                    | StoreError::Json { .. }
            ),
            IngestError::Source(_) => false,
        }
    }
}

impl From<SourceError> for IngestError {
    fn from(e: SourceError) -> Self {
        if e.bad_input {
            IngestError::BadInput(e.message)
        } else {
            IngestError::Source(e)
        }
    }
}

/// Progress callbacks (rows of level 0); every method defaults to nothing.
pub trait IngestProgress {
    /// The number of input DSMs, once the inputs are listed (skipped ones included).
    fn planned(&self, _dsms: usize) {}
    fn dsm_started(&self, _id: &str, _rows_total: u64) {}
    fn rows_done(&self, _rows: u64) {}
    fn dsm_finished(&self, _outcome: &DsmOutcome) {}
}

/// No progress output.
pub struct NoProgress;
impl IngestProgress for NoProgress {}

/// Ingest GeoTIFF files (or directories of them) into the store at `store_path`.
pub fn ingest(
    inputs: &[PathBuf],
    store_path: &Path,
    options: &IngestOptions,
    progress: &dyn IngestProgress,
) -> Result<IngestReport, IngestError> {
    ingest_with(
        inputs,
        store_path,
        options,
        progress,
        &super::vrt::open_input,
    )
}

/// [`ingest`] with any source opener (tests use in-memory sources).
pub fn ingest_with(
    inputs: &[PathBuf],
    store_path: &Path,
    options: &IngestOptions,
    progress: &dyn IngestProgress,
    open: &SourceOpener,
) -> Result<IngestReport, IngestError> {
    check_options(&options.storage)?;
    let files = files::expand_inputs(inputs).map_err(IngestError::BadInput)?;
    let attrs = match read_existing(store_path)? {
        Some(_) => recover_locked(store_path)?,
        None => empty_catalog(),
    };
    let plan = plan_all(store_path, &attrs, files, options.force)?;
    let (mut outcomes, todo) = (plan.skipped, plan.todo);
    progress.planned(outcomes.len() + todo.len());
    for outcome in &outcomes {
        progress.dsm_finished(outcome);
    }
    let paths: Vec<&Path> = todo.iter().map(|(f, _)| f.path.as_path()).collect();
    let target = super::warp::choose_target(attrs.crs.as_ref(), options.target, &paths, open)?;
    let open = &|path: &Path| super::warp::open_in_target(open, target.as_ref(), path);
    validate_all(store_path, &attrs, &todo, open)?;
    if !todo.is_empty() {
        let created = create_store(store_path)?;
        let written = write_all(store_path, todo, options, progress, open, &mut outcomes);
        if written.is_err() {
            undo_create(store_path, created);
        }
        written?;
    }
    Ok(IngestReport {
        store: store_path.to_path_buf(),
        outcomes,
    })
}

/// Write and commit every planned DSM, in order, appending their outcomes.
fn write_all(
    store_path: &Path,
    todo: Vec<(InputFile, DsmAction)>,
    options: &IngestOptions,
    progress: &dyn IngestProgress,
    open: &SourceOpener,
    outcomes: &mut Vec<DsmOutcome>,
) -> Result<(), IngestError> {
    super::alloc::reuse_freed_buffers();
    let fs =
        FilesystemStore::new(store_path).map_err(|e| StoreError::zarr(store_path.display(), e))?;
    let fs = Arc::new(fs);
    let mut batch = CatalogBatch::new(store_path);
    for (file, action) in todo {
        let written = ingest_one(
            &fs, store_path, file, action, options, progress, open, &mut batch,
        );
        let outcome = match written {
            Ok(outcome) => outcome,
            Err(e) => {
                // DSMs committed before the failing one stay listed.
                if let Err(flush) = batch.flush() {
                    tracing::warn!("{flush}");
                }
                return Err(e);
            }
        };
        progress.dsm_finished(&outcome);
        outcomes.push(outcome);
    }
    batch.flush()?;
    Ok(())
}

/// Write one DSM, commit it (rename; catalog now or with a later batch) and
/// describe what was done.
#[allow(clippy::too_many_arguments)]
fn ingest_one(
    fs: &Arc<FilesystemStore>,
    store_path: &Path,
    file: InputFile,
    action: DsmAction,
    options: &IngestOptions,
    progress: &dyn IngestProgress,
    open: &SourceOpener,
    batch: &mut CatalogBatch,
) -> Result<DsmOutcome, IngestError> {
    let started = Instant::now();
    let mut source = open(&file.path)?;
    let meta = write_dsm(
        fs,
        store_path,
        &file,
        source.as_mut(),
        &options.storage,
        progress,
    )?;
    let tmp = store_path.join(files::tmp_name(&file.id));
    batch
        .commit(&file.id, &tmp, &meta.crs)
        .map_err(|e| match e {
            StoreError::Invalid { message, .. } => {
                IngestError::BadInput(format!("{}: {message}", file.path.display()))
            }
            other => IngestError::Write {
                input: file.path.display().to_string(),
                source: other,
            },
        })?;
    let outcome = DsmOutcome {
        stored_bytes: files::dir_bytes(&store_path.join(&file.id)),
        seconds: started.elapsed().as_secs_f64(),
        georeferenced_by: source.raster().georeferenced_by.clone(),
        ..outcome_of(&file, action, &meta)
    };
    tracing::info!(dsm = %file.id, seconds = outcome.seconds, "dsm ingested");
    Ok(outcome)
}

/// The outcome fields known from the metadata (bytes and seconds left at zero).
pub(super) fn outcome_of(file: &InputFile, action: DsmAction, meta: &DsmMeta) -> DsmOutcome {
    DsmOutcome {
        id: file.id.clone(),
        path: file.path.clone(),
        action,
        width: meta.width,
        height: meta.height,
        levels: meta.levels.len(),
        valid_count: meta.valid_count,
        stored_bytes: 0,
        seconds: 0.0,
        georeferenced_by: Vec::new(),
        warped: meta.reprojected.clone(),
    }
}

/// Stream one source into `<store>/<id>.tmp-<pid>/`, return its metadata.
fn write_dsm(
    fs: &Arc<FilesystemStore>,
    store: &Path,
    file: &InputFile,
    source: &mut dyn RowSource,
    settings: &StorageSettings,
    progress: &dyn IngestProgress,
) -> Result<DsmMeta, IngestError> {
    let tmp = store.join(files::tmp_name(&file.id));
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| StoreError::io(&tmp, e))?;
    }
    let result = write_levels(fs, &tmp, file, source, settings, progress);
    if result.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    result.map_err(|e| match e {
        IngestError::Store(source) => IngestError::Write {
            input: file.path.display().to_string(),
            source,
        },
        other => other,
    })
}

fn write_levels(
    fs: &Arc<FilesystemStore>,
    tmp: &Path,
    file: &InputFile,
    source: &mut dyn RowSource,
    settings: &StorageSettings,
    progress: &dyn IngestProgress,
) -> Result<DsmMeta, IngestError> {
    let raster = source.raster().clone();
    let (w, h) = (raster.width, raster.height);
    let source_info = files::source_info(&file.path)?;
    let shapes = level_shapes(w, h, settings);
    let level_attributes = |k: usize| {
        super::geo_attrs::level_attributes(
            &raster.geotransform.overview(k as u32),
            &raster.crs,
            shapes[k].height,
            shapes[k].width,
        )
    };
    let mut pyramid = PyramidWriter::create(fs.clone(), tmp, &shapes, settings, &level_attributes)?;
    progress.dsm_started(&file.id, h);
    let acc = stream_rows(source, settings.chunk, &mut pyramid, progress)?;
    let empty_runs = pyramid.finish()?;
    let Some(height_stats) = acc.height_stats() else {
        return Err(IngestError::BadInput(format!(
            "{}: no valid pixels (every pixel is no-data)",
            file.path.display()
        )));
    };
    let meta = DsmMeta {
        id: file.id.clone(),
        width: w,
        height: h,
        geotransform: raster.geotransform,
        crs: raster.crs.clone(),
        nodata: raster.nodata,
        valid_count: acc.valid_count(),
        height_stats,
        footprint: acc.footprint(&raster.geotransform, w, h),
        levels: shapes,
        source: source_info,
        source_dtype: raster.dtype.clone(),
        storage: *settings,
        chunk_record: Some(ChunkRecord { empty_runs }),
        reprojected: source.warped(),
    };
    super::validate::check_dsm(&meta)
        .map_err(|m| IngestError::BadInput(format!("{}: {m}", file.path.display())))?;
    catalog::write_group_attributes(tmp, &meta.to_attributes())?;
    Ok(meta)
}

/// Read the source a chunk row at a time on a reader thread (decode, then
/// statistics) while this thread writes the previous chunk row into the
/// pyramid, so the stages overlap. Two row buffers circulate between the
/// threads: memory is two chunk rows of level 0 plus the pyramid's buffers.
fn stream_rows(
    source: &mut dyn RowSource,
    chunk: u64,
    pyramid: &mut PyramidWriter,
    progress: &dyn IngestProgress,
) -> Result<HeightAccumulator, IngestError> {
    let (w, h) = (source.raster().width, source.raster().height);
    let path = source.raster().path.clone();
    let (full_tx, full_rx) = bounded::<(u64, Vec<f32>)>(1);
    let (empty_tx, empty_rx) = bounded::<Vec<f32>>(2);
    for _ in 0..2 {
        empty_tx.send(Vec::new()).expect("the receiver is alive");
    }
    std::thread::scope(|scope| {
        let reader = scope.spawn(move || -> Result<HeightAccumulator, IngestError> {
            let mut acc = HeightAccumulator::default();
            let mut row0 = 0;
            while row0 < h {
                let rows = chunk.min(h - row0);
                let Ok(mut data) = empty_rx.recv() else {
                    break; // the writer stopped (its error is reported)
                };
                source.read_rows_into(row0, rows, &mut data)?;
                if data.len() as u64 != w * rows {
                    return Err(IngestError::Source(SourceError {
                        message: format!(
                            "{}: read {} values for rows {row0}..{}, expected {}",
                            path.display(),
                            data.len(),
                            row0 + rows,
                            w * rows
                        ),
                        bad_input: false,
                    }));
                }
                acc.add_rows(&mut data, w as usize, row0);
                if full_tx.send((rows, data)).is_err() {
                    break;
                }
                row0 += rows;
            }
            Ok(acc)
        });
        let mut written = Ok(());
        for (rows, data) in full_rx.iter() {
            written = pyramid.push_rows(&data);
            if written.is_err() {
                break;
            }
            progress.rows_done(rows);
            let _ = empty_tx.send(data);
        }
        drop((full_rx, empty_tx));
        let acc = reader.join().expect("the ingest reader thread panicked")?;
        written?;
        Ok(acc)
    })
}
