//! `dsmstream ingest` and `dsmstream info` run as the built binary on the real
//! fixtures: TTP 2015 (three 506 x 760 px rasters, EPSG:26917, NaN no-data)
//! and demcompare's SRTM tile in EPSG:4326 (must be refused, exit code 2).

use std::path::{Path, PathBuf};
use std::process::Output;

use crate::util::{assert_ok, assert_refusal, bin, fixtures, text};

fn fixture(rel: &str) -> PathBuf {
    fixtures().join("real").join(rel)
}

fn dsmstream(args: &[&str]) -> Output {
    bin().args(args).output().expect("run dsmstream")
}

fn ingest(inputs: &[&Path], store: &Path, extra: &[&str]) -> Output {
    let mut args: Vec<String> = vec!["ingest".into()];
    args.extend(inputs.iter().map(|p| p.display().to_string()));
    args.push("--store".into());
    args.push(store.display().to_string());
    args.extend(extra.iter().map(|s| s.to_string()));
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    dsmstream(&refs)
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(snapshot(&p));
        } else {
            out.push((p.clone(), std::fs::read(&p).unwrap()));
        }
    }
    out.sort();
    out
}

#[test]
fn ingest_directory_then_info_lists_all_three() {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("ttp.zarr");
    let out = ingest(&[&fixture("ttp2015")], &store, &["--chunk", "128"]);
    assert_ok(&out);
    let stdout = text(&out.stdout);
    for id in ["ttp_dsm_source", "ttp_dtm_source", "ttp_ndsm_source"] {
        assert!(
            stdout.contains(&format!("ingested {id}: 506 x 760 px")),
            "{stdout}"
        );
    }
    assert!(
        stdout.contains("3 ingested, 0 replaced, 0 skipped"),
        "{stdout}"
    );

    let info = dsmstream(&["info", store.to_str().unwrap()]);
    assert_ok(&info);
    let table = text(&info.stdout);
    assert!(
        table.contains("3 DSMs, CRS EPSG:26917, 3 overlapping footprint pairs"),
        "{table}"
    );
    assert!(table.contains("506 x 760"), "{table}");

    let json = dsmstream(&["info", store.to_str().unwrap(), "--json"]);
    assert_ok(&json);
    let doc: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    let dsms = doc["dsms"].as_array().unwrap();
    assert_eq!(dsms.len(), 3);
    for d in dsms {
        assert_eq!(
            d["levels"].as_array().unwrap().len(),
            5,
            "760 -> 380 -> 190 -> 95 -> 48 px (overviews down to 64 px)"
        );
        assert_eq!(d["geotransform"][1], 1.0);
        let valid = d["valid_count"].as_u64().unwrap();
        assert!(
            valid > 0 && valid < 506 * 760,
            "TTP is half water (NaN): {valid}"
        );
        assert_eq!(d["source_dtype"], "Float32");
    }
}

#[test]
fn rerun_skips_force_replaces_touched_source_replaces() {
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("ttp_dsm_source.tif");
    std::fs::copy(fixture("ttp2015/ttp_dsm_source.tif"), &src).unwrap();
    let store = tmp.path().join("c.zarr");
    assert_ok(&ingest(&[&src], &store, &[]));
    let again = ingest(&[&src], &store, &[]);
    assert_ok(&again);
    assert!(
        text(&again.stdout).contains("skipped  ttp_dsm_source"),
        "{}",
        text(&again.stdout)
    );
    assert!(text(&again.stdout).contains("0 ingested, 0 replaced, 1 skipped"));

    let forced = ingest(&[&src], &store, &["--force"]);
    assert_ok(&forced);
    assert!(text(&forced.stdout).contains("replaced ttp_dsm_source"));

    // A newer modification time counts as a changed source.
    let f = std::fs::OpenOptions::new().write(true).open(&src).unwrap();
    f.set_modified(std::time::SystemTime::now() + std::time::Duration::from_secs(5))
        .unwrap();
    drop(f);
    let touched = ingest(&[&src], &store, &[]);
    assert_ok(&touched);
    assert!(text(&touched.stdout).contains("replaced ttp_dsm_source"));
    let names: Vec<String> = std::fs::read_dir(&store)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        names
            .iter()
            .all(|n| !n.contains(".tmp-") && !n.contains(".old-")),
        "{names:?}"
    );
}

/// An ingest refused as bad input: exit 2, one line on stderr naming `file`
/// and saying `why`, and no store written.
fn assert_refused(out: &Output, store: &Path, file: &str, why: &str) {
    assert_refusal(out, file, why);
    assert!(!store.exists(), "nothing written for a refused input");
}

