//! GeoTIFF georeferencing tags, read the way GDAL reads them: the
//! GeoKeyDirectory (34735) with its double (34736) and ASCII (34737) params
//! becomes a [`Crs`]; ModelPixelScale (33550) + ModelTiepoint (33922), or
//! ModelTransformation (34264, which wins), become a [`GeoTransform`], shifted
//! by half a pixel for pixel-is-point rasters so it is always pixel-is-area;
//! GDAL_NODATA (42113) becomes an `f64`. [`encode_crs`] gives the geokey tags
//! to write back for a [`Crs`]. Pure functions over tag values: no file access.

use crate::geo::{Crs, GeoTransform};

/// TIFF tag numbers of the GeoTIFF and GDAL extensions.
pub mod tag {
    pub const MODEL_PIXEL_SCALE: u16 = 33550;
    pub const MODEL_TIEPOINT: u16 = 33922;
    pub const MODEL_TRANSFORMATION: u16 = 34264;
    pub const GEO_KEY_DIRECTORY: u16 = 34735;
    pub const GEO_DOUBLE_PARAMS: u16 = 34736;
    pub const GEO_ASCII_PARAMS: u16 = 34737;
    pub const GDAL_METADATA: u16 = 42112;
    pub const GDAL_NODATA: u16 = 42113;
}

/// GeoKey ids used here.
pub mod key {
    pub const GT_MODEL_TYPE: u16 = 1024;
    pub const GT_RASTER_TYPE: u16 = 1025;
    pub const GT_CITATION: u16 = 1026;
    pub const GEOGRAPHIC_TYPE: u16 = 2048;
    pub const GEOG_CITATION: u16 = 2049;
    pub const GEOG_ANGULAR_UNITS: u16 = 2054;
    pub const PROJECTED_CS_TYPE: u16 = 3072;
    pub const PCS_CITATION: u16 = 3073;
    pub const PROJ_COORD_TRANS: u16 = 3075;
    pub const PROJ_LINEAR_UNITS: u16 = 3076;
    pub const PROJ_LINEAR_UNIT_SIZE: u16 = 3077;
    pub const VERTICAL_CS_TYPE: u16 = 4096;
    pub const VERTICAL_UNITS: u16 = 4099;
}

/// GeoKey code meaning "user-defined": no EPSG code.
pub const USER_DEFINED: u16 = 32767;
const MODEL_PROJECTED: u16 = 1;
const MODEL_GEOGRAPHIC: u16 = 2;
const RASTER_PIXEL_IS_POINT: u16 = 2;

/// What is wrong with the georeferencing tags.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GeoKeyError {
    #[error("no georeferencing (no ModelPixelScale + ModelTiepoint or ModelTransformation tag)")]
    NoGeoreferencing,
    #[error("geotransform {0:?} is rotated, sheared or not north-up (only north-up rasters are supported)")]
    NotNorthUp([f64; 6]),
    #[error("malformed {tag} tag: {detail}")]
    Malformed { tag: &'static str, detail: String },
}

/// One GeoKey value as stored: inline short, or a slice of the double/ASCII params.
#[derive(Clone, Debug, PartialEq)]
pub enum GeoKeyValue {
    Short(u16),
    Shorts(Vec<u16>),
    Doubles(Vec<f64>),
    Ascii(String),
}

/// The parsed GeoKeyDirectory.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GeoKeys {
    pub entries: Vec<(u16, GeoKeyValue)>,
}

