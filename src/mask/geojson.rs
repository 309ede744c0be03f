//! Stable areas given as GeoJSON polygons: a FeatureCollection, a Feature or a
//! bare geometry of type Polygon, MultiPolygon or GeometryCollection, with
//! coordinates in the DSMs' CRS (the old `"crs"` member, when present, must
//! name the same EPSG code), or in longitude and latitude as RFC 7946 has
//! them (put into the DSMs' UTM zone by [`Polygons::projected`]; the caller
//! decides). Rasterised by cell centre (even-odd rule, so holes are excluded;
//! overlapping polygons add up) onto a lattice chosen by the caller.

use serde_json::Value;

use super::raster::BitRaster;
use crate::geo::proj::Projection;
use crate::geo::{Bounds, GeoTransform};

/// The longest piece (degrees) a polygon edge in longitude and latitude is
/// projected as: about 100 m, where a straight edge in degrees bows from the
/// chord by well under a millimetre.
pub const MAX_EDGE_DEG: f64 = 0.001;

/// One polygon: its outer ring, then its holes; each ring a closed or open
/// list of (x, y).
pub type Polygon = Vec<Vec<[f64; 2]>>;

/// The polygons of a GeoJSON document and the EPSG code its `"crs"` names.
#[derive(Clone, Debug, Default)]
pub struct Polygons {
    pub polygons: Vec<Polygon>,
    /// From `"crs": {"properties": {"name": "...EPSG::32617"}}`; None when
    /// absent. OGC's CRS84 (longitude, latitude on WGS 84) counts as 4326.
    /// `Some(None)`: a CRS is named but not as an EPSG code.
    pub named_epsg: Option<Option<u32>>,
}

impl Polygons {
    /// Parses the document; the error says what is wrong (without the path).
    pub fn parse(text: &str) -> Result<Polygons, String> {
        let doc: Value = serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
        let mut out = Polygons {
            named_epsg: named_crs(&doc),
            ..Default::default()
        };
        collect(&doc, &mut out.polygons)?;
        if out.polygons.is_empty() {
            return Err("no Polygon or MultiPolygon in the file".into());
        }
        Ok(out)
    }

    /// The box of every vertex.
    pub fn bounds(&self) -> Bounds {
        let mut b = Bounds {
            min_x: f64::INFINITY,
            min_y: f64::INFINITY,
            max_x: f64::NEG_INFINITY,
            max_y: f64::NEG_INFINITY,
        };
        for p in self.polygons.iter().flatten().flatten() {
            b.min_x = b.min_x.min(p[0]);
            b.max_x = b.max_x.max(p[0]);
            b.min_y = b.min_y.min(p[1]);
            b.max_y = b.max_y.max(p[1]);
        }
        b
    }

    /// True when every vertex could be a longitude and latitude.
    pub fn could_be_degrees(&self) -> bool {
        let b = self.bounds();
        b.min_x >= -180.0 && b.max_x <= 360.0 && b.min_y >= -90.0 && b.max_y <= 90.0
    }

    /// The polygons with (longitude, latitude) vertices put through `tm`,
    /// each edge first cut into pieces of at most [`MAX_EDGE_DEG`] so that it
    /// stays the curve it is in metres.
    pub fn projected(&self, projection: &Projection) -> Polygons {
        self.mapped(|lon, lat| projection.forward(lon, lat), MAX_EDGE_DEG)
    }