/// A DSM in longitude and latitude (demcompare's SRTM tile, 3" pixels,
/// EPSG:4326) is put into the collection's UTM zone as it is read, and says
/// so; `--utm-zone` chooses another zone, which must still be the
/// collection's; degrees on another datum, or far outside the zone, are
/// refused by name.
#[test]
fn a_dsm_in_degrees_is_put_into_the_collections_utm_zone() {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("c.zarr");
    let degrees = fixture("demcompare_srtm/srtm_ref.tif");
    assert_ok(&ingest(
        &[&fixture("demcompare_srtm/srtm_bs_utm.tif")],
        &store,
        &[],
    ));
    let out = ingest(&[&degrees], &store, &[]);
    assert_ok(&out);
    let said = text(&out.stdout);
    assert!(
        said.contains("ingested srtm_ref: 1015 x 1301 px")
            && said.contains(
                "reprojected from EPSG:4326 to EPSG:32637, UTM 37N (WGS 84) at 72 m (bilinear)"
            ),
        "{said}"
    );
    let info = dsmstream(&["info", &store.display().to_string(), "--json"]);
    let catalog: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let dsm = (catalog["dsms"].as_array().unwrap().iter())
        .find(|d| d["id"] == "srtm_ref")
        .unwrap();
    assert_eq!(dsm["crs"]["epsg"], 32637, "{dsm}");
    assert_eq!(dsm["geotransform"][1], 72.0, "{dsm}");
    assert_eq!(dsm["reprojected"]["from"], "EPSG:4326", "{dsm}");
    assert_eq!(dsm["source_dtype"], "Int16", "{dsm}");
    let table = text(&dsmstream(&["info", &store.display().to_string()]).stdout);
    assert!(
        table.contains("reprojected at ingest: srtm_ref (from EPSG:4326 at 72 m)"),
        "{table}"
    );
    // degrees named only by an ESRI .prj beside a world file (no code: its
    // datum by name)
    let side = fixtures().join("geotiff/wf_deg_srtm.tif");
    let out = ingest(&[&side], &store, &[]);
    assert_ok(&out);
    let said = text(&out.stdout);
    assert!(
        said.contains("georeferenced by wf_deg_srtm.tfw, wf_deg_srtm.prj; reprojected from")
            && said.contains("to EPSG:32637, UTM 37N (WGS 84) at 72 m"),
        "{said}"
    );
    // unchanged, skipped: the line still says where it came from
    let again = text(&ingest(&[&degrees], &store, &[]).stdout);
    assert!(
        again.contains("skipped  srtm_ref") && again.contains("reprojected from EPSG:4326"),
        "{again}"
    );

    // another zone: its own store takes it, this one refuses it
    let other = tmp.path().join("z38.zarr");
    let out = ingest(&[&degrees], &other, &["--utm-zone", "38N"]);
    assert_ok(&out);
    assert!(text(&out.stdout).contains("to EPSG:32638, UTM 38N (WGS 84)"));
    let before = snapshot(&store);
    let out = ingest(&[&degrees], &store, &["--utm-zone", "38N", "--force"]);
    assert_refusal(
        &out,
        "srtm_ref.tif",
        "CRS EPSG:32638 (put there from EPSG:4326) differs from the collection's CRS EPSG:32637",
    );
    assert_eq!(snapshot(&store), before);

    let write = |name: &str, code: u16, lon: f64| {
        let crs = dsmstream::geo::Crs {
            epsg: Some(u32::from(code)),
            is_geographic: true,
            geokeys: vec![1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, code],
            ..Default::default()
        };
        write_with_crs(tmp.path(), name, crs, (lon, 39.5), 1.0 / 1200.0)
    };
    let ed50 = write("ed50.tif", 4230, 40.0);
    let out = ingest(&[&ed50], &store, &[]);
    assert_refusal(
        &out,
        "ed50.tif",
        "geographic CRS EPSG:4230 (degrees) is not a metric frame",
    );
    let far = write("far.tif", 4326, 100.0);
    let out = ingest(&[&far], &store, &[]);
    assert_refusal(
        &out,
        "far.tif",
        "its footprint (longitude 100.0000 to 100.0267",
    );
    assert_eq!(snapshot(&store), before);
    // a zone for inputs that are already in it is said to do nothing
    let metres = ingest(
        &[&fixture("demcompare_srtm/srtm_ref_utm.tif")],
        &tmp.path().join("metres.zarr"),
        &["--utm-zone", "37N"],
    );
    assert_ok(&metres);
    assert!(
        text(&metres.stderr).contains("--utm-zone 37N has no effect"),
        "{}",
        text(&metres.stderr)
    );
    let bad_zone = ingest(&[&degrees], &other, &["--utm-zone", "61N"]);
    assert_eq!(bad_zone.status.code(), Some(2));
    assert!(text(&bad_zone.stderr).contains("not a UTM zone: \"61N\""));
}