impl GeoKeys {
    /// Parse the directory: a 4-short header (version, revision, minor, count)
    /// then `count` entries of [id, location, count, value_or_offset].
    pub fn parse(directory: &[u16], doubles: &[f64], ascii: &str) -> Result<GeoKeys, GeoKeyError> {
        let bad = |detail: String| GeoKeyError::Malformed {
            tag: "GeoKeyDirectory",
            detail,
        };
        if directory.len() < 4 {
            return Err(bad(format!(
                "{} values, shorter than its header",
                directory.len()
            )));
        }
        let n = directory[3] as usize;
        if directory.len() < 4 + 4 * n {
            return Err(bad(format!(
                "header says {n} keys but holds {} values",
                directory.len()
            )));
        }
        let mut entries = Vec::with_capacity(n);
        for e in directory[4..4 + 4 * n].chunks_exact(4) {
            let (id, location, count, value) = (e[0], e[1], e[2] as usize, e[3] as usize);
            let range = value..value + count;
            let v = match location {
                0 => GeoKeyValue::Short(e[3]),
                tag::GEO_KEY_DIRECTORY => GeoKeyValue::Shorts(
                    directory
                        .get(range)
                        .ok_or_else(|| bad(format!("key {id} out of range")))?
                        .to_vec(),
                ),
                tag::GEO_DOUBLE_PARAMS => GeoKeyValue::Doubles(
                    doubles
                        .get(range)
                        .ok_or_else(|| bad(format!("key {id} out of range")))?
                        .to_vec(),
                ),
                tag::GEO_ASCII_PARAMS => {
                    let s = ascii
                        .get(range)
                        .unwrap_or_else(|| ascii.get(value..).unwrap_or(""));
                    GeoKeyValue::Ascii(s.trim_end_matches(['|', '\0']).trim().to_string())
                }
                // Unknown location: keep the raw value rather than fail the whole file.
                _ => GeoKeyValue::Short(e[3]),
            };
            entries.push((id, v));
        }
        Ok(GeoKeys { entries })
    }

    pub fn get(&self, id: u16) -> Option<&GeoKeyValue> {
        self.entries.iter().find(|(k, _)| *k == id).map(|(_, v)| v)
    }

    pub fn short(&self, id: u16) -> Option<u16> {
        match self.get(id)? {
            GeoKeyValue::Short(v) => Some(*v),
            GeoKeyValue::Shorts(v) => v.first().copied(),
            _ => None,
        }
    }

    pub fn ascii(&self, id: u16) -> Option<&str> {
        match self.get(id)? {
            GeoKeyValue::Ascii(s) if !s.is_empty() => Some(s),
            _ => None,
        }
    }

    /// True when the raster type key says pixel-is-point.
    pub fn pixel_is_point(&self) -> bool {
        self.short(key::GT_RASTER_TYPE) == Some(RASTER_PIXEL_IS_POINT)
    }
}

/// Build the [`Crs`] from the raw geokey tags (any of them may be absent).
pub fn crs_from_tags(
    directory: &[u16],
    doubles: &[f64],
    ascii: Option<&str>,
) -> Result<Crs, GeoKeyError> {
    let ascii_str = ascii.unwrap_or("");
    let keys = if directory.is_empty() {
        GeoKeys::default()
    } else {
        GeoKeys::parse(directory, doubles, ascii_str)?
    };
    let code = |id| keys.short(id).filter(|&c| c != 0 && c != USER_DEFINED);
    let model = keys.short(key::GT_MODEL_TYPE);
    let projected = code(key::PROJECTED_CS_TYPE);
    let geographic = code(key::GEOGRAPHIC_TYPE);
    let is_geographic = match model {
        Some(m) => m == MODEL_GEOGRAPHIC,
        None => {
            projected.is_none()
                && keys.get(key::PROJECTED_CS_TYPE).is_none()
                && geographic.is_some()
        }
    };
    let epsg = match model {
        Some(MODEL_PROJECTED) => projected,
        Some(MODEL_GEOGRAPHIC) => geographic,
        Some(_) => None,
        None => projected.or(geographic),
    }
    .map(u32::from)
    .or_else(|| super::equivalent::identify_utm(&keys));
    let wkt = if epsg.is_none() && !directory.is_empty() {
        Some(describe_custom(&keys, model))
    } else {
        None
    };
    Ok(Crs {
        epsg,
        is_geographic,
        wkt,
        geokeys: directory.to_vec(),
        geo_doubles: doubles.to_vec(),
        geo_ascii: ascii.map(|s| s.trim_end_matches('\0').to_string()),
    })
}