    /// The polygons with their vertices put through `f`, each edge first cut
    /// into pieces of at most `max_edge` (in the vertices' units) so that it
    /// stays the curve it is where `f` takes it.
    pub fn mapped(&self, f: impl Fn(f64, f64) -> (f64, f64), max_edge: f64) -> Polygons {
        let ring = |ring: &Vec<[f64; 2]>| -> Vec<[f64; 2]> {
            let n = ring.len();
            let mut out = Vec::with_capacity(n);
            for k in 0..n {
                let (a, b) = (ring[k], ring[(k + 1) % n]);
                let span = (b[0] - a[0]).abs().max((b[1] - a[1]).abs());
                let pieces = (span / max_edge).ceil().clamp(1.0, 1e6) as usize;
                // the closing edge of an open ring too; a closed ring's last
                // vertex repeats its first, an edge of length zero
                for i in 0..pieces {
                    let t = i as f64 / pieces as f64;
                    let (x, y) = (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]));
                    let (e, n) = f(x, y);
                    out.push([e, n]);
                }
            }
            out
        };
        Polygons {
            polygons: (self.polygons.iter())
                .map(|p| p.iter().map(ring).collect())
                .collect(),
            named_epsg: None,
        }
    }

    /// A raster of `width` x `height` cells placed by `geotransform`: a cell
    /// is stable when its centre lies inside a polygon (outside its holes).
    pub fn rasterise(&self, geotransform: GeoTransform, width: i64, height: i64) -> BitRaster {
        let mut raster = BitRaster::new(geotransform, width, height);
        let mut crossings = Vec::new();
        for row in 0..height {
            let (_, y) = geotransform.pixel_to_world(0.0, row as f64 + 0.5);
            for polygon in &self.polygons {
                crossings.clear();
                for ring in polygon {
                    ring_crossings(ring, y, &mut crossings);
                }
                crossings.sort_by(f64::total_cmp);
                for span in crossings.chunks_exact(2) {
                    // cells whose centre x lies in [span[0], span[1])
                    let (c0, _) = geotransform.world_to_pixel(span[0], y);
                    let (c1, _) = geotransform.world_to_pixel(span[1], y);
                    let first = (c0 - 0.5).ceil().max(0.0) as i64;
                    let end = ((c1 - 0.5).ceil() as i64).min(width);
                    for col in first..end {
                        raster.set(col, row);
                    }
                }
            }
        }
        raster
    }
}

/// The x where the ring's edges cross the line at `y` (half-open in y, so a
/// vertex on the line is counted once).
fn ring_crossings(ring: &[[f64; 2]], y: f64, out: &mut Vec<f64>) {
    let n = ring.len();
    for k in 0..n {
        let (a, b) = (ring[k], ring[(k + 1) % n]);
        if (a[1] <= y) != (b[1] <= y) {
            out.push(a[0] + (y - a[1]) / (b[1] - a[1]) * (b[0] - a[0]));
        }
    }
}

/// The EPSG code of an old-style `"crs"` member (see [`Polygons::named_epsg`]).
fn named_crs(doc: &Value) -> Option<Option<u32>> {
    let name = doc.get("crs")?.get("properties")?.get("name")?.as_str()?;
    let upper = name.to_ascii_uppercase();
    if upper.ends_with("CRS84") {
        return Some(Some(4326));
    }
    if !upper.contains("EPSG") {
        return Some(None);
    }
    Some(upper.rsplit(':').next().and_then(|code| code.parse().ok()))
}

/// Appends the polygons of a GeoJSON object.
fn collect(v: &Value, out: &mut Vec<Polygon>) -> Result<(), String> {
    let kind = v.get("type").and_then(Value::as_str).unwrap_or("");
    match kind {
        "FeatureCollection" => {
            let features = v
                .get("features")
                .and_then(Value::as_array)
                .ok_or("a FeatureCollection without \"features\"")?;
            features.iter().try_for_each(|f| collect(f, out))
        }
        "Feature" => match v.get("geometry") {
            Some(Value::Null) | None => Ok(()),
            Some(g) => collect(g, out),
        },
        "GeometryCollection" => v
            .get("geometries")
            .and_then(Value::as_array)
            .ok_or("a GeometryCollection without \"geometries\"")?
            .iter()
            .try_for_each(|g| collect(g, out)),
        "Polygon" => {
            out.push(polygon(coordinates(v)?)?);
            Ok(())
        }
        "MultiPolygon" => {
            let list = coordinates(v)?
                .as_array()
                .ok_or("MultiPolygon coordinates are not a list")?;
            for p in list {
                out.push(polygon(p)?);
            }
            Ok(())
        }
        // points and lines have no area: they mark nothing stable
        "Point" | "MultiPoint" | "LineString" | "MultiLineString" => Ok(()),
        other => Err(format!("unknown GeoJSON type \"{other}\"")),
    }
}

fn coordinates(v: &Value) -> Result<&Value, String> {
    v.get("coordinates")
        .ok_or_else(|| "a geometry without \"coordinates\"".to_string())
}