/// `--crs` puts DSMs into a national or polar grid by its EPSG code:
/// xdem-data's Svalbard crops (ETRS89 / UTM 33N) into LAEA Europe, where the
/// two that share a lattice still pair to the identity; SRTM in degrees
/// (WGS 84, at 40 N 40 E) into Lambert-93 (ETRS89), taken as on one datum
/// and said so; into NSIDC's or the Antarctic polar stereographic it is
/// refused for its footprint, and a grid dsmstream does not know (British
/// National Grid, OSGB36) as a bad flag.
#[test]
fn crs_puts_dsms_into_a_national_or_polar_grid_by_its_code() {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("laea.zarr");
    let out = ingest(&[&fixture("xdem_gdal")], &store, &["--crs", "EPSG:3035"]);
    assert_ok(&out);
    let said = text(&out.stdout);
    assert_eq!(
        said.matches(
            "reprojected from EPSG:25833 to EPSG:3035, ETRS89-extended / LAEA Europe at 20 m"
        )
        .count(),
        3,
        "{said}"
    );
    let (code, doc) = crate::util::pair_json(
        &store,
        "shifted_reprojected_xoff200.0_yoff200.0",
        "shifted_reprojected_xoff20.0_yoff20.0",
    );
    assert_eq!(code, Some(0), "{doc}");
    // no move at the fit's centre
    let (m, c) = (&doc["result"]["matrix_world"], &doc["result"]["centre_m"]);
    let p: Vec<f64> = (0..3).map(|k| c[k].as_f64().unwrap()).collect();
    for (k, p_k) in p.iter().enumerate() {
        let moved = (0..3)
            .map(|j| m[k][j].as_f64().unwrap() * p[j])
            .sum::<f64>()
            + m[k][3].as_f64().unwrap();
        assert!((moved - p_k).abs() < 0.01, "{m} at {c}");
    }
    let degrees = fixture("demcompare_srtm/srtm_ref.tif");
    let out = ingest(
        &[&degrees],
        &tmp.path().join("l93.zarr"),
        &["--crs", "EPSG:2154"],
    );
    assert_ok(&out);
    let said = text(&out.stdout);
    assert!(
        said.contains("reprojected from EPSG:4326 to EPSG:2154, RGF93 v1 / Lambert-93 at 72 m (bilinear; WGS 84 taken as ETRS89)"),
        "{said}"
    );
    let polar = tmp.path().join("polar.zarr");
    for (flag, problem) in [
        ("EPSG:3413", "cannot be put into EPSG:3413, WGS 84 / NSIDC Sea Ice Polar Stereographic North: its scale there is off by more than 5 %"),
        ("EPSG:3031", "cannot be put into EPSG:3031, WGS 84 / Antarctic Polar Stereographic: its scale there is off by more than 5 %"),
    ] {
        let out = ingest(&[&degrees], &polar, &["--crs", flag]);
        assert_eq!(out.status.code(), Some(2), "{flag}");
        let err = text(&out.stderr);
        assert!(err.lines().count() == 1 && err.contains(problem), "{flag}: {err}");
        assert!(!polar.exists(), "{flag}: no store is left");
    }
    // beyond 84 degrees a new store of DSMs in degrees is in UPS
    let crs = dsmstream::geo::Crs {
        epsg: Some(4326),
        is_geographic: true,
        geokeys: vec![1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 1, 2048, 0, 1, 4326],
        ..Default::default()
    };
    let north = write_with_crs(tmp.path(), "n86.tif", crs, (10.0, 86.5), 1.0 / 1200.0);
    let out = ingest(&[&north], &tmp.path().join("ups.zarr"), &[]);
    assert_ok(&out);
    assert!(
        text(&out.stdout)
            .contains("reprojected from EPSG:4326 to EPSG:5041, WGS 84 / UPS North (E,N)"),
        "{}",
        text(&out.stdout)
    );
    let unknown = ingest(&[&degrees], &polar, &["--crs", "EPSG:27700"]);
    assert_eq!(unknown.status.code(), Some(2));
    assert!(text(&unknown.stderr).contains("not a CRS dsmstream can put DSMs into"));
}

/// A 32 x 32 ramp of heights with this CRS and a pixel of `pixel` m from
/// `origin` (top-left corner), written as `dir`/`name`.
fn write_with_crs(
    dir: &Path,
    name: &str,
    crs: dsmstream::geo::Crs,
    origin: (f64, f64),
    pixel: f64,
) -> PathBuf {
    use dsmstream::geo::GeoTransform;
    use dsmstream::geotiff::writer::{write_geotiff_f32, CogOptions};
    let options = CogOptions {
        geotransform: GeoTransform::north_up(origin.0, origin.1, pixel, pixel),
        crs,
        ..Default::default()
    };
    let data: Vec<f32> = (0..32 * 32).map(|k| 150.0 + (k % 32) as f32).collect();
    let path = dir.join(name);
    write_geotiff_f32(&path, 32, 32, options, &data).unwrap();
    path
}