/// The [`Crs`] that GeoTIFF keys `entries` describe, as a file holding them
/// would be read.
pub(crate) fn crs_from_entries(entries: Vec<(u16, GeoKeyValue)>) -> Result<Crs, GeoKeyError> {
    let (directory, doubles, ascii) = encode(entries);
    crs_from_tags(&directory, &doubles, Some(&ascii))
}

/// The projected CRS whose EPSG code is `code` with the vertical keys of
/// `heights` (the CRS a DSM's heights were given in, kept when a DSM in
/// longitude and latitude is put into a projected CRS).
pub fn projected_crs(code: u32, heights: &Crs) -> Option<Crs> {
    let code = u16::try_from(code).ok()?;
    let mut entries = vec![
        (key::GT_MODEL_TYPE, GeoKeyValue::Short(MODEL_PROJECTED)),
        (key::GT_RASTER_TYPE, GeoKeyValue::Short(1)),
        (key::PROJECTED_CS_TYPE, GeoKeyValue::Short(code)),
    ];
    let ascii = heights.geo_ascii.as_deref().unwrap_or("");
    if let Ok(keys) = GeoKeys::parse(&heights.geokeys, &heights.geo_doubles, ascii) {
        let vertical = (keys.entries.into_iter()).filter(|(id, _)| (4096..=4099).contains(id));
        entries.extend(vertical);
    }
    crs_from_entries(entries).ok()
}

/// The GeoKeyDirectory, GeoDoubleParams and GeoAsciiParams of `entries`.
fn encode(mut entries: Vec<(u16, GeoKeyValue)>) -> (Vec<u16>, Vec<f64>, String) {
    const DOUBLES: u16 = 34736;
    const ASCII: u16 = 34737;
    entries.sort_by_key(|(id, _)| *id);
    let mut directory = vec![1, 1, 0, entries.len() as u16];
    let (mut doubles, mut ascii) = (Vec::new(), String::new());
    for (id, value) in entries {
        let entry = match value {
            GeoKeyValue::Short(v) => [id, 0, 1, v],
            GeoKeyValue::Shorts(v) => [id, 0, 1, v.first().copied().unwrap_or(0)],
            GeoKeyValue::Doubles(v) => {
                let at = doubles.len() as u16;
                doubles.extend(&v);
                [id, DOUBLES, v.len() as u16, at]
            }
            GeoKeyValue::Ascii(s) => {
                let s = s.replace('|', "/");
                let at = ascii.len() as u16;
                ascii.push_str(&s);
                ascii.push('|');
                [id, ASCII, s.len() as u16 + 1, at]
            }
        };
        directory.extend(entry);
    }
    (directory, doubles, ascii)
}

/// A readable description of a CRS without an EPSG code: its kind and the
/// codes it does name, then the citations GDAL wrote (skipping "unknown").
fn describe_custom(keys: &GeoKeys, model: Option<u16>) -> String {
    let kind = match model {
        Some(MODEL_PROJECTED) => "user-defined projected CRS",
        Some(MODEL_GEOGRAPHIC) => "user-defined geographic CRS",
        Some(3) => "geocentric CRS",
        _ => "user-defined CRS",
    };
    let mut parts = vec![kind.to_string()];
    if let Some(t) = keys.short(key::PROJ_COORD_TRANS) {
        parts.push(coord_trans_name(t));
    }
    if let Some(g) = keys
        .short(key::GEOGRAPHIC_TYPE)
        .filter(|&g| g != USER_DEFINED)
    {
        parts.push(format!("base EPSG:{g}"));
    }
    let mut text = parts.join(", ");
    for id in [key::PCS_CITATION, key::GT_CITATION, key::GEOG_CITATION] {
        if let Some(c) = keys
            .ascii(id)
            .filter(|c| !c.eq_ignore_ascii_case("unknown"))
        {
            text.push_str("; ");
            text.push_str(c);
        }
    }
    text
}

