//! Loading masks: GeoTIFF values to bits, GeoJSON on the DSMs' lattice, and
//! the refusals (another CRS, no overlap, unknown extension), each naming the file.

use super::*;
use crate::geotiff::writer::{write_geotiff_f32, CogOptions, CogSample};
use crate::synth::output::epsg_crs;

/// DSMs at 0.5 m over [500000, 500064] x [4800000, 4800064] in EPSG:32617.
fn target() -> MaskTarget {
    MaskTarget {
        crs: Some(epsg_crs(32617)),
        finest: GeoTransform::north_up(500_000.0, 4_800_064.0, 0.5, 0.5),
        extent: Bounds::from_corners((500_000.0, 4_800_000.0), (500_064.0, 4_800_064.0)),
    }
}

/// The corners (UTM 17N) of a polygon holding the DSMs' west half, E 500032
/// its east edge.
const WEST_HALF: [(f64, f64); 4] = [
    (499_990.0, 4_799_990.0),
    (500_032.0, 4_799_990.0),
    (500_032.0, 4_800_070.0),
    (499_990.0, 4_800_070.0),
];

/// A 32 x 32 mask of 2 m cells over the DSMs: 0 in its eastern half, NaN in
/// row 0, `value` elsewhere.
fn write_mask(path: &Path, epsg: u32, sample: CogSample, value: f32) {
    let options = CogOptions {
        geotransform: GeoTransform::north_up(500_000.0, 4_800_064.0, 2.0, 2.0),
        crs: epsg_crs(epsg),
        sample,
        ..Default::default()
    };
    let data: Vec<f32> = (0..32 * 32)
        .map(|k| match (k % 32, k / 32) {
            (_, 0) => f32::NAN,
            (c, _) if c >= 16 => 0.0,
            _ => value,
        })
        .collect();
    write_geotiff_f32(path, 32, 32, options, &data).unwrap();
}

#[test]
fn a_geotiff_mask_is_stable_where_non_zero() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stable.tif");
    for (sample, value) in [(CogSample::Float32, 0.25), (CogSample::UInt16, 3.0)] {
        write_mask(&path, 32617, sample, value);
        let mask = StableMask::load(&path, &target()).unwrap();
        assert_eq!(mask.pyramid.levels[0].count(), 31 * 16);
        let dsm = GeoTransform::north_up(500_000.0, 4_800_064.0, 0.5, 0.5);
        let lookup = mask.lookup(&dsm, 128, 128);
        assert!(lookup.is_stable(0, 4) && lookup.is_stable(63, 4));
        assert!(!lookup.is_stable(64, 4), "x = 500032: the zero half");
        assert!(!lookup.is_stable(0, 3), "the NaN row");
        assert!(format!("{mask:?}").contains("32 x 32 cells"));
    }
}

#[test]
fn a_mask_in_another_crs_is_refused_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    // NAD83(CSRS) / UTM 17N: a datum dsmstream does not take as WGS 84
    let path = dir.path().join("csrs.tif");
    write_mask(&path, 2958, CogSample::Float32, 1.0);
    let err = StableMask::load(&path, &target()).unwrap_err();
    assert!(err.is_bad_input());
    let text = err.to_string();
    assert!(
        text.contains("csrs.tif") && text.contains("EPSG:2958") && text.contains("EPSG:32617"),
        "{text}"
    );
    assert!(!text.contains('\n'));
}

#[test]
fn geojson_polygons_are_rasterised_on_the_finest_dsm_lattice() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("stable.geojson");
    // the western half, and a polygon far outside (clipped away)
    let text = r#"{"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "Polygon", "coordinates":
          [[[499990, 4799990], [500032, 4799990], [500032, 4800070], [499990, 4800070]]]}}]}"#;
    std::fs::write(&path, text).unwrap();
    let mask = StableMask::load(&path, &target()).unwrap();
    let l0 = &mask.pyramid.levels[0];
    assert_eq!(
        (l0.geotransform.gsd_x(), l0.width, l0.height),
        (0.5, 64, 128)
    );
    assert_eq!(l0.count(), 64 * 128);
    let lookup = mask.lookup(&target().finest, 128, 128);
    assert!(lookup.is_stable(63, 0) && !lookup.is_stable(64, 0));
    let other = text.replace(
        r#""type": "FeatureCollection","#,
        r#""type": "FeatureCollection", "crs": {"type": "name", "properties": {"name": "EPSG:4326"}},"#,
    );
    std::fs::write(&path, other).unwrap();
    let err = StableMask::load(&path, &target()).unwrap_err().to_string();
    assert!(
        err.contains("stable.geojson") && err.contains("EPSG:4326"),
        "{err}"
    );
}

