//! The georeferencing of a level array in the Zarr conventions GIS software reads:
//! `spatial:` (dimensions, affine transform in rasterio order, shape, bbox, pixel
//! registration) and `proj:` (`proj:code` when the CRS has an EPSG code), both
//! registered in `zarr_conventions`. GDAL 3.13's Zarr driver reads these, so
//! `ZARR:"store.zarr":/<id>/0` opens with its CRS and geotransform. The group's
//! `multiscales` listing (see [`multiscales`]) follows the multiscales convention.

use crate::geo::{Bounds, Crs, GeoTransform};
use serde_json::{json, Map, Value};

/// `zarr_conventions` entry of the spatial convention (v1).
fn spatial_convention() -> Value {
    json!({
        "schema_url": "https://raw.githubusercontent.com/zarr-conventions/spatial/refs/tags/v1/schema.json",
        "spec_url": "https://github.com/zarr-conventions/spatial/blob/v1/README.md",
        "uuid": "689b58e2-cf7b-45e0-9fff-9cfc0883d6b4",
        "name": "spatial",
        "description": "Spatial coordinate information"
    })
}

/// `zarr_conventions` entry of the geo-proj convention (v1).
fn proj_convention() -> Value {
    json!({
        "schema_url": "https://raw.githubusercontent.com/zarr-conventions/geo-proj/refs/tags/v1/schema.json",
        "spec_url": "https://github.com/zarr-conventions/geo-proj/blob/v1/README.md",
        "uuid": "f17cb550-5864-4468-aeb7-f3180cfb622f",
        "name": "proj:",
        "description": "Coordinate reference system information for geospatial data"
    })
}

/// `zarr_conventions` entry of the multiscales convention (v1).
fn multiscales_convention() -> Value {
    json!({
        "schema_url": "https://raw.githubusercontent.com/zarr-conventions/multiscales/refs/tags/v1/schema.json",
        "spec_url": "https://github.com/zarr-conventions/multiscales/blob/v1/README.md",
        "uuid": "d35379db-88df-4056-af3a-620245f8e347",
        "name": "multiscales",
        "description": "Multiscale layout of zarr datasets"
    })
}

/// GDAL's geotransform order [c, a, b, f, d, e] to the conventions' [a, b, c, d, e, f].
pub fn spatial_transform(gt: &GeoTransform) -> [f64; 6] {
    let g = gt.0;
    [g[1], g[2], g[0], g[4], g[5], g[3]]
}

/// The box of the four corners of a `height` x `width` grid (any affine
/// transform; written as `[xmin, ymin, xmax, ymax]`).
fn bbox(gt: &GeoTransform, height: u64, width: u64) -> Bounds {
    let g = gt.0;
    let corner = |col: f64, row: f64| {
        (
            g[0] + col * g[1] + row * g[2],
            g[3] + col * g[4] + row * g[5],
        )
    };
    let corners = [
        corner(0.0, 0.0),
        corner(width as f64, 0.0),
        corner(0.0, height as f64),
        corner(width as f64, height as f64),
    ];
    Bounds::union_all(corners.map(|c| Bounds::from_corners(c, c))).expect("four corners")
}

/// The `spatial:` (and, with an EPSG code, `proj:`) attributes of one level array.
pub fn level_attributes(
    gt: &GeoTransform,
    crs: &Crs,
    height: u64,
    width: u64,
) -> Map<String, Value> {
    let mut conventions = vec![spatial_convention()];
    let mut attrs = Map::new();
    if let Some(code) = crs.epsg {
        conventions.insert(0, proj_convention());
        attrs.insert("proj:code".into(), json!(format!("EPSG:{code}")));
    }
    attrs.insert("zarr_conventions".into(), Value::Array(conventions));
    attrs.insert("spatial:dimensions".into(), json!(["y", "x"]));
    attrs.insert("spatial:transform_type".into(), json!("affine"));
    attrs.insert("spatial:transform".into(), json!(spatial_transform(gt)));
    attrs.insert("spatial:shape".into(), json!([height, width]));
    attrs.insert("spatial:bbox".into(), json!(bbox(gt, height, width)));
    attrs.insert("spatial:registration".into(), json!("pixel"));
    attrs
}