/// A polygon's rings from `[[[x, y], ...], ...]`.
fn polygon(v: &Value) -> Result<Polygon, String> {
    let bad = || "polygon coordinates are not [[[x, y], ...], ...]".to_string();
    let rings = v.as_array().ok_or_else(bad)?;
    rings
        .iter()
        .map(|ring| {
            let points = ring.as_array().ok_or_else(bad)?;
            let ring: Vec<[f64; 2]> = points
                .iter()
                .map(|p| match p.as_array().map(|a| a.as_slice()) {
                    Some([x, y, ..]) => match (x.as_f64(), y.as_f64()) {
                        (Some(x), Some(y)) if x.is_finite() && y.is_finite() => Ok([x, y]),
                        _ => Err(bad()),
                    },
                    _ => Err(bad()),
                })
                .collect::<Result<_, _>>()?;
            if ring.len() < 3 {
                return Err("a polygon ring has fewer than 3 points".to_string());
            }
            Ok(ring)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const SQUARE_WITH_HOLE: &str = r#"{"type": "FeatureCollection",
        "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32617"}},
        "features": [{"type": "Feature", "properties": {"class": "stable"},
          "geometry": {"type": "Polygon", "coordinates": [
            [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]],
            [[4, 4], [6, 4], [6, 6], [4, 6], [4, 4]]]}},
          {"type": "Feature", "geometry": null}]}"#;

    #[test]
    fn polygons_with_holes_are_rasterised_by_cell_centre() {
        let p = Polygons::parse(SQUARE_WITH_HOLE).unwrap();
        assert_eq!(p.named_epsg, Some(Some(32617)));
        assert_eq!(p.bounds().to_array(), [0.0, 0.0, 10.0, 10.0]);
        // 1 m cells over [-2, 12] x [-2, 12]
        let r = p.rasterise(GeoTransform::north_up(-2.0, 12.0, 1.0, 1.0), 14, 14);
        assert_eq!(r.count(), 100 - 4);
        assert!(r.get(2, 2) && r.get(11, 11)); // cells at x 0.5, x 9.5
        assert!(!r.get(1, 5) && !r.get(12, 5)); // outside
        assert!(!r.get(6, 6) && !r.get(7, 7) && r.get(8, 8)); // the hole [4, 6]
    }

    #[test]
    fn multipolygons_and_bare_geometries_are_read() {
        let text = r#"{"type": "MultiPolygon", "coordinates": [
            [[[0, 0], [2, 0], [2, 2], [0, 2]]], [[[5, 0], [7, 0], [6, 2]]]]}"#;
        let p = Polygons::parse(text).unwrap();
        assert_eq!(p.polygons.len(), 2);
        assert_eq!(p.named_epsg, None);
        let r = p.rasterise(GeoTransform::north_up(0.0, 2.0, 1.0, 1.0), 8, 2);
        // the square: 2 x 2; the triangle: 2 cell centres in its lower row, none in its tip
        assert_eq!(r.count(), 4 + 2);
    }

    #[test]
    fn what_is_not_polygons_is_refused_with_the_reason() {
        let none = Polygons::parse(r#"{"type": "Point", "coordinates": [1, 2]}"#);
        assert!(none.unwrap_err().contains("no Polygon"));
        let bad = Polygons::parse(r#"{"type": "Polygon", "coordinates": [[1, 2]]}"#);
        assert!(bad.unwrap_err().contains("not [[[x, y]"));
        assert!(Polygons::parse("{").unwrap_err().starts_with("not JSON"));
        let crs84 = r#"{"type": "Polygon", "crs": {"properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}},
            "coordinates": [[[0, 0], [1, 0], [1, 1]]]}"#;
        assert_eq!(Polygons::parse(crs84).unwrap().named_epsg, Some(Some(4326)));
        let other = r#"{"type": "Polygon", "crs": {"properties": {"name": "urn:ogc:def:crs:IGNF:LAMB93"}},
            "coordinates": [[[0, 0], [1, 0], [1, 1]]]}"#;
        assert_eq!(Polygons::parse(other).unwrap().named_epsg, Some(None));
    }
}