/// EPSG unit code of the metre.
pub const METRE: u16 = 9001;

/// The units of length of a CRS other than the metre, horizontal first: e.g.
/// "horizontal unit US survey foot (EPSG unit 9003)". A unit key
/// (ProjLinearUnits, VerticalUnits) is taken as written; without one, the
/// unit of the EPSG CRS the code keys name (ProjectedCSType, VerticalCSType)
/// is looked up in [`epsg_units`](super::epsg_units), as GDAL takes it from
/// the EPSG definition. Empty when every unit is the metre or none is known,
/// or the keys cannot be parsed.
pub fn non_metre_units(crs: &Crs) -> Vec<String> {
    let ascii = crs.geo_ascii.as_deref().unwrap_or("");
    match GeoKeys::parse(&crs.geokeys, &crs.geo_doubles, ascii) {
        Ok(keys) => keys_non_metre_units(&keys),
        Err(_) => Vec::new(),
    }
}

/// [`non_metre_units`] of parsed keys (a GeoTIFF's, or a LAS file's
/// GeoKeyDirectory VLR).
pub fn keys_non_metre_units(keys: &GeoKeys) -> Vec<String> {
    let mut found = Vec::new();
    let by_code = |id, table| {
        let code = keys.short(id).filter(|&c| c != 0 && c != USER_DEFINED)?;
        Some((epsg_unit(table, code)?, code))
    };
    match keys.short(key::PROJ_LINEAR_UNITS) {
        Some(USER_DEFINED) => {
            let size = match keys.get(key::PROJ_LINEAR_UNIT_SIZE) {
                Some(GeoKeyValue::Doubles(d)) => d.first().copied(),
                _ => None,
            };
            if let Some(size) = size.filter(|s| (s - 1.0).abs() > 1e-9) {
                found.push(format!("horizontal unit of {size} m (user-defined)"));
            }
        }
        Some(code) if code != METRE => {
            found.push(format!("horizontal unit {}", unit_name(code)));
        }
        Some(_) => {}
        None => {
            // the caller names the CRS
            if let Some((unit, _)) = by_code(key::PROJECTED_CS_TYPE, super::epsg_units::PROJECTED) {
                found.push(format!(
                    "horizontal unit {} by its EPSG definition",
                    unit_name(unit)
                ));
            }
        }
    }
    match keys.short(key::VERTICAL_UNITS) {
        Some(code) if code != METRE && code != USER_DEFINED => {
            found.push(format!("height unit {}", unit_name(code)));
        }
        Some(_) => {}
        None => {
            if let Some((unit, crs)) = by_code(key::VERTICAL_CS_TYPE, super::epsg_units::VERTICAL) {
                found.push(format!(
                    "height unit {} of vertical CRS EPSG:{crs}",
                    unit_name(unit)
                ));
            }
        }
    }
    found
}

/// The EPSG unit of the CRS `code` in a table of runs (first, last, unit)
/// sorted by code; `None` for codes not in it (metres, or unknown).
fn epsg_unit(runs: &[(u16, u16, u16)], code: u16) -> Option<u16> {
    let at = runs.partition_point(|&(_, last, _)| last < code);
    runs.get(at)
        .filter(|&&(first, _, _)| first <= code)
        .map(|&(_, _, unit)| unit)
}

/// "US survey foot (EPSG unit 9003)", or "EPSG unit N" for codes not in EPSG.
fn unit_name(code: u16) -> String {
    match super::epsg_units::UNIT_NAMES.binary_search_by_key(&code, |&(c, _)| c) {
        Ok(at) => format!("{} (EPSG unit {code})", super::epsg_units::UNIT_NAMES[at].1),
        Err(_) => format!("EPSG unit {code}"),
    }
}

