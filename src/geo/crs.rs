//! The coordinate reference system of a DSM as read from its GeoTIFF geokeys.

use serde::{Deserialize, Serialize};

/// A coordinate reference system as found in the GeoTIFF. The raw geokeys and
/// ASCII/double params are kept so a CRS without an EPSG code is not lost.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Crs {
    /// Projected (or, if `is_geographic`, geographic) EPSG code, when present.
    pub epsg: Option<u32>,
    /// True when the model type is geographic (lat/lon in degrees).
    pub is_geographic: bool,
    /// A WKT or citation string when the file carries one (GeoAsciiParams / GDAL metadata).
    pub wkt: Option<String>,
    /// Raw GeoKeyDirectory (u16 values, header included).
    pub geokeys: Vec<u16>,
    /// Raw GeoDoubleParams.
    pub geo_doubles: Vec<f64>,
    /// Raw GeoAsciiParams.
    pub geo_ascii: Option<String>,
}

impl Crs {
    /// A short label: "EPSG:32617", or "custom: <citation>" when no code is known.
    pub fn label(&self) -> String {
        match (self.epsg, &self.wkt) {
            (Some(code), _) => format!("EPSG:{code}"),
            (None, Some(w)) => format!("custom: {}", w.chars().take(60).collect::<String>()),
            (None, None) => "unknown".to_string(),
        }
    }

    /// Same CRS for registration purposes: equal EPSG codes, or (without codes)
    /// identical raw geokeys and params.
    pub fn same_as(&self, other: &Crs) -> bool {
        match (self.epsg, other.epsg) {
            (Some(a), Some(b)) => a == b && self.is_geographic == other.is_geographic,
            (None, None) => {
                self.geokeys == other.geokeys
                    && self.geo_doubles == other.geo_doubles
                    && self.geo_ascii == other.geo_ascii
            }
            _ => false,
        }
    }
}

/// GeoKeys that name units of length: ProjLinearUnitsGeoKey,
/// ProjLinearUnitSizeGeoKey (metres per unit of a user-defined one) and
/// VerticalUnitsGeoKey.
const PROJ_LINEAR_UNITS: u16 = 3076;
const PROJ_LINEAR_UNIT_SIZE: u16 = 3077;
const VERTICAL_UNITS: u16 = 4099;
/// EPSG unit codes: the metre, and "user-defined".
const METRE: u16 = 9001;
const USER_DEFINED: u16 = 32767;
/// The GeoDoubleParams tag, where a key's double values live.
const GEO_DOUBLE_PARAMS: u16 = 34736;

impl Crs {
    /// The units of length the geokeys name other than the metre, horizontal
    /// first: e.g. "horizontal unit US survey foot (EPSG unit 9003)". Empty
    /// when they name metres or no unit (an EPSG code alone: its unit is the
    /// EPSG definition's, which this reader does not carry).
    pub fn non_metre_units(&self) -> Vec<String> {
        let mut found = Vec::new();
        let keys = &self.geokeys;
        if keys.len() < 4 {
            return found;
        }
        let n = (keys[3] as usize).min((keys.len() - 4) / 4);
        let entry = |id: u16| {
            (0..n)
                .map(|i| &keys[4 + 4 * i..8 + 4 * i])
                .find(|e| e[0] == id)
                .map(|e| (e[1], e[3]))
        };
        let inline = |id: u16| entry(id).filter(|&(loc, _)| loc == 0).map(|(_, v)| v);
        match inline(PROJ_LINEAR_UNITS) {
            Some(USER_DEFINED) => {
                let size = entry(PROJ_LINEAR_UNIT_SIZE)
                    .filter(|&(loc, _)| loc == GEO_DOUBLE_PARAMS)
                    .and_then(|(_, at)| self.geo_doubles.get(at as usize).copied());
                if let Some(size) = size.filter(|s| (s - 1.0).abs() > 1e-9) {
                    found.push(format!("horizontal unit of {size} m (user-defined)"));
                }
            }
            Some(code) if code != METRE => {
                found.push(format!("horizontal unit {}", unit_name(code)));
            }
            _ => {}
        }
        match inline(VERTICAL_UNITS) {
            Some(code) if code != METRE && code != USER_DEFINED => {
                found.push(format!("height unit {}", unit_name(code)));
            }
            _ => {}
        }
        found
    }
}

/// "US survey foot (EPSG unit 9003)", or "EPSG unit N" for codes not named here.
fn unit_name(code: u16) -> String {
    let name = match code {
        9002 => "foot",
        9003 => "US survey foot",
        9004 => "modified American foot",
        9005 => "Clarke's foot",
        9006 => "Indian foot",
        9014 => "fathom",
        9030 => "nautical mile",
        9035 => "statute mile",
        9036 => "kilometre",
        9037 => "Clarke's yard",
        9096 => "yard",
        _ => return format!("EPSG unit {code}"),
    };
    format!("{name} (EPSG unit {code})")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn crs(entries: &[[u16; 4]], doubles: &[f64]) -> Crs {
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
        let feet = crs(&[projected, [3072, 0, 1, 2992], [3076, 0, 1, 9002]], &[]);
        assert_eq!(
            feet.non_metre_units(),
            ["horizontal unit foot (EPSG unit 9002)"]
        );
        let survey = crs(&[[3076, 0, 1, 9003], [4099, 0, 1, 9003]], &[]);
        assert_eq!(
            survey.non_metre_units(),
            [
                "horizontal unit US survey foot (EPSG unit 9003)",
                "height unit US survey foot (EPSG unit 9003)"
            ]
        );
        let metres = crs(&[projected, [3076, 0, 1, 9001], [4099, 0, 1, 9001]], &[]);
        assert!(metres.non_metre_units().is_empty());
        // an EPSG code alone names no unit here
        assert!(crs(&[projected, [3072, 0, 1, 32617]], &[])
            .non_metre_units()
            .is_empty());
        assert!(Crs::default().non_metre_units().is_empty());
    }

    #[test]
    fn a_user_defined_unit_is_judged_by_its_size() {
        let size = |metres: f64| crs(&[[3076, 0, 1, 32767], [3077, 34736, 1, 1]], &[0.0, metres]);
        assert_eq!(
            size(0.3048).non_metre_units(),
            ["horizontal unit of 0.3048 m (user-defined)"]
        );
        assert!(size(1.0).non_metre_units().is_empty());
    }
}
