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

    /// Same CRS for registration purposes: equal EPSG codes (a user-defined
    /// UTM zone counts as its code: `geotiff::equivalent::code`), or, without
    /// codes, keys that define the same thing, citations aside.
    pub fn same_as(&self, other: &Crs) -> bool {
        use crate::geotiff::equivalent::{code, same_definition};
        if self.is_geographic != other.is_geographic {
            return false;
        }
        match (code(self), code(other)) {
            (Some(a), Some(b)) => a == b,
            (None, None) => same_definition(self, other),
            _ => false,
        }
    }
}
