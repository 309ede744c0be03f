//! Integration tests of outputs people stack and inputs people have (issue 14
//! items 7, 8-VRT, 9): fuse's band descriptions and units, `count` as a UInt16
//! band, `--bounds` and `--nodata`, read back with the crate's own GeoTIFF
//! reader and the raw GDAL tags; a VRT mosaic ingested as one DSM; the demo.

use std::fs::File;
use std::path::{Path, PathBuf};

use dsmstream::geotiff::reader::{GeoTiffReader, SampleType};
use tiff::decoder::Decoder;
use tiff::tags::Tag;

use crate::util::{bin, chain4_store, fixtures, ok, run, text};

/// (reader, every pixel, NaN = no-data).
fn read(path: &Path) -> (GeoTiffReader, Vec<f32>) {
    let mut r = GeoTiffReader::open(path).unwrap();
    let h = r.info().height;
    let data = r.read_rows(0, h).unwrap();
    (r, data)
}

/// The GDAL_METADATA XML of the first image.
fn gdal_metadata(path: &Path) -> String {
    let mut d = Decoder::new(File::open(path).unwrap()).unwrap();
    d.get_tag(Tag::Unknown(42112))
        .unwrap()
        .into_string()
        .unwrap()
}

fn same(a: f32, b: f32) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

/// Bounds off the data's lattice and past its west edge (chain4 covers
/// 500000..500281 x 4799872..4800000 at 0.5 m): snapped outward to
/// 499990.0 4799900.0 500121.0 4799950.0 = 262 x 100 px.
const BOUNDS: [&str; 4] = ["499990.2", "4799900.3", "500120.7", "4799949.9"];

