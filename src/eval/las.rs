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
    wkt.map(|w| wkt_non_metre_units(&w)).unwrap_or_default()
}

/// The units of length of a WKT 1 or 2 CRS other than the metre: WKT 1
/// `UNIT` nodes of a projected, vertical or local CRS (not the angle unit of
/// its geographic base), WKT 2 `LENGTHUNIT` nodes; e.g. "unit US survey foot
/// (0.304800609601219 m)".
pub fn wkt_non_metre_units(wkt: &str) -> Vec<String> {
    const LENGTH_PARENTS: [&str; 5] = ["PROJCS", "VERT_CS", "LOCAL_CS", "GEOCCS", "VERTCS"];
    let mut stack: Vec<&str> = Vec::new();
    let mut found = Vec::new();
    let mut word_start = 0;
    for (k, ch) in wkt.char_indices() {
        match ch {
            '[' | '(' => {
                let keyword = wkt[word_start..k].trim();
                let length = keyword == "LENGTHUNIT"
                    || (keyword == "UNIT"
                        && stack.last().is_some_and(|p| LENGTH_PARENTS.contains(p)));
                if length {
                    if let Some(unit) = unit_not_metre(&wkt[k + 1..]) {
                        if !found.contains(&unit) {
                            found.push(unit);
                        }
                    }
                }
                stack.push(keyword);
                word_start = k + 1;
            }
            ']' | ')' => {
                stack.pop();
                word_start = k + 1;
            }
            ',' => word_start = k + 1,
            _ => {}
        }
    }
    found
}

/// `"name",factor` at the start of a unit node's body, when the factor is
/// not 1 (a metre).
fn unit_not_metre(body: &str) -> Option<String> {
    let body = body.trim_start().strip_prefix('"')?;
    let (name, rest) = body.split_once('"')?;
    let factor: String = (rest.trim_start().strip_prefix(',')?.trim_start().chars())
        .take_while(|c| c.is_ascii_digit() || matches!(c, '.' | 'e' | 'E' | '-' | '+'))
        .collect();
    let factor: f64 = factor.parse().ok()?;
    ((factor - 1.0).abs() > 1e-9).then(|| format!("unit {name} ({factor} m)"))
}

/// EPSG code of the horizontal CRS recorded in the header, if any.
pub fn crs_epsg(header: &las::Header) -> Option<u32> {
    if let Some(wkt) = header.get_wkt_crs_bytes() {
        let text = String::from_utf8_lossy(wkt);
        if let Some(code) = wkt_epsg(&text) {
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

/// The EPSG code of the projected (else the outermost) CRS of a WKT 1 or 2
/// string: the `AUTHORITY["EPSG",...]` / `ID["EPSG",...]` directly inside its
/// PROJCS/PROJCRS node (not one of a nested datum or unit).
pub fn wkt_epsg(wkt: &str) -> Option<u32> {
    let start = ["PROJCS[", "PROJCRS["]
        .iter()
        .find_map(|k| wkt.find(k))
        .unwrap_or(0);
    let body = &wkt[start..];
    let keys = ["AUTHORITY[\"EPSG\",", "ID[\"EPSG\","];
    let (mut depth, mut found) = (0i32, None);
    for (k, ch) in body.char_indices() {
        match ch {
            '[' | '(' => depth += 1,
            ']' | ')' => {
                depth -= 1;
                if depth == 0 {
                    break;
                }
            }
            _ if depth == 1 => {
                if let Some(key) = keys.iter().find(|key| body[k..].starts_with(**key)) {
                    found = Some(k + key.len());
                }
            }
            _ => {}
        }
    }
    let digits: String = body[found?..]
        .chars()
        .skip_while(|c| *c == '"' || c.is_whitespace())
        .take_while(|c| c.is_ascii_digit())
        .collect();
    digits.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::wkt_epsg;

    #[test]
    fn epsg_of_projected_wkt() {
        let wkt1 = r#"PROJCS["NAD83 / UTM zone 17N",GEOGCS["NAD83",AUTHORITY["EPSG","4269"]],UNIT["metre",1,AUTHORITY["EPSG","9001"]],AUTHORITY["EPSG","26917"]]"#;
        assert_eq!(wkt_epsg(wkt1), Some(26917));
        let compound = r#"COMPD_CS["x",PROJCS["WGS 84 / UTM zone 16N",GEOGCS["WGS 84",AUTHORITY["EPSG","4326"]],AUTHORITY["EPSG","32616"]],VERT_CS["NAVD88",AUTHORITY["EPSG","5703"]]]"#;
        assert_eq!(wkt_epsg(compound), Some(32616));
        let wkt2 = r#"PROJCRS["WGS 84 / UTM zone 16N",BASEGEOGCRS["WGS 84",ID["EPSG",4326]],ID["EPSG",32616]]"#;
        assert_eq!(wkt_epsg(wkt2), Some(32616));
        assert_eq!(wkt_epsg("LOCAL_CS[\"x\"]"), None);
        let no_own = r#"PROJCS["x",GEOGCS["WGS 84",AUTHORITY["EPSG","4326"]],UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
        assert_eq!(wkt_epsg(no_own), None);
    }

    #[test]
    fn wkt_units_of_length_but_not_angles() {
        use super::wkt_non_metre_units;
        let feet = r#"PROJCS["NAD83(HARN) / Oregon GIC Lambert (ft)",GEOGCS["NAD83(HARN)",UNIT["degree",0.0174532925199433]],PROJECTION["Lambert_Conformal_Conic_2SP"],UNIT["foot",0.3048,AUTHORITY["EPSG","9002"]]]"#;
        assert_eq!(wkt_non_metre_units(feet), ["unit foot (0.3048 m)"]);
        let utm = r#"PROJCS["WGS 84 / UTM zone 16N",GEOGCS["WGS 84",UNIT["degree",0.0174532925199433]],UNIT["metre",1,AUTHORITY["EPSG","9001"]]]"#;
        assert!(wkt_non_metre_units(utm).is_empty());
        let heights_in_feet = r#"COMPD_CS["x",PROJCS["UTM",GEOGCS["g",UNIT["degree",0.01745]],UNIT["metre",1]],VERT_CS["NAVD88 height (ftUS)",VERT_DATUM["North American Vertical Datum 1988",2005],UNIT["US survey foot",0.304800609601219]]]"#;
        assert_eq!(
            wkt_non_metre_units(heights_in_feet),
            ["unit US survey foot (0.304800609601219 m)"]
        );
        let wkt2 = r#"PROJCRS["x",BASEGEOGCRS["g",ANGLEUNIT["degree",0.0174532925199433]],CS[Cartesian,2],AXIS["easting",east,LENGTHUNIT["US survey foot",0.304800609601219]]]"#;
        assert_eq!(
            wkt_non_metre_units(wkt2),
            ["unit US survey foot (0.304800609601219 m)"]
        );
    }
}
