//! When two GeoTIFF CRS descriptions are one CRS.
//!
//! Writers differ in how they describe a CRS: GDAL writes the EPSG code of a
//! UTM zone (ProjectedCSTypeGeoKey 32633), other software writes the same zone
//! as a user-defined projected CRS (the UTM projection's code, or Transverse
//! Mercator with its parameters, on the WGS 84 datum) with its own citation.
//! [`identify_utm`] gives such a description its EPSG code, as GDAL identifies
//! it, so DSMs of one zone from several producers form one collection;
//! [`same_keys`] compares two user-defined descriptions by what they define,
//! not by their citations.

use super::geokeys::{key, GeoKeyValue, GeoKeys, METRE, USER_DEFINED};
use crate::geo::tm::{Datum, Utm};
use crate::geo::Crs;

/// The EPSG code of `crs`: its own, or the UTM zone its user-defined keys
/// describe ([`identify_utm`]; stores written before this identification
/// keep their keys, so it is asked again here).
pub fn code(crs: &Crs) -> Option<u32> {
    crs.epsg.or_else(|| {
        let keys = parse(crs)?;
        identify_utm(&keys).or_else(|| identify_grid(&keys))
    })
}

/// The EPSG code of a user-defined projected CRS that is one of the national
/// and polar grids of [`crate::geo::proj`], as GDAL writes one from a PROJ
/// string (`+proj=stere +lat_0=90 +lat_ts=70 +lon_0=-45 +datum=WGS84`, as
/// ASP's `--t_srs` takes them): the coordinate transformation's code and
/// parameters, in metres, on WGS 84, NAD83 or ETRS89, or on an unnamed datum
/// of their ellipsoid with no shift (`+ellps=GRS80 +towgs84=0,0,0`).
pub fn identify_grid(keys: &GeoKeys) -> Option<u32> {
    if !user_defined_in_metres(keys) {
        return None;
    }
    let doubles = |id| match keys.get(id) {
        Some(GeoKeyValue::Doubles(d)) => Some(d.clone()),
        _ => None,
    };
    let no_shift = doubles(param::TOWGS84).is_none_or(|d| d.iter().all(|v| *v == 0.0));
    let ellipsoid = keys.short(param::ELLIPSOID);
    let semi_major = doubles(param::SEMI_MAJOR).and_then(|d| d.first().copied());
    let unnamed = keys.short(param::GEODETIC_DATUM) == Some(USER_DEFINED)
        && (matches!(ellipsoid, Some(7019 | 7030)) || semi_major == Some(6_378_137.0))
        && no_shift;
    if keys_datum(keys).is_none() && !unnamed {
        return None;
    }
    let method = match keys.short(key::PROJ_COORD_TRANS)? {
        1 => "transverse_mercator",
        8 => "lambert_conformal_conic_2sp",
        10 => "lambert_azimuthal_equal_area",
        11 => "albers",
        15 => "polar_stereographic",
        _ => return None,
    };
    const NAMES: [(u16, &str); 14] = [
        (3078, "standard_parallel_1"),
        (3079, "standard_parallel_2"),
        (3080, "longitude_of_natural_origin"),
        (3081, "latitude_of_natural_origin"),
        (3082, "false_easting"),
        (3083, "false_northing"),
        (3084, "longitude_of_false_origin"),
        (3085, "latitude_of_false_origin"),
        (3086, "easting_at_false_origin"),
        (3087, "northing_at_false_origin"),
        (3088, "longitude_of_center"),
        (3089, "latitude_of_center"),
        (3092, "scale_factor"),
        (3095, "longitude_of_origin"),
    ];
    let params: Vec<(String, f64)> = (NAMES.iter())
        .filter_map(|&(id, name)| Some((name.to_string(), *doubles(id)?.first()?)))
        .collect();
    crate::geo::proj::identify(method, &params)
}

/// True when two CRSs without EPSG codes define the same thing ([`same_keys`]);
/// keys that do not parse are compared as written.
pub fn same_definition(a: &Crs, b: &Crs) -> bool {
    match (parse(a), parse(b)) {
        (Some(ka), Some(kb)) => same_keys(&ka, &kb),
        _ => a.geokeys == b.geokeys && a.geo_doubles == b.geo_doubles && a.geo_ascii == b.geo_ascii,
    }
}

fn parse(crs: &Crs) -> Option<GeoKeys> {
    let ascii = crs.geo_ascii.as_deref().unwrap_or("");
    GeoKeys::parse(&crs.geokeys, &crs.geo_doubles, ascii).ok()
}

