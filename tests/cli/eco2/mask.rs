//! `--mask`: a pair whose overlap changed in the middle registers off without
//! a mask and correctly with one (GeoTIFF, GeoJSON with a hole); a mask in
//! another CRS is refused; the journal records the mask.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use serde_json::{json, Value};

use dsmstream::geo::GeoTransform;
use dsmstream::geotiff::writer::{write_geotiff_f32, CogOptions};
use dsmstream::synth::output::epsg_crs;

use super::{error_m, matrix, rewrite, Box2, Truth};
use crate::util::{assert_refusal, dsmgen_tiles, fixtures, ingest, ok, run, text};

/// Two generated 512 px tiles (0.5 m) of which tile_01 has the middle of the
/// overlap raised by 5 m (a changed area larger than the unchanged one).
struct ChangedPair {
    dir: tempfile::TempDir,
    store: PathBuf,
    /// tile_00^-1 tile_01 of the truth.
    relative: Matrix4<f64>,
    overlap: Box2,
    raised: Box2,
}

fn changed_pair() -> ChangedPair {
    let dir = tempfile::tempdir().unwrap();
    let tiles = dir.path().join("tiles");
    // low noise, no spikes, no changed buildings: the change is the block alone
    let clean = ["--noise", "0.1", "--outliers", "0", "--no-changes"];
    let args = [
        &["--count", "2", "--size", "512", "--seed", "5"][..],
        &clean[..],
    ]
    .concat();
    dsmgen_tiles(&args, &tiles);
    let truth = Truth::load(&tiles);
    let (g0, g1) = (truth.gt(0), truth.gt(1));
    let side_m = 512.0 * 0.5;
    let overlap = Box2 {
        min_x: g1[0],
        max_x: g0[0] + side_m,
        min_y: g0[3] - side_m,
        max_y: g0[3],
    };
    // the middle of the overlap, 12 % in from each side: 58 % of its area
    let (inset_x, inset_y) = (0.12 * (overlap.max_x - overlap.min_x), 0.12 * side_m);
    let raised = Box2 {
        min_x: overlap.min_x + inset_x,
        max_x: overlap.max_x - inset_x,
        min_y: overlap.min_y + inset_y,
        max_y: overlap.max_y - inset_y,
    };
    rewrite(&tiles.join("tile_01.tif"), (0.0, 0.0), |x, y, h| {
        if raised.contains(x, y) {
            h + 5.0
        } else {
            h
        }
    });
    let store = dir.path().join("s.zarr");
    ingest(&[tiles], &store);
    ChangedPair {
        store,
        relative: truth.m(0).try_inverse().unwrap() * truth.m(1),
        overlap,
        raised,
        dir,
    }
}

/// A GeoTIFF mask of 1 m cells over `area`: 0 on `excluded`, 1 elsewhere.
fn write_tiff_mask(path: &Path, area: Box2, excluded: Box2, epsg: u32) {
    let (w, h) = (
        (area.max_x - area.min_x) as u64,
        (area.max_y - area.min_y) as u64,
    );
    let gt = GeoTransform::north_up(area.min_x, area.max_y, 1.0, 1.0);
    let data: Vec<f32> = (0..w * h)
        .map(|k| {
            let (x, y) = gt.pixel_to_world((k % w) as f64 + 0.5, (k / w) as f64 + 0.5);
            if excluded.contains(x, y) {
                0.0
            } else {
                1.0
            }
        })
        .collect();
    let options = CogOptions {
        geotransform: gt,
        crs: epsg_crs(epsg),
        ..Default::default()
    };
    write_geotiff_f32(path, w, h, options, &data).unwrap();
}

/// `pair tile_00 tile_01 --json <extra>` on the pair: its error against the truth.
fn pair_error(p: &ChangedPair, extra: &[&dyn AsRef<std::ffi::OsStr>]) -> f64 {
    let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> =
        vec![&"pair", &p.store, &"tile_00", &"tile_01", &"--json"];
    args.extend_from_slice(extra);
    let out = run(&args);
    let doc: Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|_| panic!("no JSON: {}", text(&out.stderr)));
    error_m(
        &matrix(&doc["matrix_world"]),
        &p.relative,
        &p.overlap.corners(),
    )
}