/// A DSM in a CRS whose unit is the foot (US State Plane and Oregon Lambert
/// rasters often are): every distance the tool reports is in metres, so the
/// file is refused by name, its unit said, rather than registered in feet
/// read as metres.
#[test]
fn a_dsm_in_feet_is_refused_with_its_unit() {
    let tmp = tempfile::tempdir().unwrap();
    let write = |name: &str, unit_key: Option<[u16; 4]>| {
        // EPSG:2992, NAD83 / Oregon GIC Lambert (ft), as GDAL writes it
        // (with the unit key) or as writers that give the code alone do
        let count = 3 + u16::from(unit_key.is_some());
        let mut geokeys = vec![
            1, 1, 0, count, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 2992,
        ];
        geokeys.extend(unit_key.iter().flatten());
        let crs = dsmstream::geo::Crs {
            epsg: Some(2992),
            geokeys,
            ..Default::default()
        };
        write_with_crs(tmp.path(), name, crs, (7_650_000.0, 700_000.0), 3.0)
    };
    let feet = write("autzen_ft.tif", Some([3076, 0, 1, 9002]));
    let store = tmp.path().join("c.zarr");
    let out = ingest(&[&feet], &store, &[]);
    assert_refused(
        &out,
        &store,
        "autzen_ft.tif",
        "horizontal unit foot (EPSG unit 9002) in CRS EPSG:2992, not metres",
    );
    // the code alone: its unit is the EPSG definition's
    let code_only = write("autzen_code.tif", None);
    let out = ingest(&[&code_only], &store, &[]);
    assert_refused(
        &out,
        &store,
        "autzen_code.tif",
        "horizontal unit foot (EPSG unit 9002) by its EPSG definition in CRS EPSG:2992, not metres",
    );
    // the same raster in metres (the unit key says so) is taken
    let metres = write("autzen_m.tif", Some([3076, 0, 1, 9001]));
    assert_ok(&ingest(&[&metres], &store, &[]));
}

/// A national or polar grid written by GDAL from a PROJ string, as
/// user-defined GeoTIFF keys without a code (fixtures/geotiff/ud_*.tif,
/// `tools/scripts/make_user_defined_grids.py`: Lambert-93 on GRS80 with a
/// zero shift, NSIDC's polar stereographic, Conus Albers), is one collection
/// with its EPSG twin: neither is reprojected. A DSM in UTM joins the Albers
/// one's store, put into it.
#[test]
fn a_grid_written_as_user_defined_keys_joins_its_epsg_twin() {
    let tmp = tempfile::tempdir().unwrap();
    for (file, code, origin) in [
        ("ud_lambert93.tif", 2154u16, (652_000.0, 6_862_000.0)),
        ("ud_nsidc_north.tif", 3413, (-200_000.0, -2_000_000.0)),
        ("ud_conus_albers.tif", 5070, (1_332_000.0, 2_409_700.0)),
    ] {
        let crs = dsmstream::geo::Crs {
            epsg: Some(u32::from(code)),
            geokeys: vec![1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, code],
            ..Default::default()
        };
        let twin = write_with_crs(tmp.path(), &format!("twin_{code}.tif"), crs, origin, 1.0);
        let store = tmp.path().join(format!("{code}.zarr"));
        let out = ingest(
            &[&fixtures().join("geotiff").join(file), &twin],
            &store,
            &[],
        );
        assert_ok(&out);
        let said = text(&out.stdout);
        assert!(!said.contains("reprojected"), "{file}: {said}");
        if code == 5070 {
            let utm = fixture("ttp2015/ttp_dsm_source.tif");
            let out = ingest(&[&utm], &store, &[]);
            assert_ok(&out);
            assert!(
                text(&out.stdout).contains("reprojected from EPSG:26917 to EPSG:5070"),
                "{}",
                text(&out.stdout)
            );
        }
    }
}