/// GeoKeys of the projection and its parameters (GeoTIFF 1.1).
mod param {
    pub const PROJECTION: u16 = 3074;
    pub const NAT_ORIGIN_LONG: u16 = 3080;
    pub const NAT_ORIGIN_LAT: u16 = 3081;
    pub const FALSE_EASTING: u16 = 3082;
    pub const FALSE_NORTHING: u16 = 3083;
    pub const SCALE_AT_NAT_ORIGIN: u16 = 3092;
    pub const GEODETIC_DATUM: u16 = 2050;
    pub const ELLIPSOID: u16 = 2056;
    pub const SEMI_MAJOR: u16 = 2057;
    pub const TOWGS84: u16 = 2062;
}

/// Free-text keys: two descriptions that differ only there are one CRS.
const CITATIONS: [u16; 4] = [
    key::GT_CITATION,
    key::GEOG_CITATION,
    key::PCS_CITATION,
    4097, // VerticalCitationGeoKey
];

const MODEL_PROJECTED: u16 = 1;
const COORD_TRANS_TRANSVERSE_MERCATOR: u16 = 1;

/// A projected CRS the keys define themselves (no code), in metres.
fn user_defined_in_metres(keys: &GeoKeys) -> bool {
    keys.short(key::GT_MODEL_TYPE) == Some(MODEL_PROJECTED)
        && (keys.short(key::PROJECTED_CS_TYPE)).is_none_or(|c| c == USER_DEFINED)
        && (keys.short(key::PROJ_LINEAR_UNITS)).is_none_or(|u| u == METRE)
}

/// The EPSG code of a user-defined projected CRS that is a UTM zone on
/// WGS 84 (326zz / 327zz), NAD83 (269zz, zones 1-23) or ETRS89 (258zz, zones
/// 28-38): named by the EPSG UTM projection code (16001-16060 north,
/// 16101-16160 south) or by Transverse Mercator with the zone's parameters.
/// `None` for anything else, or when the keys give an EPSG code already.
pub fn identify_utm(keys: &GeoKeys) -> Option<u32> {
    if !user_defined_in_metres(keys) {
        return None;
    }
    let (zone, north) = utm_zone(keys)?;
    let datum = keys_datum(keys)?;
    Utm {
        datum,
        zone: zone as u8,
        north,
    }
    .epsg()
}

/// The datum (of the three with UTM codes) a geographic CRS's keys name, by
/// the geographic CRS's code or, user-defined, by the datum's code.
fn keys_datum(keys: &GeoKeys) -> Option<Datum> {
    match (
        keys.short(key::GEOGRAPHIC_TYPE),
        keys.short(param::GEODETIC_DATUM),
    ) {
        (Some(4326), _) | (None | Some(USER_DEFINED), Some(6326)) => Some(Datum::Wgs84),
        (Some(4269), _) | (None | Some(USER_DEFINED), Some(6269)) => Some(Datum::Nad83),
        (Some(4258), _) | (None | Some(USER_DEFINED), Some(6258)) => Some(Datum::Etrs89),
        _ => None,
    }
}

/// The datum of a geographic CRS (longitude and latitude) when it is WGS 84,
/// NAD83 or ETRS89, the datums whose UTM zones have EPSG codes.
pub fn geographic_datum(crs: &Crs) -> Option<Datum> {
    if !crs.is_geographic {
        return None;
    }
    match crs.epsg {
        Some(4326) => Some(Datum::Wgs84),
        Some(4269) => Some(Datum::Nad83),
        Some(4258) => Some(Datum::Etrs89),
        Some(_) => None,
        None => keys_datum(&parse(crs)?),
    }
}

