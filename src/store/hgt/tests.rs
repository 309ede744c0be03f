use super::*;

/// A 1201 x 1201 tile whose sample (row, col) is `row - col`, with voids
/// where both are multiples of 100.
fn tile_bytes() -> Vec<u8> {
    let mut out = Vec::with_capacity(1201 * 1201 * 2);
    for row in 0..1201i32 {
        for col in 0..1201i32 {
            let h = if row % 100 == 0 && col % 100 == 0 {
                VOID
            } else {
                (row - col) as i16
            };
            out.extend(h.to_be_bytes());
        }
    }
    out
}

fn read_all(source: &mut HgtSource) -> Vec<f32> {
    let (mut all, mut band) = (Vec::new(), Vec::new());
    let mut row0 = 0;
    while row0 < source.raster().height {
        let rows = 37.min(source.raster().height - row0);
        source.read_rows_into(row0, rows, &mut band).unwrap();
        all.extend_from_slice(&band);
        row0 += rows;
    }
    all
}

#[test]
fn tiles_are_named_as_gdal_names_them() {
    let cases = [
        ("N39E040.hgt", Some((39, 40))),
        ("s12w077.SRTMGL1.hgt", Some((-12, -77))),
        ("N00W180.hgt", Some((0, -180))),
        ("S90E000", Some((-90, 0))),
        ("N39E040x.hgt", None),
        ("N39E04.hgt", None),
        ("foo.hgt", None),
        ("N90E000.hgt", None),
        ("N39E181.hgt", None),
        ("X39E040.hgt", None),
    ];
    for (name, want) in cases {
        let got = Tile::of_name(name).map(|t| (t.lat, t.lon));
        assert_eq!(got, want, "{name}");
        if let Some(t) = Tile::of_name(name) {
            assert!(name.to_ascii_uppercase().starts_with(&t.name()), "{name}");
        }
    }
    assert_eq!(id_of_zip("N39E040.SRTMGL1.hgt.zip"), "N39E040.SRTMGL1");
    assert_eq!(id_of_zip("NASADEM_HGT_n39e040.ZIP"), "NASADEM_HGT_n39e040");
}

/// The transforms GDAL 3.10.3's SRTMHGT driver gives files of each size
/// (rasterio's `transform`, printed to 17 digits).
#[test]
fn transforms_are_gdals() {
    let cases = [
        (
            "N39E040",
            1201,
            1201,
            39.999583333333334,
            40.000416666666666,
        ),
        (
            "S12W077",
            3601,
            3601,
            -77.00013888888888,
            -10.99986111111111,
        ),
        ("N61E010", 1801, 3601, 9.999722222222223, 62.00013888888889),
        ("N39E041", 7201, 7201, 40.99993055555556, 40.00006944444444),
    ];
    for (name, cols, rows, west, north) in cases {
        let gt = Tile::of_name(name).unwrap().geotransform(cols, rows);
        let g = gt.0;
        assert!((g[0] - west).abs() < 1e-12, "{name} west {}", g[0]);
        assert!((g[3] - north).abs() < 1e-12, "{name} north {}", g[3]);
        assert!((g[1] - 1.0 / (cols - 1) as f64).abs() < 1e-15, "{name}");
        assert!((g[5] + 1.0 / (rows - 1) as f64).abs() < 1e-15, "{name}");
        // the south-west sample sits on the tile's corner
        let (x, y) = gt.pixel_to_world(0.5, rows as f64 - 0.5);
        let t = Tile::of_name(name).unwrap();
        assert!((x - f64::from(t.lon)).abs() < 1e-12 && (y - f64::from(t.lat)).abs() < 1e-12);
    }
}