/// The group's multiscales convention: level `k` (array `k`) is 2^k coarser than
/// level 0 and derived from level k-1 by a 2x2 mean, each with its own
/// `spatial:transform` and `spatial:shape`; the CRS as `proj:code` on the group too.
pub fn multiscales(levels: &[(GeoTransform, u64, u64)], crs: &Crs) -> Map<String, Value> {
    let layout: Vec<Value> = levels
        .iter()
        .enumerate()
        .map(|(k, (gt, height, width))| {
            let scale = (1u64 << k) as f64;
            let mut entry = json!({
                "asset": k.to_string(),
                "transform": {"scale": [scale, scale], "translation": [0.0, 0.0]},
                "spatial:transform": spatial_transform(gt),
                "spatial:shape": [height, width],
            });
            if k > 0 {
                entry["derived_from"] = json!((k - 1).to_string());
                entry["resampling_method"] = json!("average");
            }
            entry
        })
        .collect();
    let mut attrs = Map::new();
    let mut conventions = vec![multiscales_convention(), spatial_convention()];
    if let Some(code) = crs.epsg {
        conventions.insert(1, proj_convention());
        attrs.insert("proj:code".into(), json!(format!("EPSG:{code}")));
    }
    attrs.insert("zarr_conventions".into(), Value::Array(conventions));
    attrs.insert("spatial:dimensions".into(), json!(["y", "x"]));
    attrs.insert(
        "multiscales".into(),
        json!({"layout": layout, "resampling_method": "average"}),
    );
    attrs
}

#[cfg(test)]
mod tests {
    use super::*;

    fn utm() -> Crs {
        Crs {
            epsg: Some(32617),
            ..Crs::default()
        }
    }

    #[test]
    fn level_attributes_carry_the_affine_in_rasterio_order_and_the_code() {
        let gt = GeoTransform::north_up(630_000.0, 4_833_000.0, 0.5, 0.5);
        let a = level_attributes(&gt, &utm(), 100, 200);
        assert_eq!(a["proj:code"], "EPSG:32617");
        assert_eq!(
            a["spatial:transform"],
            json!([0.5, 0.0, 630_000.0, 0.0, -0.5, 4_833_000.0])
        );
        assert_eq!(a["spatial:shape"], json!([100, 200]));
        assert_eq!(
            a["spatial:bbox"],
            json!([630_000.0, 4_832_950.0, 630_100.0, 4_833_000.0])
        );
        let names: Vec<&str> = a["zarr_conventions"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["name"].as_str().unwrap())
            .collect();
        assert_eq!(names, ["proj:", "spatial"]);
        let no_code = level_attributes(&gt, &Crs::default(), 100, 200);
        assert!(no_code.get("proj:code").is_none());
        assert_eq!(no_code["zarr_conventions"].as_array().unwrap().len(), 1);
    }

    #[test]
    fn multiscales_layout_doubles_the_cell_per_level() {
        let gt = GeoTransform::north_up(10.0, 20.0, 1.0, 1.0);
        let levels = [(gt, 64, 128), (gt.overview(1), 32, 64)];
        let m = multiscales(&levels, &utm());
        let layout = m["multiscales"]["layout"].as_array().unwrap();
        assert_eq!(layout[1]["asset"], "1");
        assert_eq!(layout[1]["derived_from"], "0");
        assert_eq!(layout[1]["transform"]["scale"], json!([2.0, 2.0]));
        assert_eq!(layout[1]["spatial:transform"][0], 2.0);
        assert_eq!(layout[0]["spatial:shape"], json!([64, 128]));
    }
}