/// The mask holds the western half of the DSMs of [`target`], E 500000 to
/// 500032, and nothing else (`what` says which mask in a failure).
fn assert_west_half_stable(mask: &StableMask, what: &str) {
    let lookup = mask.lookup(&target().finest, 128, 128);
    let stable = (0..128)
        .flat_map(|r| (0..128).map(move |c| (c, r)))
        .filter(|&(c, r)| lookup.is_stable(c, r))
        .count();
    assert_eq!(stable, 64 * 128, "{what}");
    assert!(
        lookup.is_stable(63, 0) && !lookup.is_stable(64, 0),
        "{what}"
    );
}

/// The polygons of the test above in longitude and latitude, as RFC 7946
/// GeoJSON has them (no "crs" member, or CRS84 named): put into the DSMs'
/// UTM zone, the same cells are stable. Degrees into DSMs in a CRS dsmstream
/// cannot project into (British National Grid) are refused.
#[test]
fn geojson_in_degrees_is_put_into_the_dsms_utm_zone() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("degrees.geojson");
    let tm = crate::geo::tm::Utm::from_epsg(32617).unwrap().projection();
    let ring: Vec<String> = WEST_HALF
        .iter()
        .map(|&(e, n)| {
            let (lon, lat) = tm.inverse(e, n);
            format!("[{lon:.12}, {lat:.12}]")
        })
        .collect();
    let text = format!(
        r#"{{"type": "Polygon", "coordinates": [[{}]]}}"#,
        ring.join(", ")
    );
    for doc in [
        text.clone(),
        text.replace(
            r#""type": "Polygon","#,
            r#""type": "Polygon", "crs": {"type": "name", "properties": {"name": "urn:ogc:def:crs:OGC:1.3:CRS84"}},"#,
        ),
    ] {
        std::fs::write(&path, &doc).unwrap();
        assert_west_half_stable(&StableMask::load(&path, &target()).unwrap(), &doc);
    }
    let local = MaskTarget {
        crs: Some(epsg_crs(27700)),
        ..target()
    };
    std::fs::write(
        &path,
        text.replace(
            r#""type": "Polygon","#,
            r#""type": "Polygon", "crs": {"properties": {"name": "EPSG:4326"}},"#,
        ),
    )
    .unwrap();
    let err = StableMask::load(&path, &local).unwrap_err().to_string();
    assert!(
        err.contains("degrees.geojson") && err.contains("is not a projected CRS dsmstream knows"),
        "{err}"
    );
}