#[test]
fn plain_and_zipped_tiles_read_the_same_heights() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = tile_bytes();
    let plain = dir.path().join("N39E040.hgt");
    std::fs::write(&plain, &bytes).unwrap();
    let zipped = dir.path().join("N39E040.SRTMGL3.hgt.zip");
    std::fs::write(
        &zipped,
        zip::tests::archive(&[("N39E040.hgt", &bytes)], true),
    )
    .unwrap();
    let nasadem = dir.path().join("NASADEM_HGT_n39e040.zip");
    let archive = zip::tests::archive(&[("n39e040.hgt", &bytes), ("readme.txt", b"x")], false);
    std::fs::write(&nasadem, archive).unwrap();

    let mut first = HgtSource::open(&plain).unwrap();
    let r = first.raster().clone();
    assert_eq!((r.width, r.height, r.nodata), (1201, 1201, Some(-32768.0)));
    assert_eq!(r.crs.epsg, Some(4326));
    assert!(r.crs.is_geographic);
    let want = read_all(&mut first);
    assert_eq!(want[1], -1.0);
    assert_eq!(want[1201 * 3 + 2], 1.0);
    assert!(want[0].is_nan() && want[100 * 1201 + 200].is_nan());
    assert_eq!(want.iter().filter(|h| h.is_nan()).count(), 13 * 13);
    for path in [&zipped, &nasadem] {
        let mut source = HgtSource::open(path).unwrap();
        assert_eq!(
            source.raster().geotransform,
            r.geotransform,
            "{}",
            path.display()
        );
        let got = read_all(&mut source);
        let same = got
            .iter()
            .zip(&want)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same && got.len() == want.len(), "{}", path.display());
    }
}

#[test]
fn bad_tiles_are_refused_naming_the_file_and_the_problem() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = tile_bytes();
    let write = |name: &str, data: &[u8]| {
        let path = dir.path().join(name);
        std::fs::write(&path, data).unwrap();
        path
    };
    let cases = [
        (
            write("N39E040.hgt", &bytes[..bytes.len() - 1000]),
            "not an SRTM HGT tile",
        ),
        (write("dem.hgt", &bytes), "name must start with its tile"),
        (
            write(
                "N38E040.hgt.zip",
                &zip::tests::archive(&[("N39E040.hgt", &bytes)], true),
            ),
            "name says N38E040 but it holds N39E040.hgt",
        ),
        (
            write(
                "dsm.zip",
                &zip::tests::archive(&[("dsm.tif", b"II*\0")], true),
            ),
            "holds none (dsm.tif)",
        ),
        (
            write(
                "two.zip",
                &zip::tests::archive(&[("N39E040.hgt", &bytes), ("N39E041.hgt", &bytes)], false),
            ),
            "holds several",
        ),
        (
            write("N39E040.zip", &bytes[..5000]),
            "not a zip archive, or truncated",
        ),
        (
            // a corrupt name with a newline: still one line (fuzz case)
            write(
                "N.zip",
                &zip::tests::archive(&[("N39E040.h\nt", b"x")], false),
            ),
            "holds none (N39E040.h\u{fffd}t)",
        ),
    ];
    for (path, want) in cases {
        let err = HgtSource::open(&path).err().expect("refused");
        assert!(err.bad_input, "{}", err.message);
        assert!(
            err.message.starts_with(&path.display().to_string()),
            "{}",
            err.message
        );
        assert!(err.message.contains(want), "{}", err.message);
        assert!(!err.message.contains('\n'), "{}", err.message);
    }
}

/// The streamed zip answers any sequence of requests as the plain file does:
/// rising overlapping bands (as the warp asks), jumps ahead, a step back
/// (the stream starts again), one row, the last rows.
#[test]
fn zipped_rows_in_any_order_are_the_plain_rows() {
    let dir = tempfile::tempdir().unwrap();
    let bytes = tile_bytes();
    let plain = dir.path().join("N39E040.hgt");
    std::fs::write(&plain, &bytes).unwrap();
    let zipped = dir.path().join("N39E040.hgt.zip");
    std::fs::write(
        &zipped,
        zip::tests::archive(&[("N39E040.hgt", &bytes)], true),
    )
    .unwrap();
    let mut a = HgtSource::open(&plain).unwrap();
    let mut b = HgtSource::open(&zipped).unwrap();
    let requests = [
        (0, 40),
        (30, 40),
        (60, 5),
        (500, 100),
        (550, 1),
        (100, 10),
        (1190, 11),
        (0, 1201),
        (1200, 1),
    ];
    for (row0, rows) in requests {
        let (want, got) = (
            a.read_rows(row0, rows).unwrap(),
            b.read_rows(row0, rows).unwrap(),
        );
        let same = want
            .iter()
            .zip(&got)
            .all(|(x, y)| x.to_bits() == y.to_bits());
        assert!(same && want.len() == got.len(), "rows {row0}..+{rows}");
    }
    assert!(b.read_rows(1200, 2).is_err(), "past the last row");
}