/// One UTM zone described two ways, as GDAL writes it (EPSG:32617) and as a
/// user-defined Transverse Mercator on WGS 84 with its own citation (other
/// producers), is one collection; a TM one degree off is another CRS.
#[test]
fn a_utm_zone_written_as_user_defined_joins_its_epsg_twin() {
    let tmp = tempfile::tempdir().unwrap();
    let write = |name: &str, geokeys: Vec<u16>, doubles: Vec<f64>, ascii: Option<&str>| {
        let crs = dsmstream::geo::Crs {
            geokeys,
            geo_doubles: doubles,
            geo_ascii: ascii.map(str::to_string),
            ..Default::default()
        };
        write_with_crs(tmp.path(), name, crs, (500_000.0, 4_800_000.0), 1.0)
    };
    let gdal = write(
        "gdal.tif",
        vec![1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32617],
        vec![],
        None,
    );
    // projected, user-defined, WGS 84, TM, metres, its citation, then the
    // central meridian, latitude of origin, false easting and northing, scale
    let custom = |long: f64| {
        let entries: [[u16; 4]; 13] = [
            [1024, 0, 1, 1],
            [1025, 0, 1, 1],
            [2048, 0, 1, 4326],
            [3072, 0, 1, 32767],
            [3073, 34737, 22, 0],
            [3074, 0, 1, 32767],
            [3075, 0, 1, 1],
            [3076, 0, 1, 9001],
            [3080, 34736, 1, 0],
            [3081, 34736, 1, 1],
            [3082, 34736, 1, 2],
            [3083, 34736, 1, 3],
            [3092, 34736, 1, 4],
        ];
        let mut keys = vec![1, 1, 0, entries.len() as u16];
        keys.extend(entries.iter().flatten());
        (keys, vec![long, 0.0, 500_000.0, 0.0, 0.9996])
    };
    let (keys, doubles) = custom(-81.0);
    let twin = write("custom.tif", keys, doubles, Some("UTM 17 North (custom)|"));
    let store = tmp.path().join("c.zarr");
    assert_ok(&ingest(&[&gdal, &twin], &store, &[]));
    let info = text(&dsmstream(&["info", store.to_str().unwrap()]).stdout);
    assert!(info.contains("2 DSMs, CRS EPSG:32617"), "{info}");
    // one degree east of the zone's meridian: not the collection's CRS
    let (keys, doubles) = custom(-80.0);
    let off = write("off.tif", keys, doubles, Some("UTM 17 North (custom)|"));
    let out = ingest(&[&off], &store, &[]);
    assert_refusal(
        &out,
        "off.tif",
        "differs from the collection's CRS EPSG:32617",
    );
}

/// (valid pixels, min, max, mean) of DSM `id` in `store`, from `info --json`.
fn height_stats(store: &Path, id: &str) -> (u64, f64, f64, f64) {
    let out = dsmstream(&["info", store.to_str().unwrap(), "--json"]);
    let catalog: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let dsms = catalog["dsms"].as_array().unwrap();
    let dsm = dsms.iter().find(|d| d["id"] == id).unwrap();
    let get = |k: &str| dsm["height_stats"][k].as_f64().unwrap();
    let count = dsm["valid_count"].as_u64().unwrap();
    (count, get("min"), get("max"), get("mean"))
}

/// Ingest fixture `file` (fixtures/geotiff) beside `f32_tile_deflate.tif`,
/// the same surface stored plainly with a no-data value; the two heights'
/// (valid pixels, min, max, mean).
fn ingested_beside_the_plain_twin(file: &str) -> [(u64, f64, f64, f64); 2] {
    let tmp = tempfile::tempdir().unwrap();
    let geotiff = fixtures().join("geotiff");
    let store = tmp.path().join("c.zarr");
    let twin = geotiff.join("f32_tile_deflate.tif");
    assert_ok(&ingest(&[&geotiff.join(file), &twin], &store, &[]));
    let id = file.trim_end_matches(".tif");
    [
        height_stats(&store, id),
        height_stats(&store, "f32_tile_deflate"),
    ]
}

/// A DSM stored with LERC (as ESRI tools and GDAL's COMPRESS=LERC_ZSTD write
/// it) is ingested to the same heights as the same raster stored with Deflate.
#[test]
fn a_lerc_dsm_is_ingested_like_its_deflate_twin() {
    let [lerc, twin] = ingested_beside_the_plain_twin("f32_tile_lerc_zstd.tif");
    assert_eq!(lerc, twin);
    assert!(twin.0 > 2000, "{twin:?}");
}

/// A half-float DSM (GDAL's Float32 with NBITS=16; Float16 in GDAL 3.11)
/// is ingested to its twin's heights within a half float's step (1/16 m
/// between 64 and 128 m, GDAL truncating), its no-data -9999 (stored as the
/// half float -9992) as no-data.
#[test]
fn a_half_float_dsm_is_ingested_within_a_half_float_step_of_its_twin() {
    let [(n, lo, hi, mean), (n_twin, lo_t, hi_t, mean_t)] =
        ingested_beside_the_plain_twin("f16_tile_deflate_nodata_9999.tif");
    assert_eq!(n, n_twin, "no-data pixels read as heights");
    for (a, b) in [(lo, lo_t), (hi, hi_t), (mean, mean_t)] {
        assert!(a <= b && b - a < 0.0625, "{a} vs {b}");
    }
}