fn coord_trans_name(code: u16) -> String {
    let name = match code {
        1 => "Transverse Mercator",
        7 => "Mercator",
        8 => "Lambert Conformal Conic 2SP",
        9 => "Lambert Conformal Conic 1SP",
        10 => "Lambert Azimuthal Equal Area",
        11 => "Albers Equal Area",
        15 => "Polar Stereographic",
        16 => "Oblique Stereographic",
        17 => "Equirectangular",
        _ => return format!("coordinate transformation {code}"),
    };
    name.to_string()
}

/// The GDAL geotransform (pixel-is-area) from the model tags.
/// `transformation` (16 values, row-major 4x4) wins over `scale` + `tiepoint`.
pub fn geotransform_from_tags(
    scale: Option<&[f64]>,
    tiepoint: Option<&[f64]>,
    transformation: Option<&[f64]>,
    pixel_is_point: bool,
) -> Result<GeoTransform, GeoKeyError> {
    let mut gt = if let Some(m) = transformation {
        if m.len() < 16 {
            return Err(GeoKeyError::Malformed {
                tag: "ModelTransformation",
                detail: format!("{} values instead of 16", m.len()),
            });
        }
        [m[3], m[0], m[1], m[7], m[4], m[5]]
    } else {
        match (scale, tiepoint) {
            (Some(s), Some(t)) if s.len() >= 2 && t.len() >= 6 => {
                // Tiepoint (I, J, K, X, Y, Z): raster (I, J) sits at model (X, Y).
                [
                    t[3] - t[0] * s[0],
                    s[0],
                    0.0,
                    t[4] + t[1] * s[1],
                    0.0,
                    -s[1],
                ]
            }
            _ => return Err(GeoKeyError::NoGeoreferencing),
        }
    };
    if pixel_is_point {
        // GDAL: the tiepoint names the pixel centre; report the outer corner.
        gt[0] -= 0.5 * gt[1] + 0.5 * gt[2];
        gt[3] -= 0.5 * gt[4] + 0.5 * gt[5];
    }
    let gt = GeoTransform(gt);
    if !gt.0.iter().all(|v| v.is_finite()) || !gt.is_north_up() {
        return Err(GeoKeyError::NotNorthUp(gt.0));
    }
    Ok(gt)
}

/// Parse GDAL_NODATA: ASCII such as "nan", "-9999", "-3.4028234663852886e+38",
/// possibly with trailing NULs or whitespace. None when empty or unparsable.
pub fn parse_gdal_nodata(text: &str) -> Option<f64> {
    let t = text.trim_matches(|c: char| c == '\0' || c.is_whitespace());
    if t.is_empty() {
        return None;
    }
    let lower = t.to_ascii_lowercase();
    if matches!(
        lower.as_str(),
        "nan" | "-nan" | "+nan" | "1.#qnan" | "-1.#ind"
    ) {
        return Some(f64::NAN);
    }
    lower.parse::<f64>().ok()
}

/// The geokey tag values to write for a CRS.
#[derive(Clone, Debug, PartialEq)]
pub struct GeoKeyTags {
    pub directory: Vec<u16>,
    pub doubles: Vec<f64>,
    pub ascii: Option<String>,
}