#[test]
fn bounds_and_nodata_cut_the_mosaic_on_its_own_grid_with_band_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let store = chain4_store(dir.path());
    let (full, cut) = (dir.path().join("full.tif"), dir.path().join("cut.tif"));
    ok(run(&[&"fuse", &store, &"--out", &full]));
    let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"fuse", &store, &"--out", &cut];
    args.extend([&"--bounds" as &dyn AsRef<std::ffi::OsStr>]);
    for b in &BOUNDS {
        args.push(b);
    }
    args.extend([&"--nodata" as &dyn AsRef<std::ffi::OsStr>, &"-9999"]);
    ok(run(&args));

    let (rf, full_px) = read(&full);
    let (rc, cut_px) = read(&cut);
    let (fi, ci) = (rf.info(), rc.info());
    assert_eq!(
        ci.geotransform.0,
        [499_990.0, 0.5, 0.0, 4_799_950.0, 0.0, -0.5]
    );
    assert_eq!((ci.width, ci.height), (262, 100));
    assert_eq!(ci.nodata, Some(-9999.0));
    assert!(fi.nodata.is_some_and(f64::is_nan), "default no-data is nan");
    assert_eq!(ci.sample_type, SampleType::F32);
    // the cut is the mosaic's pixels (full origin 500000, 4800000), none resampled
    let (dc, dr) = (20i64, 100i64); // cut pixel (c, r) = full pixel (c - 20, r + 100)
    let mut compared = 0;
    for r in 0..ci.height as i64 {
        for c in 0..ci.width as i64 {
            let v = cut_px[(r * ci.width as i64 + c) as usize];
            if c < dc {
                assert!(v.is_nan(), "west of the data: no-data at ({c}, {r})");
                continue;
            }
            let w = full_px[((r + dr) * fi.width as i64 + c - dc) as usize];
            assert!(same(v, w), "({c}, {r}): {v} vs {w}");
            compared += u32::from(!v.is_nan());
        }
    }
    assert!(compared > 20_000, "{compared} valid pixels compared");
    // stored no-data is -9999, not nan
    let mut d = Decoder::new(File::open(&cut).unwrap()).unwrap();
    let nodata = d.get_tag(Tag::GdalNodata).unwrap().into_string().unwrap();
    assert_eq!(nodata, "-9999");
    let xml = gdal_metadata(&cut);
    assert!(
        xml.contains(r#"<Item name="DESCRIPTION" sample="0" role="description">height</Item>"#),
        "{xml}"
    );
    assert!(
        xml.contains(r#"<Item name="UNITTYPE" sample="0" role="unittype">m</Item>"#),
        "{xml}"
    );
    assert!(
        xml.contains(r#"<Item name="FUSE_METHOD">median</Item>"#),
        "{xml}"
    );
}

#[test]
fn count_is_a_uint16_band_equal_to_the_valid_per_dsm_files_on_one_grid() {
    let dir = tempfile::tempdir().unwrap();
    let store = chain4_store(dir.path());
    let (count, per) = (dir.path().join("count.tif"), dir.path().join("per"));
    let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"fuse", &store, &"--method", &"count"];
    args.extend([&"--out" as &dyn AsRef<std::ffi::OsStr>, &count, &"--bounds"]);
    for b in &BOUNDS {
        args.push(b);
    }
    ok(run(&args));
    let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"fuse", &store, &"--per-dsm", &per];
    args.push(&"--bounds");
    for b in &BOUNDS {
        args.push(b);
    }
    ok(run(&args));

    let (rc, counts) = read(&count);
    let info = rc.info();
    assert_eq!(info.sample_type, SampleType::U16);
    assert_eq!(info.nodata, None, "0 is a count, not no-data");
    assert_eq!((info.width, info.height), (262, 100));
    let xml = gdal_metadata(&count);
    assert!(xml.contains(r#"role="description">count</Item>"#), "{xml}");
    assert!(!xml.contains("UNITTYPE"), "a count has no unit: {xml}");

    let mut valid = vec![0f32; counts.len()];
    for id in ["tile_00", "tile_01", "tile_02", "tile_03"] {
        let path = per.join(format!("{id}.tif"));
        let (r, px) = read(&path);
        assert_eq!(r.info().geotransform, info.geotransform, "{id}: same grid");
        assert_eq!((r.info().width, r.info().height), (262, 100));
        assert!(gdal_metadata(&path).contains(&format!(r#"<Item name="DSM_ID">{id}</Item>"#)));
        for (v, p) in valid.iter_mut().zip(&px) {
            *v += f32::from(u8::from(!p.is_nan()));
        }
    }
    assert_eq!(counts, valid, "count = DSMs with a valid height");
    assert_eq!(counts.iter().copied().fold(0.0, f32::max), 3.0);
    assert!(counts.contains(&0.0), "west of the data nothing counts");
}

#[test]
fn bad_bounds_and_nodata_are_refused_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let store = chain4_store(dir.path());
    let out = dir.path().join("m.tif");
    let cases: [(&[&str], &str); 4] = [
        (&["--bounds", "10", "0", "5", "1"], "xmin < xmax"),
        (
            &["--bounds", "0", "0", "10", "10"],
            "--bounds 0 0 10 10 meet no DSM",
        ),
        (
            &["--method", "count", "--nodata", "0"],
            "--nodata does not apply to --method count",
        ),
        (&["--nodata", "inf"], "must be a finite number or nan"),
    ];
    for (extra, want) in cases {
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"fuse", &store, &"--out", &out];
        for e in extra {
            args.push(e);
        }
        let o = run(&args);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {err}");
        assert!(err.contains(want), "{extra:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{extra:?}: {err}");
        assert!(!out.exists(), "{extra:?} wrote a file");
    }
}

/// A VRT of chain4's tile_00 and tile_01 (0.5 m, tile_01 102 px east) by hand,
/// as gdalbuildvrt writes it.
fn chain_vrt(dir: &Path, extra_source: &str) -> PathBuf {
    let tiles = fixtures().join("synth/chain4");
    let source = |kind: &str, name: &str, x_off: u32, extra: &str| {
        format!(
            r#"    <{kind}>
      <SourceFilename relativeToVRT="0">{}</SourceFilename>
      <SourceBand>1</SourceBand>
      <SourceProperties RasterXSize="256" RasterYSize="256" DataType="Float32" BlockXSize="256" BlockYSize="256" />
      <SrcRect xOff="0" yOff="0" xSize="256" ySize="256" />
      <DstRect xOff="{x_off}" yOff="0" xSize="256" ySize="256" />{extra}
    </{kind}>
"#,
            tiles.join(name).display()
        )
    };
    let text = format!(
        r#"<VRTDataset rasterXSize="358" rasterYSize="256">
  <SRS dataAxisToSRSAxisMapping="1,2">EPSG:32617</SRS>
  <GeoTransform>  5.0000000000000000e+05,  5.0000000000000000e-01,  0.0000000000000000e+00,  4.8000000000000000e+06,  0.0000000000000000e+00, -5.0000000000000000e-01</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">
    <NoDataValue>nan</NoDataValue>
    <ColorInterp>Gray</ColorInterp>
{}{}  </VRTRasterBand>
</VRTDataset>
"#,
        source(
            "ComplexSource",
            "tile_00.tif",
            0,
            "\n      <NODATA>nan</NODATA>"
        ),
        source("ComplexSource", "tile_01.tif", 102, extra_source)
    );
    let path = dir.join("pair.vrt");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn a_vrt_mosaic_is_ingested_as_one_dsm_equal_to_its_sources() {
    let dir = tempfile::tempdir().unwrap();
    let vrt = chain_vrt(dir.path(), "");
    let store = dir.path().join("v.zarr");
    let out = ok(run(&[&"ingest", &vrt, &"--store", &store]));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("ingested pair: 358 x 256 px"), "{stdout}");
    let per = dir.path().join("per");
    ok(run(&[&"fuse", &store, &"--per-dsm", &per]));
    let (r, got) = read(&per.join("pair.tif"));
    assert_eq!(
        r.info().geotransform.0,
        [500_000.0, 0.5, 0.0, 4_800_000.0, 0.0, -0.5]
    );
    assert_eq!((r.info().width, r.info().height), (358, 256));
    // the mosaic of the sources: tile_01 over tile_00 where it is valid
    let mut want = vec![f32::NAN; 358 * 256];
    for (name, x_off) in [("tile_00.tif", 0usize), ("tile_01.tif", 102)] {
        let (_, px) = read(&fixtures().join("synth/chain4").join(name));
        for row in 0..256 {
            for col in 0..256 {
                let v = px[row * 256 + col];
                if !v.is_nan() {
                    want[row * 358 + x_off + col] = v;
                }
            }
        }
    }
    let differing = got
        .iter()
        .zip(&want)
        .filter(|(a, b)| !same(**a, **b))
        .count();
    assert_eq!(differing, 0, "ingested VRT differs from its sources");
    assert!(want.iter().filter(|v| v.is_nan()).count() < 358 * 256 / 10);
}

#[test]
fn a_vrt_that_scales_is_refused_with_one_line_naming_file_and_element() {
    let dir = tempfile::tempdir().unwrap();
    let vrt = chain_vrt(dir.path(), "\n      <ScaleRatio>0.3048</ScaleRatio>");
    let store = dir.path().join("v.zarr");
    let o = run(&[&"ingest", &vrt, &"--store", &store]);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("pair.vrt"), "{err}");
    assert!(err.contains("<ScaleRatio> inside <ComplexSource>"), "{err}");
    assert!(!store.join("pair").exists());
}

/// Names of leftover demo work folders in `tmp`.
fn demo_leftovers(tmp: &Path) -> Vec<String> {
    std::fs::read_dir(tmp)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("dsmstream-demo-"))
        .collect()
}

#[test]
fn a_failed_demo_removes_its_temporary_folder() {
    let tmp = tempfile::tempdir().unwrap();
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let o = bin()
        .current_dir(tmp.path())
        .env("TMPDIR", tmp.path())
        .args(["demo", "--data"])
        .arg(&empty)
        .output()
        .unwrap();
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(
        err.contains("no .tif, .tiff, .hgt or .hgt.zip files"),
        "{err}"
    );
    assert_eq!(demo_leftovers(tmp.path()), Vec::<String>::new());
}

/// The demo run from a folder that is not the repository (the fixtures are
/// found above the binary), ending with one conclusion line per part, its
/// temporary folder gone.
#[test]
fn demo_runs_from_any_directory_concludes_each_part_and_cleans_up() {
    let tmp = tempfile::tempdir().unwrap();
    let o = bin()
        .current_dir(tmp.path())
        .env("TMPDIR", tmp.path())
        .arg("demo")
        .output()
        .unwrap();
    let out = text(&o.stdout);
    assert!(o.status.success(), "{}\n{out}", text(&o.stderr));
    assert_eq!(out.matches("\nconclusion (").count(), 2, "{out}");
    for part in ["ingest: ", "align: ", "fuse: ", "eval: "] {
        assert_eq!(
            out.matches(&format!("\n  {part}")).count(),
            2,
            "{part}: {out}"
        );
    }
    assert!(out.contains("-> the collection agrees"), "{out}");
    assert!(out.contains("demo finished in "), "{out}");
    assert_eq!(demo_leftovers(tmp.path()), Vec::<String>::new());
}