/// `gdalbuildvrt` over two neighbouring tiles (one plain, one zipped): one
/// DSM of 2401 x 1201 samples whose shared column is the later tile's where
/// it has data, as GDAL composes it.
#[test]
fn a_vrt_mosaic_of_tiles_is_one_source() {
    use crate::store::vrt::VrtSource;
    let dir = tempfile::tempdir().unwrap();
    let bytes = tile_bytes();
    std::fs::write(dir.path().join("N39E040.hgt"), &bytes).unwrap();
    let zipped = zip::tests::archive(&[("N39E041.hgt", &bytes)], true);
    std::fs::write(dir.path().join("N39E041.SRTMGL3.hgt.zip"), zipped).unwrap();
    let source = |file: &str, x_off: u64| {
        format!(
            r#"<ComplexSource><SourceFilename relativeToVRT="1">{file}</SourceFilename><SourceBand>1</SourceBand>
      <SourceProperties RasterXSize="1201" RasterYSize="1201" DataType="Int16" BlockXSize="1201" BlockYSize="1" />
      <SrcRect xOff="0" yOff="0" xSize="1201" ySize="1201" /><DstRect xOff="{x_off}" yOff="0" xSize="1201" ySize="1201" />
      <NODATA>-32768</NODATA></ComplexSource>"#
        )
    };
    let text = format!(
        r#"<VRTDataset rasterXSize="2401" rasterYSize="1201">
  <SRS dataAxisToSRSAxisMapping="2,1">GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],AXIS["Latitude",NORTH],AXIS["Longitude",EAST],AUTHORITY["EPSG","4326"]]</SRS>
  <GeoTransform>  3.9999583333333334e+01,  8.3333333333333339e-04,  0.0000000000000000e+00,  4.0000416666666666e+01,  0.0000000000000000e+00, -8.3333333333333339e-04</GeoTransform>
  <VRTRasterBand dataType="Int16" band="1">
    <NoDataValue>-32768</NoDataValue>
    <ColorInterp>Gray</ColorInterp>
    {}
    {}
  </VRTRasterBand>
</VRTDataset>"#,
        source("N39E040.hgt", 0),
        source("N39E041.SRTMGL3.hgt.zip", 1200)
    );
    let path = dir.path().join("srtm.vrt");
    std::fs::write(&path, text).unwrap();
    let mut vrt = VrtSource::open(&path).unwrap();
    assert_eq!((vrt.raster().width, vrt.raster().height), (2401, 1201));
    assert_eq!(vrt.raster().crs.epsg, Some(4326));
    let rows = vrt.read_rows(0, 1201).unwrap();
    let tile = |r: usize, c: usize| {
        let h = i16::from_be_bytes([bytes[(r * 1201 + c) * 2], bytes[(r * 1201 + c) * 2 + 1]]);
        (h != VOID).then_some(f32::from(h))
    };
    for r in 0..1201 {
        for c in 0..2401 {
            let later = (c >= 1200).then(|| tile(r, c - 1200)).flatten();
            let earlier = (c <= 1200).then(|| tile(r, c)).flatten();
            let want = later.or(earlier).unwrap_or(f32::NAN);
            let got = rows[r * 2401 + c];
            assert!(
                got.to_bits() == want.to_bits(),
                "({r}, {c}): {got} / {want}"
            );
        }
    }
}
