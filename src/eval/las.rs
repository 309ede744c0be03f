//! Lidar reference points from a LAS/LAZ file (the `las` crate), streamed in
//! batches: noise classes (7 low point, 18 high noise) and withheld points are
//! dropped, only first returns are kept unless `all_returns` (a DSM is the top
//! surface), and every k-th remaining point is kept so at most about
//! `max_samples` are evaluated. The CRS is read from the WKT or GeoTIFF-key VLRs
//! and compared with the store's EPSG code.

use std::path::Path;

use las::point::Classification;
use las::Reader;

use super::{EvalConfig, EvalError};
use crate::geo::Bounds;
use crate::store::Store;

/// Points read per batch.
const BATCH_POINTS: u64 = 262_144;

/// Kept points (x, y, z) and remarks for the report.
pub struct LasSamples {
    pub points: Vec<[f64; 3]>,
    pub notes: Vec<String>,
}

impl LasSamples {
    pub fn read(
        store: &Store,
        path: &Path,
        config: &EvalConfig,
        store_bounds: Bounds,
    ) -> Result<LasSamples, EvalError> {
        let bad = |m: String| EvalError::Input(format!("{}: {m}", path.display()));
        let mut reader = Reader::from_path(path).map_err(|e| bad(e.to_string()))?;
        let header = reader.header().clone();
        let mut notes = Vec::new();
        if let Some(unit) = non_metre_units(&header).first() {
            return Err(bad(format!(
                "{unit} in the point cloud's CRS, not metres: reproject it to the store's CRS first (e.g. pdal translate with filters.reprojection)"
            )));
        }
        let las_epsg = crs_epsg(&header);
        match (las_epsg, store.crs().and_then(|c| c.epsg)) {
            (Some(a), Some(b)) if a != b => {
                return Err(bad(format!(
                    "CRS EPSG:{a} differs from the store's EPSG:{b}"
                )))
            }
            (Some(a), Some(_)) => notes.push(format!("point cloud CRS EPSG:{a}, as the store")),
            (Some(a), None) => notes.push(format!(
                "the point cloud is EPSG:{a}; the store has no EPSG code, assumed the same"
            )),
            (None, _) => notes.push(
                "the point cloud records no EPSG code; assumed to be in the store's CRS".into(),
            ),
        }
        let b = header.bounds();
        let bounds = Bounds::from([b.min.x, b.min.y, b.max.x, b.max.y]);
        if !bounds.overlaps(&store_bounds) {
            return Err(bad(format!(
                "does not overlap the store (points {:.1?}, store {:.1?})",
                bounds.to_array(),
                store_bounds.to_array()
            )));
        }
        let total = header.number_of_points();
        let stride = total.div_ceil(config.max_samples.max(1)).max(1);
        let (mut points, mut seen, mut kept_filter) = (Vec::new(), 0u64, 0u64);
        loop {
            let batch = reader
                .read_points(BATCH_POINTS)
                .map_err(|e| bad(format!("reading points: {e}")))?;
            if batch.is_empty() {
                break;
            }
            for p in batch.points() {
                let p = p.map_err(|e| bad(format!("reading points: {e}")))?;
                seen += 1;
                if !on_surface(&p, config.all_returns) {
                    continue;
                }
                kept_filter += 1;
                if (kept_filter - 1).is_multiple_of(stride) {
                    points.push([p.x, p.y, p.z]);
                }
            }
        }
        notes.push(format!(
            "{seen} points, {kept_filter} after filtering ({}), {}",
            if config.all_returns {
                "noise and withheld removed"
            } else {
                "first returns only, noise and withheld removed"
            },
            if stride > 1 {
                format!("every {stride}th kept")
            } else {
                "all kept".to_string()
            }
        ));
        Ok(LasSamples { points, notes })
    }
}

/// A point of the surface a DSM shows: not noise (classes 7 low point, 18
/// high noise), not withheld, and a first return unless `all_returns`.
pub fn on_surface(p: &las::Point, all_returns: bool) -> bool {
    let noise = matches!(
        p.classification,
        Classification::LowPoint | Classification::HighNoise
    );
    !noise && !p.is_withheld && (p.return_number <= 1 || all_returns)
}

/// The units of length other than the metre the header's CRS names: its
/// GeoKeyDirectory's unit keys (or the units of the EPSG codes it gives),
/// else its WKT's.
pub fn non_metre_units(header: &las::Header) -> Vec<String> {
    use crate::geotiff::geokeys::{keys_non_metre_units, GeoKeyValue, GeoKeys};
    use las::crs::GeoTiffData;
    if let Ok(Some(geotiff)) = header.get_geotiff_crs() {
        let entries = (geotiff.entries.iter())
            .map(|e| {
                let value = match &e.data {
                    GeoTiffData::U16(v) => GeoKeyValue::Short(*v),
                    GeoTiffData::Doubles(d) => GeoKeyValue::Doubles(d.clone()),
                    GeoTiffData::String(s) => GeoKeyValue::Ascii(s.clone()),
                };
                (e.id, value)
            })
            .collect();
        let found = keys_non_metre_units(&GeoKeys { entries });
        if !found.is_empty() {
            return found;
        }
    }
    let wkt = header.get_wkt_crs_bytes().map(String::from_utf8_lossy);
    wkt.map(|w| crate::geotiff::wkt::non_metre_units(&w))
        .unwrap_or_default()
}

/// EPSG code of the horizontal CRS recorded in the header, if any.
pub fn crs_epsg(header: &las::Header) -> Option<u32> {
    if let Some(wkt) = header.get_wkt_crs_bytes() {
        let text = String::from_utf8_lossy(wkt);
        if let Some(code) = crate::geotiff::wkt::epsg(&text) {
            return Some(code);
        }
    }
    let geotiff = header.get_geotiff_crs().ok().flatten()?;
    geotiff
        .get_projected_crs_geo_key_value()
        .filter(|&k| (1024..32767).contains(&k))
        .or_else(|| {
            geotiff
                .get_geodetic_crs_geo_key_value()
                .filter(|&k| (1024..32767).contains(&k))
        })
        .map(u32::from)
}