/// A DSM georeferenced only beside the file (a `.wld` world file and an ESRI
/// `.prj`, as ArcGIS delivers it) is one collection with its twin whose
/// GeoTIFF tags say the same: same CRS, place and heights; ingest names the
/// side files it read. The store records
/// the side files: a world file moved 10 m east re-ingests the DSM 10 m east,
/// and without its `.prj` the DSM has no CRS and is refused, the store kept.
#[test]
fn a_dsm_georeferenced_by_side_files_is_its_twin_and_follows_them() {
    let [side, twin] = ingested_beside_the_plain_twin("wf_wld_prj.tif");
    assert_eq!(side, twin);
    let tmp = tempfile::tempdir().unwrap();
    let geotiff = fixtures().join("geotiff");
    for ext in ["tif", "wld", "prj"] {
        std::fs::copy(
            geotiff.join(format!("wf_wld_prj.{ext}")),
            tmp.path().join(format!("a.{ext}")),
        )
        .unwrap();
    }
    let (tif, store) = (tmp.path().join("a.tif"), tmp.path().join("c.zarr"));
    let dsm = || {
        let out = dsmstream(&["info", store.to_str().unwrap(), "--json"]);
        let catalog: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        catalog["dsms"][0].clone()
    };
    let out = ingest(&[&tif], &store, &[]);
    assert_ok(&out);
    let said = text(&out.stdout);
    assert!(said.contains("; georeferenced by a.wld, a.prj"), "{said}");
    assert_eq!(dsm()["geotransform"][0], 630000.5);
    assert_eq!(dsm()["crs"]["epsg"], 32617);
    assert_eq!(dsm()["source"]["side_files"].as_array().unwrap().len(), 2);
    let east = "0.5\n0.0\n0.0\n-0.5\n630010.75\n4830000.0\n";
    std::fs::write(tmp.path().join("a.wld"), east).unwrap();
    let out = ingest(&[&tif], &store, &[]);
    assert_ok(&out);
    assert!(
        text(&out.stdout).contains("1 replaced"),
        "{}",
        text(&out.stdout)
    );
    assert_eq!(dsm()["geotransform"][0], 630010.5);
    std::fs::remove_file(tmp.path().join("a.prj")).unwrap();
    assert_refusal(&ingest(&[&tif], &store, &[]), "a.tif", "no CRS");
    assert_eq!(dsm()["geotransform"][0], 630010.5, "the store is kept");
}

/// An `.aux.xml` whose GeoTransform differs from the file's own tags wins,
/// as GDAL reads it, and the user is told so once.
#[test]
fn a_side_file_overriding_the_tags_is_taken_and_said_once() {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("c.zarr");
    let file = fixtures().join("geotiff").join("wf_pam_over_tags.tif");
    let out = ingest(&[&file], &store, &[]);
    assert_ok(&out);
    let err = text(&out.stderr);
    let said = "wf_pam_over_tags.tif.aux.xml: its GeoTransform [630010.5, 0.5, 0.0, 4830000.25, 0.0, -0.5] overrides the one of the file's own tags";
    assert_eq!(err.matches(said).count(), 1, "{err}");
    let info = dsmstream(&["info", store.to_str().unwrap(), "--json"]);
    let catalog: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(catalog["dsms"][0]["geotransform"][0], 630010.5);
}

/// A national grid named by an ESRI `.prj` without a code (ArcGIS writes
/// them so): xdem's crop without GeoTIFF tags (fixtures/geotiff/wf_real_xdem)
/// given a world file in ETRS89 / LAEA Europe and the `.prj` PROJ writes for
/// it (`to_wkt("WKT1_ESRI")`) is identified as EPSG:3035 and makes the
/// store's CRS; the crops in ETRS89 / UTM 33N are then put into it.
#[test]
fn a_grid_named_by_an_esri_prj_is_identified_by_its_parameters() {
    let tmp = tempfile::tempdir().unwrap();
    let geotiff = fixtures().join("geotiff");
    let tif = tmp.path().join("laea.tif");
    std::fs::copy(geotiff.join("wf_real_xdem.tif"), &tif).unwrap();
    std::fs::copy(
        geotiff.join("wf_real_xdem.tif.aux.xml"),
        tmp.path().join("laea.tif.aux.xml"),
    )
    .unwrap();
    std::fs::write(
        tmp.path().join("laea.tfw"),
        "20\n0\n0\n-20\n4444480\n6102630\n",
    )
    .unwrap();
    let esri = r#"PROJCS["ETRS_1989_LAEA",GEOGCS["GCS_ETRS_1989",DATUM["D_ETRS_1989",SPHEROID["GRS_1980",6378137.0,298.257222101]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]],PROJECTION["Lambert_Azimuthal_Equal_Area"],PARAMETER["False_Easting",4321000.0],PARAMETER["False_Northing",3210000.0],PARAMETER["Central_Meridian",10.0],PARAMETER["Latitude_Of_Origin",52.0],UNIT["Meter",1.0]]"#;
    std::fs::write(tmp.path().join("laea.prj"), esri).unwrap();
    let store = tmp.path().join("laea.zarr");
    let crop = fixture("xdem_gdal/shifted_reprojected_xoff20.0_yoff20.0.tif");
    let out = ingest(&[&tif, &crop], &store, &[]);
    assert_ok(&out);
    let said = text(&out.stdout);
    assert!(
        said.contains("georeferenced by laea.tfw, laea.prj")
            && said.contains(
                "reprojected from EPSG:25833 to EPSG:3035, ETRS89-extended / LAEA Europe"
            ),
        "{said}"
    );
    let info = dsmstream(&["info", store.to_str().unwrap(), "--json"]);
    let catalog: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    assert_eq!(catalog["crs"], "EPSG:3035");
}

