//! What a mosaic may cost, checked before anything is written: poses that
//! throw a DSM far away (a rotation about the CRS origin, a shift of 1e6 m)
//! imply a mosaic of billions of empty pixels that would run for hours or
//! abort on an allocation. Three limits, each refused with one line naming
//! the pose that moves a DSM farthest:
//! - the corrected footprints must be finite and the raster writable
//!   (each side at most `u32::MAX` px);
//! - the writer's tile index (a few words per tile, in memory for the whole
//!   run) must fit in the cache budget;
//! - the mosaic may be at most [`MAX_EMPTY_FACTOR`] times the area the DSMs
//!   cover (and at least [`SPARSE_FLOOR_PX`] px is always allowed).

use super::layout::{OutputGrid, PlacedDsm};
use super::pose_set::PoseSet;
use crate::store::Store;

/// Most mosaic pixels per pixel of the DSMs' own footprints.
pub const MAX_EMPTY_FACTOR: f64 = 1000.0;
/// Mosaics up to this many pixels are never called sparse.
pub const SPARSE_FLOOR_PX: f64 = (1u64 << 28) as f64;
/// Memory per output tile held for the whole run (tile index, order, refs).
pub const TILE_INDEX_BYTES: u64 = 48;

/// The poses imply a mosaic beyond the limits.
#[derive(Debug, thiserror::Error)]
#[error("{reason}; {moved} (refusing before writing anything: check the poses)")]
pub struct MosaicTooLarge {
    pub reason: String,
    /// Which pose moves its DSM the farthest, and how far.
    pub moved: String,
}

/// The DSM whose pose moves its footprint centre the farthest.
fn farthest_move(store: &Store, poses: &PoseSet, placed: &[PlacedDsm]) -> String {
    let mut best: Option<(f64, usize)> = None;
    for p in placed {
        let f = store.dsms()[p.index].footprint.to_array();
        let centre = [(f[0] + f[2]) / 2.0, (f[1] + f[3]) / 2.0, p.z_start_m];
        let moved = poses.poses[p.index].apply(centre);
        let d = ((moved[0] - centre[0]).powi(2) + (moved[1] - centre[1]).powi(2)).sqrt();
        let d = if d.is_finite() { d } else { f64::INFINITY };
        if best.is_none_or(|(b, _)| d > b) {
            best = Some((d, p.index));
        }
    }
    match best {
        Some((d, i)) => format!(
            "the pose of DSM '{}' moves its centre by {d:.0} m",
            store.dsms()[i].id
        ),
        None => "no DSM".into(),
    }
}

/// Refuse a mosaic beyond the limits (see the module doc).
pub fn check_mosaic(
    store: &Store,
    poses: &PoseSet,
    placed: &[PlacedDsm],
    grid: &OutputGrid,
    cache_budget_bytes: usize,
) -> Result<(), MosaicTooLarge> {
    let refuse = |reason: String| {
        Err(MosaicTooLarge {
            reason,
            moved: farthest_move(store, poses, placed),
        })
    };
    let gsd = grid.gsd_m();
    let finite = placed
        .iter()
        .all(|p| p.corrected_bounds.iter().all(|v| v.is_finite()));
    let g = &grid.geotransform.0;
    let b = super::layout::union_bounds(placed.iter().map(|p| p.corrected_bounds));
    let (w, h) = match b {
        Some(b) => ((b[2] - b[0]) / gsd, (b[3] - b[1]) / gsd),
        None => (0.0, 0.0),
    };
    if !(finite && g.iter().all(|v| v.is_finite()) && w.is_finite() && h.is_finite()) {
        return refuse("the corrected footprints are not finite".into());
    }
    if w > u32::MAX as f64 || h > u32::MAX as f64 {
        return refuse(format!(
            "the mosaic would be {w:.0} x {h:.0} px at {gsd} m, more than a GeoTIFF can hold"
        ));
    }
    let tile = super::TILE_SIZE as f64;
    let tiles = (w / tile).ceil() * (h / tile).ceil();
    let index_bytes = tiles * TILE_INDEX_BYTES as f64;
    if index_bytes > cache_budget_bytes as f64 {
        return refuse(format!(
            "the mosaic would be {w:.0} x {h:.0} px at {gsd} m; its tile index alone needs {} MiB, more than the cache budget of {} MiB (--cache-mb)",
            (index_bytes / (1u64 << 20) as f64).ceil(),
            cache_budget_bytes >> 20
        ));
    }
    let covered_px: f64 = placed
        .iter()
        .map(|p| {
            let f = store.dsms()[p.index].footprint.to_array();
            ((f[2] - f[0]) / gsd).max(1.0) * ((f[3] - f[1]) / gsd).max(1.0)
        })
        .sum();
    let mosaic_px = w * h;
    if mosaic_px > SPARSE_FLOOR_PX && mosaic_px > MAX_EMPTY_FACTOR * covered_px {
        return refuse(format!(
            "the mosaic would be {w:.0} x {h:.0} px at {gsd} m, {:.0} times the area the DSMs cover",
            mosaic_px / covered_px.max(1.0)
        ));
    }
    Ok(())
}
