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
    let path = dir.path().join("utm18.tif");
    write_mask(&path, 32618, CogSample::Float32, 1.0);
    let err = StableMask::load(&path, &target()).unwrap_err();
    assert!(err.is_bad_input());
    let text = err.to_string();
    assert!(
        text.contains("utm18.tif") && text.contains("EPSG:32618") && text.contains("EPSG:32617"),
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
