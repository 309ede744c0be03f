//! Deciding what an ingest run will do, before it writes anything: option
//! checks, the existing catalog (or none), new / changed / unchanged per input,
//! and header validation (size, metric CRS, one CRS per collection, north-up).

use std::path::Path;

use super::catalog::{self, RootAttrs, StorageSettings, STORE_VERSION};
use super::files::{self, InputFile};
use super::ingest::{outcome_of, DsmAction, DsmOutcome, IngestError};
use super::lock::{StoreLock, LOCK_FILE};
use super::source::SourceOpener;
use super::source::SourceRaster;
use super::warp::Warped;
use super::{validate, StoreError};
use crate::geo::Crs;

pub(super) fn check_options(s: &StorageSettings) -> Result<(), IngestError> {
    let (lo, hi) = validate::CHUNK_RANGE_PX;
    if !(lo..=hi).contains(&s.chunk) {
        return Err(IngestError::BadInput(format!(
            "chunk size {} px is out of range ({lo} ..= {hi})",
            s.chunk
        )));
    }
    Ok(())
}

/// The catalog of an existing store, None when the path does not exist yet
/// (or is an empty directory, or holds only what another run creating the
/// store right now has put there).
pub(super) fn read_existing(store: &Path) -> Result<Option<RootAttrs>, IngestError> {
    let read_root = || {
        catalog::read_root(store)
            .map(Some)
            .map_err(|e| IngestError::BadInput(e.to_string()))
    };
    if store.join("zarr.json").exists() {
        return read_root();
    }
    match std::fs::read_dir(store) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(IngestError::BadInput(format!(
            "{}: cannot use as a store: {e}",
            store.display()
        ))),
        Ok(_) if files::only_leftovers(store) => Ok(None),
        // Another run creating the store wrote its catalog between the two
        // looks (concurrent ingests into a fresh store).
        Ok(_) if store.join("zarr.json").exists() => read_root(),
        Ok(_) => Err(IngestError::BadInput(format!(
            "{}: exists, is not empty and is not a dsmstream store (no zarr.json)",
            store.display()
        ))),
    }
}

/// An empty catalog.
pub(super) fn empty_catalog() -> RootAttrs {
    RootAttrs {
        version: STORE_VERSION,
        crs: None,
        dsms: Vec::new(),
    }
}

/// Under the store lock: the catalog as it is now, after repairing what
/// killed runs left behind. A read-only store is read without repair.
pub(super) fn recover_locked(store: &Path) -> Result<RootAttrs, IngestError> {
    let lock = match StoreLock::acquire(store) {
        Ok(lock) => lock,
        Err(StoreError::ReadOnly { .. }) => {
            return Ok(read_existing(store)?.unwrap_or_else(empty_catalog))
        }
        Err(e) => return Err(e.into()),
    };
    let attrs = read_existing(store)?.unwrap_or_else(empty_catalog);
    let attrs = files::recover(store, attrs)?;
    drop(lock);
    Ok(attrs)
}

/// What [`create_store`] made, to undo it when the run writes no DSM.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Created {
    pub dir: bool,
    pub catalog: bool,
}

/// Make the store folder and an empty catalog unless they exist (two runs
/// creating one store both succeed: the catalog is written under the lock).
/// Taking the lock is the write test: a read-only store fails here, before
/// anything is written.
pub(super) fn create_store(store: &Path) -> Result<Created, IngestError> {
    let dir = !store.exists();
    std::fs::create_dir_all(store)
        .map_err(|e| IngestError::from(StoreError::io_or_read_only(store, store, e)))?;
    let _lock = StoreLock::acquire(store)?;
    let catalog = !store.join("zarr.json").exists();
    if catalog {
        catalog::write_root(store, &empty_catalog())?;
    }
    Ok(Created { dir, catalog })
}

/// Undo [`create_store`] after a failed run, if the catalog is still empty and
/// no other run has started writing into the store.
pub(super) fn undo_create(store: &Path, created: Created) {
    if !created.catalog {
        return;
    }
    let Ok(lock) = StoreLock::acquire(store) else {
        return;
    };
    let empty = catalog::read_root(store).is_ok_and(|a| a.dsms.is_empty());
    let others = std::fs::read_dir(store).map_or(true, |mut entries| {
        entries.any(|e| {
            e.map_or(true, |e| {
                let name = e.file_name();
                name != "zarr.json" && name != LOCK_FILE
            })
        })
    });
    if empty && !others {
        let _ = std::fs::remove_file(store.join("zarr.json"));
        drop(lock);
        let _ = std::fs::remove_file(store.join(LOCK_FILE));
        if created.dir {
            let _ = std::fs::remove_dir(store);
        }
        tracing::info!(store = %store.display(), "empty store removed");
    }
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
    let old = match catalog::read_valid_dsm(store, &file.id, attrs.crs.as_ref()) {
        Ok(old) => old,
        Err(e) => {
            tracing::warn!("{e}; DSM \"{}\" is damaged and is ingested again", file.id);
            return Ok(DsmAction::Replaced);
        }
    };
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
    warped: Option<&Warped>,
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
    if raster.crs.epsg.is_none() && raster.crs.wkt.is_none() && raster.crs.geokeys.is_empty() {
        return bad(
            "no CRS (no GeoKeyDirectory): assign one first, e.g. gdal_edit.py -a_srs EPSG:326xx"
                .into(),
        );
    }
    if raster.crs.is_geographic {
        return bad(format!(
            "geographic CRS {} (degrees) is not a metric frame, and only longitude and latitude on WGS 84, NAD83 or ETRS89 are put into UTM here; reproject to a projected CRS first, e.g. gdalwarp -t_srs EPSG:326xx",
            raster.crs.label()
        ));
    }
    if let Some(unit) = crate::geotiff::geokeys::non_metre_units(&raster.crs).first() {
        return bad(format!(
            "{unit} in CRS {}, not metres: reproject to a metric CRS first (heights too), e.g. gdalwarp -t_srs EPSG:326xx",
            raster.crs.label()
        ));
    }
    if let Some(unit) =
        (raster.height_unit.as_deref()).filter(|u| crate::geotiff::gdal_metadata::is_feet(u))
    {
        return bad(format!(
            "height unit {unit:?} (GDAL band metadata), not metres: convert the heights to metres first (x 0.3048 for feet, x 0.3048006 for US survey feet)"
        ));
    }
    if !raster.geotransform.is_north_up() {
        return bad(format!(
            "geotransform {:?} is rotated, sheared or not north-up; only north-up rasters are supported (gdalwarp can resample it)",
            raster.geotransform.0
        ));
    }
    if let Err(msg) = validate::check_raster(raster.width, raster.height, &raster.geotransform) {
        return bad(msg);
    }
    match collection {
        Some((crs, origin)) if !crs.same_as(&raster.crs) => bad(format!(
            "CRS {}{} differs from the collection's CRS {} (from {origin}); reproject it to the same CRS",
            raster.crs.label(),
            warped.map_or(String::new(), |w| format!(" (put there from {})", w.from)),
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
                let meta = catalog::read_valid_dsm(store, &file.id, attrs.crs.as_ref())?;
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
        validate(
            source.raster(),
            source.warped().as_ref(),
            &file.path,
            &mut collection,
        )?;
    }
    Ok(())
}