/// Side files that cannot be read are refused by name, nothing written: a
/// `.prj` whose CRS names no EPSG code and is no UTM zone, a world file of
/// five numbers, an `.aux.xml` that is not XML, a rotated world file.
#[test]
fn side_files_that_cannot_be_read_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let geotiff = fixtures().join("geotiff");
    for (file, side, why) in [
        (
            "bad_wf_prj_lambert.tif",
            "bad_wf_prj_lambert.prj",
            "names no EPSG code",
        ),
        (
            "bad_wf_short.tif",
            "bad_wf_short.tfw",
            "bad world file: holds 5 numbers, not 6",
        ),
        (
            "bad_wf_aux_xml.tif",
            "bad_wf_aux_xml.tif.aux.xml",
            "not valid XML",
        ),
        ("bad_wf_rotated.tif", "bad_wf_rotated.tfw", "not north-up"),
    ] {
        let store = tmp.path().join(format!("{file}.zarr"));
        let out = ingest(&[&geotiff.join(file)], &store, &[]);
        assert_refused(&out, &store, side, why);
    }
}

/// A DSM whose no-data is GDAL's internal mask band (no no-data value, the
/// masked pixels hold 0) is ingested with those pixels as no-data: the same
/// heights as its twin with a no-data value, no zeros.
#[test]
fn gdal_s_internal_mask_makes_no_data() {
    let [masked, twin] = ingested_beside_the_plain_twin("f32_tile_deflate_mask.tif");
    assert_eq!(masked, twin);
    assert!(masked.1 > 50.0, "masked zeros read as heights: {masked:?}");
}

/// Heights stored as integers with GDAL's band scale and offset (centimetres
/// about 100 m) are ingested in metres, equal to the same surface stored as
/// Float32; a band whose unit is feet is refused by name, nothing written.
#[test]
fn gdal_band_scale_and_offset_give_metres_and_a_band_in_feet_is_refused() {
    let [(n_scaled, lo, hi, mean), (n_float, lo_f, hi_f, mean_f)] =
        ingested_beside_the_plain_twin("i16_scale_offset.tif");
    assert_eq!(n_scaled, n_float);
    // centimetre integers: within half a centimetre of the float surface
    for (a, b) in [(lo, lo_f), (hi, hi_f), (mean, mean_f)] {
        assert!((a - b).abs() <= 0.005 + 1e-6, "{a} vs {b}");
    }
    let tmp = tempfile::tempdir().unwrap();
    let feet = fixtures().join("geotiff").join("f32_units_ft.tif");
    let store = tmp.path().join("ft.zarr");
    let out = ingest(&[&feet], &store, &[]);
    assert_refused(
        &out,
        &store,
        "f32_units_ft.tif",
        "height unit \"ft\" (GDAL band metadata), not metres",
    );
}

/// A lidar file handed to ingest (the usual mistake) is named for what it is.
#[test]
fn a_point_cloud_is_refused_with_what_to_do() {
    let tmp = tempfile::tempdir().unwrap();
    let laz = tmp.path().join("epoch.laz");
    let mut header = b"LASF".to_vec();
    header.resize(375, 0);
    std::fs::write(&laz, header).unwrap();
    let store = tmp.path().join("c.zarr");
    let out = ingest(&[&laz], &store, &[]);
    assert_refused(
        &out,
        &store,
        "epoch.laz",
        "a LAS/LAZ point cloud: grid it into a DSM GeoTIFF first",
    );
}

#[test]
fn failed_ingest_leaves_the_store_untouched() {
    let tmp = tempfile::tempdir().unwrap();
    let store = tmp.path().join("c.zarr");
    assert_ok(&ingest(
        &[&fixture("ttp2015/ttp_dsm_source.tif")],
        &store,
        &[],
    ));
    let before = snapshot(&store);
    // A valid new file first, then a geographic one: the run is refused as a whole.
    let out = ingest(
        &[
            &fixture("ttp2015/ttp_dtm_source.tif"),
            &fixture("demcompare_srtm/srtm_ref.tif"),
        ],
        &store,
        &[],
    );
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert_eq!(snapshot(&store), before);
    // A UTM zone far from the collection's: it cannot be put into it.
    let out = ingest(&[&fixture("demcompare_srtm/srtm_ref_utm.tif")], &store, &[]);
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("srtm_ref_utm.tif: its footprint")
            && err.contains("cannot be put into EPSG:26917, UTM 17N (NAD83)"),
        "{err}"
    );
    assert_eq!(snapshot(&store), before);
}

