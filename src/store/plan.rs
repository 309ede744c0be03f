//! Deciding what an ingest run will do, before it writes anything: option
//! checks, the existing catalog (or none), new / changed / unchanged per input,
//! and header validation (size, metric CRS, one CRS per collection, north-up).

use std::path::Path;

use super::catalog::{self, RootAttrs, StorageSettings};
use super::files::{self, InputFile};
use super::ingest::{outcome_of, DsmAction, DsmOutcome, IngestError};
use super::source::SourceOpener;
use super::source::SourceRaster;
use crate::raster::Crs;

pub(super) fn check_options(s: &StorageSettings) -> Result<(), IngestError> {
    if !(16..=8192).contains(&s.chunk) {
        return Err(IngestError::BadInput(format!(
            "chunk size {} px is out of range (16 ..= 8192)",
            s.chunk
        )));
    }
    Ok(())
}

/// The catalog of an existing store, None when the path does not exist yet
/// (or is an empty directory).
pub(super) fn read_existing(store: &Path) -> Result<Option<RootAttrs>, IngestError> {
    if store.join("zarr.json").exists() {
        return catalog::read_root(store)
            .map(Some)
            .map_err(|e| IngestError::BadInput(e.to_string()));
    }
    match std::fs::read_dir(store) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(IngestError::BadInput(format!(
            "{}: cannot use as a store: {e}",
            store.display()
        ))),
        Ok(mut entries) => match entries.next() {
            None => Ok(None),
            Some(_) => Err(IngestError::BadInput(format!(
                "{}: exists, is not empty and is not a dsmstream store (no zarr.json)",
                store.display()
            ))),
        },
    }
}

pub(super) fn create_store(store: &Path, attrs: &RootAttrs) -> Result<(), IngestError> {
    let cannot = |e: &dyn std::fmt::Display| {
        IngestError::BadInput(format!("{}: cannot write the store: {e}", store.display()))
    };
    std::fs::create_dir_all(store).map_err(|e| cannot(&e))?;
    if !store.join("zarr.json").exists() {
        catalog::write_root(store, attrs).map_err(|e| cannot(&e))?;
    }
    Ok(())
}

/// New, changed, unchanged, or a clash with a same-id DSM from another file.
fn plan_one(
    store: &Path,
    attrs: &RootAttrs,
    file: &InputFile,
    force: bool,
) -> Result<DsmAction, IngestError> {
    if !attrs.dsms.contains(&file.id) {
        return Ok(DsmAction::Ingested);
    }
    let old = catalog::read_dsm(&store.join(&file.id))?;
    if force {
        return Ok(DsmAction::Replaced);
    }
    let now = files::source_info(&file.path)?;
    if old.source.path != now.path {
        return Err(IngestError::BadInput(format!(
            "{}: DSM id \"{}\" is already in the store, from {}; rename the file or use --force to replace it",
            file.path.display(),
            file.id,
            old.source.path
        )));
    }
    if old.source == now {
        Ok(DsmAction::Skipped)
    } else {
        tracing::info!(dsm = %file.id, "source changed");
        Ok(DsmAction::Replaced)
    }
}

/// Header checks; `collection` is the CRS every DSM must share and where it came from.
fn validate(
    raster: &SourceRaster,
    path: &Path,
    collection: &mut Option<(Crs, String)>,
) -> Result<(), IngestError> {
    let file = path.display();
    let bad = |msg: String| Err(IngestError::BadInput(format!("{file}: {msg}")));
    if raster.width == 0 || raster.height == 0 {
        return bad(format!(
            "empty raster ({} x {} px)",
            raster.width, raster.height
        ));
    }
    if raster.crs.is_geographic {
        return bad(format!(
            "geographic CRS {} (degrees) is not a metric frame; reproject to a projected CRS first, e.g. gdalwarp -t_srs EPSG:326xx",
            raster.crs.label()
        ));
    }
    if !raster.geotransform.is_north_up() {
        return bad(format!(
            "geotransform {:?} is rotated, sheared or not north-up; only north-up rasters are supported (gdalwarp can resample it)",
            raster.geotransform.0
        ));
    }
    match collection {
        Some((crs, origin)) if !crs.same_as(&raster.crs) => bad(format!(
            "CRS {} differs from the collection's CRS {} (from {origin}); reproject it to the same CRS",
            raster.crs.label(),
            crs.label()
        )),
        Some(_) => Ok(()),
        None => {
            *collection = Some((raster.crs.clone(), file.to_string()));
            Ok(())
        }
    }
}

/// What a run will do: DSMs skipped as unchanged, and files to write.
pub(super) struct RunPlan {
    pub skipped: Vec<DsmOutcome>,
    pub todo: Vec<(InputFile, DsmAction)>,
}

/// Split the inputs into skipped DSMs and files to write.
pub(super) fn plan_all(
    store: &Path,
    attrs: &RootAttrs,
    files: Vec<InputFile>,
    force: bool,
) -> Result<RunPlan, IngestError> {
    let mut skipped = Vec::new();
    let mut todo = Vec::new();
    for file in files {
        match plan_one(store, attrs, &file, force)? {
            DsmAction::Skipped => {
                let meta = catalog::read_dsm(&store.join(&file.id))?;
                let mut outcome = outcome_of(&file, DsmAction::Skipped, &meta);
                outcome.stored_bytes = files::dir_bytes(&store.join(&file.id));
                skipped.push(outcome);
            }
            action => todo.push((file, action)),
        }
    }
    Ok(RunPlan { skipped, todo })
}

/// Open every file to write and check its header, all before anything is written.
pub(super) fn validate_all(
    store: &Path,
    attrs: &RootAttrs,
    todo: &[(InputFile, DsmAction)],
    open: &SourceOpener,
) -> Result<(), IngestError> {
    let mut collection: Option<(Crs, String)> = attrs
        .crs
        .clone()
        .map(|c| (c, format!("the store {}", store.display())));
    for (file, _) in todo {
        let source = open(&file.path)?;
        validate(source.raster(), &file.path, &mut collection)?;
    }
    Ok(())
}