/// Tags that describe `crs`: its raw geokeys when it carries them (so a CRS
/// without an EPSG code round-trips), else a minimal directory naming its EPSG
/// code. The raster type key is set to area or point as asked.
pub fn encode_crs(crs: &Crs, pixel_is_point: bool) -> GeoKeyTags {
    let raster_type = if pixel_is_point {
        RASTER_PIXEL_IS_POINT
    } else {
        1
    };
    if crs.geokeys.len() >= 4 {
        let mut directory = crs.geokeys.clone();
        let n = (directory[3] as usize).min((directory.len() - 4) / 4);
        for i in 0..n {
            let e = 4 + 4 * i;
            if directory[e] == key::GT_RASTER_TYPE && directory[e + 1] == 0 {
                directory[e + 3] = raster_type;
            }
        }
        return GeoKeyTags {
            directory,
            doubles: crs.geo_doubles.clone(),
            ascii: crs.geo_ascii.clone(),
        };
    }
    let mut entries: Vec<[u16; 4]> = Vec::new();
    let code = crs.epsg.and_then(|c| u16::try_from(c).ok());
    let model = if crs.is_geographic {
        MODEL_GEOGRAPHIC
    } else {
        MODEL_PROJECTED
    };
    entries.push([key::GT_MODEL_TYPE, 0, 1, model]);
    entries.push([key::GT_RASTER_TYPE, 0, 1, raster_type]);
    if let Some(c) = code {
        let id = if crs.is_geographic {
            key::GEOGRAPHIC_TYPE
        } else {
            key::PROJECTED_CS_TYPE
        };
        entries.push([id, 0, 1, c]);
    }
    let mut directory = vec![1, 1, 0, entries.len() as u16];
    directory.extend(entries.iter().flatten());
    GeoKeyTags {
        directory,
        doubles: Vec::new(),
        ascii: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const UTM_DIR: [u16; 32] = [
        1, 1, 0, 7, 1024, 0, 1, 1, 1025, 0, 1, 1, 1026, 34737, 21, 0, 2049, 34737, 6, 21, 2054, 0,
        1, 9102, 3072, 0, 1, 26917, 3076, 0, 1, 9001,
    ];

    #[test]
    fn projected_epsg_and_citations() {
        let crs = crs_from_tags(&UTM_DIR, &[], Some("NAD83 / UTM zone 17N|NAD83|\0")).unwrap();
        assert_eq!(crs.epsg, Some(26917));
        assert!(!crs.is_geographic);
        assert_eq!(crs.wkt, None);
        assert_eq!(crs.label(), "EPSG:26917");
        let keys = GeoKeys::parse(&UTM_DIR, &[], "NAD83 / UTM zone 17N|NAD83|").unwrap();
        assert_eq!(keys.ascii(key::GT_CITATION), Some("NAD83 / UTM zone 17N"));
        assert_eq!(keys.ascii(key::GEOG_CITATION), Some("NAD83"));
    }

    #[test]
    fn geographic_and_user_defined() {
        let geo = [1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 2, 2048, 0, 1, 4326];
        let crs = crs_from_tags(&geo, &[], None).unwrap();
        assert_eq!((crs.epsg, crs.is_geographic), (Some(4326), true));
        // No model type key: a geographic code alone means geographic.
        let crs = crs_from_tags(&[1, 1, 0, 1, 2048, 0, 1, 4269], &[], None).unwrap();
        assert_eq!((crs.epsg, crs.is_geographic), (Some(4269), true));
        let custom = [
            1, 1, 0, 4, 1024, 0, 1, 1, 1026, 34737, 8, 0, 3072, 0, 1, 32767, 3075, 0, 1, 1,
        ];
        let crs = crs_from_tags(&custom, &[], Some("My grid|")).unwrap();
        assert_eq!(crs.epsg, None);
        assert!(!crs.is_geographic);
        let label = crs.label();
        assert!(
            label.contains("projected") && label.contains("Transverse Mercator"),
            "{label}"
        );
        assert!(crs.wkt.unwrap().ends_with("My grid"));
    }

    #[test]
    fn malformed_directory_is_an_error() {
        assert!(GeoKeys::parse(&[1, 1, 0], &[], "").is_err());
        assert!(GeoKeys::parse(&[1, 1, 0, 2, 1024, 0, 1, 1], &[], "").is_err());
        assert!(GeoKeys::parse(&[1, 1, 0, 1, 2057, 34736, 1, 5], &[1.0], "").is_err());
    }

    #[test]
    fn tiepoint_scale_and_pixel_is_point() {
        let s = [0.5, 0.25, 0.0];
        let t = [0.0, 0.0, 0.0, 1000.0, 2000.0, 0.0];
        let gt = geotransform_from_tags(Some(&s), Some(&t), None, false).unwrap();
        assert_eq!(gt.0, [1000.0, 0.5, 0.0, 2000.0, 0.0, -0.25]);
        let gt = geotransform_from_tags(Some(&s), Some(&t), None, true).unwrap();
        assert_eq!(gt.0, [999.75, 0.5, 0.0, 2000.125, 0.0, -0.25]);
        // A tiepoint at raster (10, 4).
        let t = [10.0, 4.0, 0.0, 1005.0, 1999.0, 0.0];
        let gt = geotransform_from_tags(Some(&s), Some(&t), None, false).unwrap();
        assert_eq!(gt.0, [1000.0, 0.5, 0.0, 2000.0, 0.0, -0.25]);
    }

    #[test]
    fn transformation_wins_and_rotation_is_refused() {
        let m = [
            2.0, 0.0, 0.0, 10.0, 0.0, -2.0, 0.0, 20.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let s = [1.0, 1.0, 0.0];
        let t = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let gt = geotransform_from_tags(Some(&s), Some(&t), Some(&m), false).unwrap();
        assert_eq!(gt.0, [10.0, 2.0, 0.0, 20.0, 0.0, -2.0]);
        let mut rot = m;
        rot[1] = 0.1;
        assert!(matches!(
            geotransform_from_tags(None, None, Some(&rot), false),
            Err(GeoKeyError::NotNorthUp(_))
        ));
        let mut south_up = m;
        south_up[5] = 2.0;
        assert!(geotransform_from_tags(None, None, Some(&south_up), false).is_err());
        assert_eq!(
            geotransform_from_tags(None, None, None, false),
            Err(GeoKeyError::NoGeoreferencing)
        );
        assert_eq!(
            geotransform_from_tags(Some(&s), None, None, false),
            Err(GeoKeyError::NoGeoreferencing)
        );
    }

    #[test]
    fn gdal_nodata_strings() {
        assert!(parse_gdal_nodata("nan\0").unwrap().is_nan());
        assert!(parse_gdal_nodata("NaN").unwrap().is_nan());
        assert_eq!(parse_gdal_nodata("-9999\0\0"), Some(-9999.0));
        assert_eq!(parse_gdal_nodata(" -32768 \n"), Some(-32768.0));
        assert_eq!(
            parse_gdal_nodata("-3.4028234663852886e+38"),
            Some(f32::MIN as f64)
        );
        assert_eq!(parse_gdal_nodata("\0"), None);
        assert_eq!(parse_gdal_nodata("none"), None);
    }

    #[test]
    fn encode_round_trips() {
        let crs = crs_from_tags(&UTM_DIR, &[], Some("NAD83 / UTM zone 17N|NAD83|")).unwrap();
        let tags = encode_crs(&crs, true);
        let back = crs_from_tags(&tags.directory, &tags.doubles, tags.ascii.as_deref()).unwrap();
        assert_eq!(back.epsg, Some(26917));
        assert!(GeoKeys::parse(&tags.directory, &[], "")
            .unwrap()
            .pixel_is_point());
        let bare = Crs {
            epsg: Some(4326),
            is_geographic: true,
            ..Crs::default()
        };
        let tags = encode_crs(&bare, false);
        let back = crs_from_tags(&tags.directory, &tags.doubles, None).unwrap();
        assert_eq!((back.epsg, back.is_geographic), (Some(4326), true));
    }

    fn crs_with(entries: &[[u16; 4]], doubles: &[f64]) -> Crs {
        let mut geokeys = vec![1, 1, 0, entries.len() as u16];
        entries.iter().for_each(|e| geokeys.extend_from_slice(e));
        Crs {
            epsg: Some(2992),
            geokeys,
            geo_doubles: doubles.to_vec(),
            ..Default::default()
        }
    }

    #[test]
    fn feet_are_named_and_metres_are_not() {
        let projected = [1024, 0, 1, 1];
        let feet = crs_with(&[projected, [3072, 0, 1, 2992], [3076, 0, 1, 9002]], &[]);
        assert_eq!(
            non_metre_units(&feet),
            ["horizontal unit foot (EPSG unit 9002)"]
        );
        let survey = crs_with(&[[3076, 0, 1, 9003], [4099, 0, 1, 9003]], &[]);
        assert_eq!(
            non_metre_units(&survey),
            [
                "horizontal unit US survey foot (EPSG unit 9003)",
                "height unit US survey foot (EPSG unit 9003)"
            ]
        );
        let metres = crs_with(&[projected, [3076, 0, 1, 9001], [4099, 0, 1, 9001]], &[]);
        assert!(non_metre_units(&metres).is_empty());
        // an EPSG code alone of a CRS in metres
        let epsg_only = crs_with(&[projected, [3072, 0, 1, 32617]], &[]);
        assert!(non_metre_units(&epsg_only).is_empty());
        assert!(non_metre_units(&Crs::default()).is_empty());
        // GDAL's UTM directory names the metre
        let utm = crs_from_tags(&UTM_DIR, &[], Some("NAD83 / UTM zone 17N|NAD83|\0")).unwrap();
        assert!(non_metre_units(&utm).is_empty());
    }

    #[test]
    fn an_epsg_code_alone_gives_its_definition_s_unit() {
        let projected = [1024, 0, 1, 1];
        let only = |code: u16| crs_with(&[projected, [3072, 0, 1, code]], &[]);
        assert_eq!(
            non_metre_units(&only(2263)),
            ["horizontal unit US survey foot (EPSG unit 9003) by its EPSG definition"]
        );
        assert_eq!(
            non_metre_units(&only(2992)),
            ["horizontal unit foot (EPSG unit 9002) by its EPSG definition"]
        );
        // the first and last codes of runs, and their neighbours in metres
        assert_eq!(
            epsg_unit(super::super::epsg_units::PROJECTED, 2222),
            Some(9002)
        );
        assert_eq!(
            epsg_unit(super::super::epsg_units::PROJECTED, 2289),
            Some(9003)
        );
        assert_eq!(epsg_unit(super::super::epsg_units::PROJECTED, 2290), None);
        assert_eq!(epsg_unit(super::super::epsg_units::PROJECTED, 2221), None);
        for code in [0, 1, 26917, 32617, 25832, 2154, 3857, 65534] {
            assert!(non_metre_units(&only(code)).is_empty(), "EPSG:{code}");
        }
        // heights: NAVD88 in US survey feet by code, in metres (5703) not
        let vertical =
            |code: u16| crs_with(&[projected, [3072, 0, 1, 26917], [4096, 0, 1, code]], &[]);
        assert_eq!(
            non_metre_units(&vertical(6360)),
            ["height unit US survey foot (EPSG unit 9003) of vertical CRS EPSG:6360"]
        );
        assert!(non_metre_units(&vertical(5703)).is_empty());
        // a unit key is taken as written over the code's definition
        let said = crs_with(&[projected, [3072, 0, 1, 2263], [3076, 0, 1, 9001]], &[]);
        assert!(non_metre_units(&said).is_empty());
    }

    #[test]
    fn the_generated_tables_are_sorted_runs() {
        use super::super::epsg_units::{PROJECTED, UNIT_NAMES, VERTICAL};
        for runs in [PROJECTED, VERTICAL] {
            assert!(runs
                .iter()
                .all(|&(first, last, unit)| first <= last && unit != METRE));
            assert!(runs.windows(2).all(|w| w[0].1 < w[1].0));
            assert!(runs
                .iter()
                .all(|&(_, _, unit)| !unit_name(unit).starts_with("EPSG")));
        }
        assert!(UNIT_NAMES.windows(2).all(|w| w[0].0 < w[1].0));
    }

    #[test]
    fn a_user_defined_unit_is_judged_by_its_size() {
        let size =
            |metres: f64| crs_with(&[[3076, 0, 1, 32767], [3077, 34736, 1, 1]], &[0.0, metres]);
        assert_eq!(
            non_metre_units(&size(0.3048)),
            ["horizontal unit of 0.3048 m (user-defined)"]
        );
        assert!(non_metre_units(&size(1.0)).is_empty());
    }
}