#[test]
fn unwritable_store_path_is_a_clear_error() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("plain_file");
    std::fs::write(&file, b"not a directory").unwrap();
    let store = file.join("c.zarr");
    let out = ingest(&[&fixture("ttp2015/ttp_dsm_source.tif")], &store, &[]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert!(
        err.contains("plain_file/c.zarr") && err.contains("cannot use as a store"),
        "{err}"
    );
}

#[test]
fn info_on_a_non_store_is_exit_2() {
    let tmp = tempfile::tempdir().unwrap();
    let out = dsmstream(&["info", tmp.path().to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("not a dsmstream store"));
}

/// SRTM tiles as delivered: a zipped HGT tile (fixtures/hgt, real SRTM
/// heights) and the same tile unzipped, named or found in a folder, are put
/// into UTM like any DSM in degrees and give the same DSM; a truncated
/// download, a tile its name does not place and an archive that names
/// another tile are refused by name, the store untouched.
#[test]
fn srtm_hgt_tiles_plain_and_zipped_are_ingested() {
    let tmp = tempfile::tempdir().unwrap();
    let zipped = fixtures().join("hgt/N39E040.SRTMGL3.hgt.zip");
    let store = tmp.path().join("h.zarr");
    let out = ingest(&[&fixtures().join("hgt")], &store, &[]);
    assert_ok(&out);
    let said = text(&out.stdout);
    assert!(
        said.contains("ingested N39E040.SRTMGL3: 1222 x 1563 px")
            && said.contains("reprojected from EPSG:4326 to EPSG:32637, UTM 37N (WGS 84) at 72 m"),
        "{said}"
    );
    // the tile unzipped (as `unzip` leaves it), beside it in the store
    let bytes = std::fs::read(&zipped).unwrap();
    let plain = tmp.path().join("N39E040.hgt");
    std::fs::write(&plain, unzip_one(&bytes)).unwrap();
    assert_ok(&ingest(&[&plain], &store, &[]));
    let info = dsmstream(&["info", &store.display().to_string(), "--json"]);
    let catalog: serde_json::Value = serde_json::from_slice(&info.stdout).unwrap();
    let dsms = catalog["dsms"].as_array().unwrap();
    let [a, b] = [dsms[0].clone(), dsms[1].clone()];
    let keys = [
        "geotransform",
        "width",
        "height",
        "crs",
        "valid_count",
        "height_stats",
    ];
    for key in keys {
        assert_eq!(a[key], b[key], "{key}: {a} / {b}");
    }
    assert_eq!(a["source_dtype"], "Int16");
    assert!(a["valid_count"].as_u64().unwrap() > 300_000, "{a}");

    let before = snapshot(&store);
    let truncated = tmp.path().join("N39E041.hgt");
    std::fs::write(&truncated, &unzip_one(&bytes)[..1_000_000]).unwrap();
    let out = ingest(&[&truncated], &store, &[]);
    assert_refusal(
        &out,
        "N39E041.hgt",
        "1000000 bytes is not an SRTM HGT tile (truncated?)",
    );
    let unnamed = tmp.path().join("dem.hgt");
    std::fs::copy(&plain, &unnamed).unwrap();
    let out = ingest(&[&unnamed], &store, &[]);
    assert_refusal(
        &out,
        "dem.hgt",
        "name must start with its tile, as N39E040.hgt",
    );
    let renamed = tmp.path().join("N38E040.hgt.zip");
    std::fs::copy(&zipped, &renamed).unwrap();
    let out = ingest(&[&renamed], &store, &[]);
    assert_refusal(
        &out,
        "N38E040.hgt.zip",
        "name says N38E040 but it holds N39E040.hgt",
    );
    let cut = tmp.path().join("N39E040.SRTMGL1.hgt.zip");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let out = ingest(&[&cut], &store, &[]);
    assert_refusal(
        &out,
        "N39E040.SRTMGL1.hgt.zip",
        "not a zip archive, or truncated",
    );
    assert_eq!(snapshot(&store), before);
}

/// The one member of a zip archive of one Deflate member, inflated by hand
/// (the test does not trust the reader under test).
fn unzip_one(archive: &[u8]) -> Vec<u8> {
    use std::io::Read;
    let u16_at = |at: usize| u16::from_le_bytes([archive[at], archive[at + 1]]) as usize;
    let u32_at = |at: usize| u32::from_le_bytes(archive[at..at + 4].try_into().unwrap()) as usize;
    assert_eq!(u32_at(0), 0x0403_4b50, "a local header first");
    assert_eq!(u16_at(8), 8, "Deflate");
    let start = 30 + u16_at(26) + u16_at(28);
    let mut out = Vec::new();
    flate2::read::DeflateDecoder::new(&archive[start..start + u32_at(18)])
        .read_to_end(&mut out)
        .unwrap();
    assert_eq!(out.len(), u32_at(22));
    out
}