/// The UTM zone (1-60) and hemisphere the projection keys define.
fn utm_zone(keys: &GeoKeys) -> Option<(u16, bool)> {
    match keys.short(param::PROJECTION) {
        Some(p @ 16001..=16060) => return Some((p - 16000, true)),
        Some(p @ 16101..=16160) => return Some((p - 16100, false)),
        Some(p) if p != USER_DEFINED => return None,
        _ => {}
    }
    if keys.short(key::PROJ_COORD_TRANS) != Some(COORD_TRANS_TRANSVERSE_MERCATOR) {
        return None;
    }
    let value = |id| match keys.get(id) {
        Some(GeoKeyValue::Doubles(d)) => d.first().copied(),
        _ => None,
    };
    let near =
        |id, want: f64| value(id).is_some_and(|v| (v - want).abs() <= 1e-9 * want.abs().max(1.0));
    let long = value(param::NAT_ORIGIN_LONG)?;
    let zone = ((long + 183.0) / 6.0).round();
    if !(1.0..=60.0).contains(&zone)
        || !near(param::NAT_ORIGIN_LONG, 6.0 * zone - 183.0)
        || !near(param::NAT_ORIGIN_LAT, 0.0)
        || !near(param::SCALE_AT_NAT_ORIGIN, 0.9996)
        || !near(param::FALSE_EASTING, 500_000.0)
    {
        return None;
    }
    let north = if near(param::FALSE_NORTHING, 0.0) {
        true
    } else if near(param::FALSE_NORTHING, 10_000_000.0) {
        false
    } else {
        return None;
    };
    Some((zone as u16, north))
}

/// The keys of `k` that define the CRS, by id.
fn defining(k: &GeoKeys) -> Vec<&(u16, GeoKeyValue)> {
    let mut entries: Vec<&(u16, GeoKeyValue)> = (k.entries.iter())
        .filter(|(id, _)| !CITATIONS.contains(id))
        .collect();
    entries.sort_by_key(|(id, _)| *id);
    entries
}