/// A GeoTIFF mask in degrees (a land cover map as delivered): each cell of
/// the DSMs' lattice takes the mask cell its centre falls in. Stable west of
/// the meridian through E 500032 (zone 17's central meridian is E 500000, so
/// the meridian is a straight line there), in cells of 1e-5 degree (0.8 x
/// 1.1 m): the boundary lands within a mask cell of E 500032.
#[test]
fn a_geotiff_mask_in_degrees_is_sampled_on_the_dsm_lattice() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("landcover.tif");
    let tm = crate::geo::tm::Utm::from_epsg(32617).unwrap().projection();
    let (lon0, lat1) = tm.inverse(499_980.0, 4_800_080.0);
    let (split, _) = tm.inverse(500_032.0, 4_800_032.0);
    let cell = 1e-5;
    let (w, h) = (150u64, 100u64);
    let gt = GeoTransform::north_up(lon0, lat1, cell, cell);
    let data: Vec<f32> = (0..w * h)
        .map(|k| {
            let (lon, _) = gt.pixel_to_world((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
            if lon < split {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    let crs = Crs {
        epsg: Some(4326),
        is_geographic: true,
        geokeys: vec![1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326],
        ..Default::default()
    };
    let options = CogOptions {
        geotransform: gt,
        crs,
        ..Default::default()
    };
    write_geotiff_f32(&path, w, h, options, &data).unwrap();
    // cell centres 500000.25 + 0.5 c; the boundary within 0.85 m of 500032
    assert_stable_west_of(&path, 62..=66);
}

/// The GeoTIFF mask at `path`, sampled on the lattice of [`target`], is
/// stable in each row up to a first excluded cell within `edge` and not
/// after it.
fn assert_stable_west_of(path: &Path, edge: std::ops::RangeInclusive<i64>) {
    let mask = StableMask::load(path, &target()).unwrap();
    assert_eq!(mask.pyramid.levels[0].geotransform.gsd_x(), 0.5);
    let lookup = mask.lookup(&target().finest, 128, 128);
    for row in [0, 64, 127] {
        let first = (0..128).find(|&c| !lookup.is_stable(c, row)).unwrap();
        assert!(
            edge.contains(&first),
            "row {row}: first excluded cell {first}"
        );
        assert!((first..128).all(|c| !lookup.is_stable(c, row)));
    }
}

/// GeoJSON polygons naming the neighbouring UTM zone (EPSG:32618 for DSMs in
/// 17N), or a national grid on the DSMs' datum (NAD83 / Conus Albers for
/// DSMs in NAD83 / UTM 17N): the west half of the DSMs, its corners given in
/// that CRS, is put into 17N (edges cut every 100 m), and the same cells as
/// in 17N are stable.
#[test]
fn geojson_in_another_utm_zone_is_put_into_the_dsms_zone() {
    use crate::geo::proj::ProjectedCrs;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("other.geojson");
    for (dsms, polygons) in [(32617, 32618), (26917, 5070)] {
        let (z17, other) = (
            ProjectedCrs::from_epsg(dsms).unwrap().projection,
            ProjectedCrs::from_epsg(polygons).unwrap().projection,
        );
        let ring: Vec<String> = WEST_HALF
            .iter()
            .map(|&(e, n)| {
                let (lon, lat) = z17.inverse(e, n);
                let (x, y) = other.forward(lon, lat);
                format!("[{x:.6}, {y:.6}]")
            })
            .collect();
        let doc = format!(
            r#"{{"type": "Polygon", "crs": {{"type": "name", "properties": {{"name": "EPSG:{polygons}"}}}}, "coordinates": [[{}]]}}"#,
            ring.join(", ")
        );
        std::fs::write(&path, &doc).unwrap();
        let target = MaskTarget {
            crs: Some(epsg_crs(dsms)),
            ..target()
        };
        assert_west_half_stable(&StableMask::load(&path, &target).unwrap(), &doc);
    }
    // a CRS dsmstream does not know (NAD83(CSRS) / UTM 18N) is refused by name
    let doc = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, doc.replace("EPSG:5070", "EPSG:2959")).unwrap();
    let err = StableMask::load(&path, &target()).unwrap_err().to_string();
    assert!(
        err.contains("EPSG:2959") && err.contains("EPSG:32617"),
        "{err}"
    );
}

/// A GeoTIFF mask in the neighbouring UTM zone (18N for DSMs in 17N): each
/// cell of the DSMs' lattice takes the mask cell its centre falls in. Stable
/// where a 1 m cell's centre lies west of E 500032 in 17N, a line turned by
/// the zones' convergence in 18N: the boundary lands within a mask cell of it.
#[test]
fn a_geotiff_mask_in_another_utm_zone_is_sampled_on_the_dsm_lattice() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("zone18.tif");
    let (z17, z18) = (
        crate::geo::tm::Utm::from_epsg(32617).unwrap().projection(),
        crate::geo::tm::Utm::from_epsg(32618).unwrap().projection(),
    );
    let to18 = |e: f64, n: f64| {
        let (lon, lat) = z17.inverse(e, n);
        z18.forward(lon, lat)
    };
    let corners = [(500_000.0, 4_800_000.0), (500_064.0, 4_800_064.0)];
    let (mut x0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY);
    for e in [corners[0].0, corners[1].0] {
        for n in [corners[0].1, corners[1].1] {
            let (x, y) = to18(e, n);
            (x0, y1) = (x0.min(x), y1.max(y));
        }
    }
    let gt = GeoTransform::north_up((x0 - 20.0).floor(), (y1 + 20.0).ceil(), 1.0, 1.0);
    let (w, h) = (130u64, 130u64);
    let data: Vec<f32> = (0..w * h)
        .map(|k| {
            let (x, y) = gt.pixel_to_world((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
            let (lon, lat) = z18.inverse(x, y);
            f32::from(u8::from(z17.forward(lon, lat).0 < 500_032.0))
        })
        .collect();
    let options = CogOptions {
        geotransform: gt,
        crs: epsg_crs(32618),
        ..Default::default()
    };
    write_geotiff_f32(&path, w, h, options, &data).unwrap();
    // cell centres 500000.25 + 0.5 c; the boundary within a 1 m cell
    assert_stable_west_of(&path, 61..=67);
}

#[test]
fn masks_that_cannot_apply_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let far = dir.path().join("far.json");
    std::fs::write(
        &far,
        r#"{"type": "Polygon", "coordinates": [[[-80, 40], [-79, 40], [-79, 41]]]}"#,
    )
    .unwrap();
    let err = StableMask::load(&far, &target()).unwrap_err().to_string();
    assert!(
        err.contains("far.json") && err.contains("cover none"),
        "{err}"
    );
    let shp = dir.path().join("mask.shp");
    std::fs::write(&shp, "x").unwrap();
    let err = StableMask::load(&shp, &target()).unwrap_err().to_string();
    assert!(err.contains("mask.shp: a mask is a GeoTIFF"), "{err}");
    let missing = StableMask::load(&dir.path().join("none.tif"), &target()).unwrap_err();
    assert!(missing.is_bad_input() && missing.to_string().contains("none.tif"));
}