#[test]
fn a_mask_excluding_a_changed_area_registers_the_pair_correctly() {
    let p = changed_pair();
    let unmasked = pair_error(&p, &[]);
    assert!(unmasked > 1.0, "without a mask: {unmasked} m");
    // a GeoTIFF: the raised area (with 4 m for the offsets) excluded
    let area = p.overlap.grown(300.0);
    let tif = p.dir.path().join("stable.tif");
    write_tiff_mask(&tif, area, p.raised.grown(4.0), 32617);
    let masked = pair_error(&p, &[&"--mask", &tif]);
    assert!(masked < 0.1, "with a GeoTIFF mask: {masked} m");
    // GeoJSON polygons of the stable area: the whole area but a hole over the raised one
    let ring = |b: Box2| -> Vec<[f64; 2]> {
        let c = b.corners();
        [0, 1, 3, 2, 0].iter().map(|&k| [c[k].0, c[k].1]).collect()
    };
    let polygon = vec![ring(area), ring(p.raised.grown(4.0))];
    let geojson = p.dir.path().join("stable.geojson");
    let doc = json!({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {}, "geometry": {"type": "Polygon", "coordinates": polygon}}]});
    std::fs::write(&geojson, doc.to_string()).unwrap();
    let by_polygon = pair_error(&p, &[&"--mask", &geojson]);
    assert!(by_polygon < 0.1, "with GeoJSON polygons: {by_polygon} m");
    // the same polygons in longitude and latitude, as RFC 7946 and GIS
    // exports have them (no "crs" member): put into the DSMs' UTM zone
    let tm = dsmstream::geo::tm::Utm::from_epsg(32617)
        .unwrap()
        .projection();
    let degrees: Vec<Vec<[f64; 2]>> = (polygon.iter())
        .map(|ring| {
            (ring.iter())
                .map(|p| {
                    let (lon, lat) = tm.inverse(p[0], p[1]);
                    [lon, lat]
                })
                .collect()
        })
        .collect();
    let geojson_deg = p.dir.path().join("stable_degrees.geojson");
    let doc = json!({"type": "Polygon", "coordinates": degrees});
    std::fs::write(&geojson_deg, doc.to_string()).unwrap();
    let by_degrees = pair_error(&p, &[&"--mask", &geojson_deg]);
    assert!(
        (by_degrees - by_polygon).abs() < 0.01,
        "with the polygons in degrees: {by_degrees} m, in metres {by_polygon} m"
    );
    // a mask in another CRS (NAD83(CSRS): a datum dsmstream does not take as
    // WGS 84; a UTM zone or grid on WGS 84, NAD83 or ETRS89 would be sampled
    // into theirs): one line, exit 2, the file named
    let csrs = p.dir.path().join("csrs.tif");
    write_tiff_mask(&csrs, area, p.raised, 2958);
    let out = run(&[&"pair", &p.store, &"tile_00", &"tile_01", &"--mask", &csrs]);
    assert_refusal(&out, "csrs.tif", "EPSG:2958");
    // a mask with no stable cell in the overlap: said so, exit 2
    let elsewhere = p.dir.path().join("elsewhere.tif");
    write_tiff_mask(&elsewhere, area, p.overlap.grown(250.0), 32617);
    let out = run(&[
        &"pair", &p.store, &"tile_00", &"tile_01", &"--mask", &elsewhere,
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert!(err.contains("on the stable cells of the mask"), "{err}");
}

#[test]
fn the_journal_records_the_mask() {
    let dir = tempfile::tempdir().unwrap();
    let store = dir.path().join("c.zarr");
    ingest(&[fixtures().join("synth/chain4")], &store);
    let area = Box2 {
        min_x: 499_900.0,
        max_x: 500_400.0,
        min_y: 4_799_800.0,
        max_y: 4_800_100.0,
    };
    let (a, b) = (dir.path().join("a.tif"), dir.path().join("b.tif"));
    let nowhere = Box2 {
        min_x: 0.0,
        max_x: 1.0,
        min_y: 0.0,
        max_y: 1.0,
    };
    write_tiff_mask(&a, area, nowhere, 32617);
    write_tiff_mask(
        &b,
        area,
        Box2 {
            max_y: 4_799_810.0,
            ..area
        },
        32617,
    );
    let poses = dir.path().join("poses.json");
    let out = ok(run(&[&"align", &store, &"--out", &poses, &"--mask", &a]));
    assert!(
        text(&out.stdout).contains("aligned 4 DSMs"),
        "{}",
        text(&out.stdout)
    );
    let out = run(&[&"align", &store, &"--out", &poses, &"--mask", &b]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("--mask"),
        "{}",
        text(&out.stderr)
    );
    let again = ok(run(&[&"align", &store, &"--out", &poses, &"--mask", &a]));
    assert!(
        text(&again.stderr).contains("resumed"),
        "{}",
        text(&again.stderr)
    );
    let out = run(&[&"align", &store, &"--out", &poses]);
    assert_eq!(out.status.code(), Some(2), "no mask is another setting");
}