/// True when two key sets define the same thing: the same keys with the same
/// values, citations aside, doubles equal to 1e-9 relative.
pub fn same_keys(a: &GeoKeys, b: &GeoKeys) -> bool {
    let (a, b) = (defining(a), defining(b));
    a.len() == b.len()
        && a.iter().zip(&b).all(|((ia, va), (ib, vb))| {
            ia == ib
                && match (va, vb) {
                    (GeoKeyValue::Doubles(x), GeoKeyValue::Doubles(y)) => {
                        x.len() == y.len()
                            && x.iter()
                                .zip(y)
                                .all(|(p, q)| (p - q).abs() <= 1e-9 * p.abs().max(q.abs()).max(1.0))
                    }
                    _ => va == vb,
                }
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A user-defined projected CRS: model, raster type, citations, the keys
    /// given, in a directory with its doubles.
    fn keys(entries: &[(u16, GeoKeyValue)]) -> GeoKeys {
        let mut all = vec![
            (key::GT_MODEL_TYPE, GeoKeyValue::Short(1)),
            (key::GT_RASTER_TYPE, GeoKeyValue::Short(1)),
            (key::PROJECTED_CS_TYPE, GeoKeyValue::Short(USER_DEFINED)),
        ];
        all.extend_from_slice(entries);
        GeoKeys { entries: all }
    }

    /// NSIDC's polar stereographic north as GDAL writes it from a PROJ
    /// string (fixtures/geotiff/ud_nsidc_north.tif's keys), with `lat_ts`
    /// and a datum shift.
    fn nsidc(lat_ts: f64, towgs84: Option<[f64; 3]>) -> GeoKeys {
        use GeoKeyValue::{Doubles, Short};
        let mut entries = vec![
            (key::GEOGRAPHIC_TYPE, Short(USER_DEFINED)),
            (param::GEODETIC_DATUM, Short(USER_DEFINED)),
            (param::ELLIPSOID, Short(7030)),
            (key::PROJ_COORD_TRANS, Short(15)),
            (key::PROJ_LINEAR_UNITS, Short(9001)),
            (param::NAT_ORIGIN_LAT, Doubles(vec![lat_ts])),
            (param::FALSE_EASTING, Doubles(vec![0.0])),
            (param::FALSE_NORTHING, Doubles(vec![0.0])),
            (param::SCALE_AT_NAT_ORIGIN, Doubles(vec![1.0])),
            (3095, Doubles(vec![-45.0])),
        ];
        entries.extend(towgs84.map(|t| (param::TOWGS84, Doubles(t.to_vec()))));
        keys(&entries)
    }

    #[test]
    fn a_polar_grid_as_user_defined_keys_gets_its_code_only_when_exact() {
        assert_eq!(identify_grid(&nsidc(70.0, None)), Some(3413));
        assert_eq!(identify_grid(&nsidc(70.0, Some([0.0; 3]))), Some(3413));
        assert_eq!(identify_grid(&nsidc(71.0, None)), None);
        assert_eq!(identify_grid(&nsidc(70.0, Some([1.0, 2.0, 3.0]))), None);
    }

    fn tm(long: f64, false_northing: f64, geographic: u16) -> GeoKeys {
        use GeoKeyValue::{Doubles, Short};
        keys(&[
            (key::GEOGRAPHIC_TYPE, Short(geographic)),
            (key::PROJ_COORD_TRANS, Short(1)),
            (key::PROJ_LINEAR_UNITS, Short(9001)),
            (param::NAT_ORIGIN_LONG, Doubles(vec![long])),
            (param::NAT_ORIGIN_LAT, Doubles(vec![0.0])),
            (param::SCALE_AT_NAT_ORIGIN, Doubles(vec![0.9996])),
            (param::FALSE_EASTING, Doubles(vec![500_000.0])),
            (param::FALSE_NORTHING, Doubles(vec![false_northing])),
        ])
    }

    #[test]
    fn utm_zones_written_as_transverse_mercator_get_their_code() {
        assert_eq!(identify_utm(&tm(15.0, 0.0, 4326)), Some(32633));
        assert_eq!(identify_utm(&tm(-81.0, 0.0, 4269)), Some(26917));
        assert_eq!(identify_utm(&tm(9.0, 0.0, 4258)), Some(25832));
        assert_eq!(identify_utm(&tm(147.0, 10_000_000.0, 4326)), Some(32755));
        assert_eq!(identify_utm(&tm(-177.0, 0.0, 4326)), Some(32601));
        assert_eq!(identify_utm(&tm(177.0, 10_000_000.0, 4326)), Some(32760));
    }

    #[test]
    fn near_misses_stay_user_defined() {
        // a central meridian between zones, another false northing, another datum
        assert_eq!(identify_utm(&tm(16.0, 0.0, 4326)), None);
        assert_eq!(identify_utm(&tm(15.0, 5_000_000.0, 4326)), None);
        assert_eq!(identify_utm(&tm(15.0, 0.0, 4267)), None);
        // NAD83 has no UTM codes of this series south or past zone 23
        assert_eq!(identify_utm(&tm(-81.0, 10_000_000.0, 4269)), None);
        assert_eq!(identify_utm(&tm(147.0, 0.0, 4269)), None);
        // another scale factor (a national TM, e.g. 0.9999)
        let mut national = tm(15.0, 0.0, 4326);
        for (id, v) in &mut national.entries {
            if *id == param::SCALE_AT_NAT_ORIGIN {
                *v = GeoKeyValue::Doubles(vec![0.9999]);
            }
        }
        assert_eq!(identify_utm(&national), None);
        // feet
        let mut feet = tm(15.0, 0.0, 4326);
        feet.entries.retain(|(id, _)| *id != key::PROJ_LINEAR_UNITS);
        feet.entries
            .push((key::PROJ_LINEAR_UNITS, GeoKeyValue::Short(9002)));
        assert_eq!(identify_utm(&feet), None);
    }

    #[test]
    fn the_utm_projection_code_names_the_zone() {
        use GeoKeyValue::Short;
        let by_code = |projection: u16, datum: (u16, u16)| {
            keys(&[
                (datum.0, Short(datum.1)),
                (param::PROJECTION, Short(projection)),
            ])
        };
        assert_eq!(
            identify_utm(&by_code(16033, (key::GEOGRAPHIC_TYPE, 4326))),
            Some(32633)
        );
        assert_eq!(
            identify_utm(&by_code(16133, (param::GEODETIC_DATUM, 6326))),
            Some(32733)
        );
        assert_eq!(
            identify_utm(&by_code(16017, (param::GEODETIC_DATUM, 6269))),
            Some(26917)
        );
        assert_eq!(
            identify_utm(&by_code(19914, (key::GEOGRAPHIC_TYPE, 4326))),
            None
        );
    }

    #[test]
    fn citations_do_not_make_another_crs() {
        let cite = |text: &str| {
            let mut k = tm(16.0, 0.0, 4326);
            k.entries
                .push((key::PCS_CITATION, GeoKeyValue::Ascii(text.to_string())));
            k
        };
        assert!(same_keys(
            &cite("Custom TM 16E"),
            &cite("TM 16 East, WGS84")
        ));
        assert!(same_keys(
            &tm(16.0, 0.0, 4326),
            &cite("no citation on the other")
        ));
        assert!(!same_keys(
            &tm(16.0, 0.0, 4326),
            &tm(16.0 + 1e-6, 0.0, 4326)
        ));
        assert!(same_keys(
            &tm(16.0, 0.0, 4326),
            &tm(16.0 + 1e-12, 0.0, 4326)
        ));
        assert!(!same_keys(&tm(16.0, 0.0, 4326), &tm(16.0, 0.0, 4258)));
    }
}
