//! Reader tests against GDAL's answers in fixtures/geotiff/expected.json
//! (written by tools/scripts/make_test_tiffs.py): every fixture's metadata and pixels,
//! every refused file's error, truncated copies, and row-range reads.

use std::path::{Path, PathBuf};

use serde_json::Value;

use super::*;

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/geotiff")
}

fn expected() -> Value {
    let text = std::fs::read_to_string(fixtures().join("expected.json")).expect("expected.json");
    serde_json::from_str(&text).expect("expected.json parses")
}

fn records(section: &str) -> Vec<Value> {
    expected()[section].as_array().expect("section").clone()
}

fn sample_type_of(dtype: &str) -> SampleType {
    match dtype {
        "uint8" => SampleType::U8,
        "int8" => SampleType::I8,
        "uint16" => SampleType::U16,
        "int16" => SampleType::I16,
        "uint32" => SampleType::U32,
        "int32" => SampleType::I32,
        "float16" => SampleType::F16,
        "float32" => SampleType::F32,
        "float64" => SampleType::F64,
        other => panic!("dtype {other}"),
    }
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(1.0)
}

/// Metadata of `info` equals GDAL's record; returns a description of the first mismatch.
fn check_info(info: &GeoTiffInfo, rec: &Value) {
    let file = rec["file"].as_str().unwrap();
    assert_eq!(info.width, rec["width"].as_u64().unwrap(), "{file} width");
    assert_eq!(
        info.height,
        rec["height"].as_u64().unwrap(),
        "{file} height"
    );
    assert_eq!(
        u64::from(info.band_count),
        rec["band_count"].as_u64().unwrap(),
        "{file} bands"
    );
    assert_eq!(
        info.sample_type,
        sample_type_of(rec["dtype"].as_str().unwrap()),
        "{file} type"
    );
    assert_eq!(
        info.compression,
        rec["compression"].as_str().unwrap(),
        "{file} compression"
    );
    assert_eq!(info.tiled, rec["tiled"].as_bool().unwrap(), "{file} tiled");
    let block = [info.block_width as u64, info.block_height as u64];
    assert_eq!(
        block[0],
        rec["block"][0].as_u64().unwrap(),
        "{file} block width"
    );
    assert_eq!(
        block[1],
        rec["block"][1].as_u64().unwrap(),
        "{file} block height"
    );
    for (i, want) in rec["geotransform"].as_array().unwrap().iter().enumerate() {
        let (got, want) = (info.geotransform.0[i], want.as_f64().unwrap());
        assert!(
            close(got, want),
            "{file} geotransform[{i}]: {got} vs GDAL {want}"
        );
    }
    let epsg = rec["epsg"].as_u64().map(|c| c as u32);
    assert_eq!(info.crs.epsg, epsg, "{file} epsg");
    assert_eq!(
        info.crs.is_geographic,
        rec["is_geographic"].as_bool().unwrap(),
        "{file} geographic"
    );
    assert_ne!(info.crs.label(), "unknown", "{file} CRS label");
    match &rec["nodata"] {
        Value::Null => assert_eq!(info.nodata, None, "{file} nodata"),
        Value::String(s) if s == "nan" => {
            assert!(info.nodata.is_some_and(f64::is_nan), "{file} nodata")
        }
        v => assert_eq!(info.nodata, v.as_f64(), "{file} nodata"),
    }
    if let Some(p) = rec.get("predictor").and_then(Value::as_u64) {
        assert_eq!(u64::from(info.predictor), p, "{file} predictor");
    }
    let point = rec
        .get("pixel_is_point")
        .and_then(Value::as_bool)
        .unwrap_or(false);
    assert_eq!(info.pixel_is_point, point, "{file} pixel-is-point");
    let number = |key: &str, default: f64| rec.get(key).and_then(Value::as_f64).unwrap_or(default);
    assert_eq!(info.band.scale, number("scale", 1.0), "{file} scale");
    assert_eq!(info.band.offset, number("offset", 0.0), "{file} offset");
    let masked = rec.get("internal_mask").and_then(Value::as_bool);
    assert_eq!(info.internal_mask, masked.unwrap_or(false), "{file} mask");
    let unit = rec.get("height_unit").and_then(Value::as_str);
    assert_eq!(info.band.unit.as_deref(), unit, "{file} unit");
    let side_files: Vec<String> = (info.georeferenced_by.iter())
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    let want: Vec<String> = match rec.get("side_files") {
        Some(v) => serde_json::from_value(v.clone()).unwrap(),
        None => Vec::new(),
    };
    assert_eq!(side_files, want, "{file} side files");
}

fn read_all(path: &Path) -> (GeoTiffInfo, Vec<f32>) {
    let mut r = GeoTiffReader::open(path).unwrap_or_else(|e| panic!("{e}"));
    let h = r.info().height;
    let px = r.read_rows(0, h).unwrap_or_else(|e| panic!("{e}"));
    (r.info().clone(), px)
}

fn same_pixels(file: &str, got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len(), "{file} pixel count");
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!(
            g.to_bits() == w.to_bits() || (g.is_nan() && w.is_nan()),
            "{file} pixel {i}: {g} vs GDAL {w}"
        );
    }
}

fn load_bin(name: &str) -> Vec<f32> {
    let bytes = std::fs::read(fixtures().join(name)).expect("pixels bin");
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

#[test]
fn every_fixture_matches_gdal() {
    let good = records("good");
    assert!(good.len() >= 80, "fixture list too short: {}", good.len());
    for rec in &good {
        let file = rec["file"].as_str().unwrap();
        let (info, px) = read_all(&fixtures().join(file));
        check_info(&info, rec);
        same_pixels(file, &px, &load_bin(rec["pixels"].as_str().unwrap()));
    }
}

#[test]
fn special_fixtures_report_their_features() {
    let open = |f: &str| {
        GeoTiffReader::open(&fixtures().join(f))
            .unwrap()
            .info()
            .clone()
    };
    assert!(open("f32_tile_deflate_bigtiff.tif").bigtiff);
    assert!(!open("f32_tile_deflate.tif").bigtiff);
    assert_eq!(open("f32_tile_deflate32946.tif").compression, "deflate");
    let point = open("f32_4326_point.tif");
    assert!(point.pixel_is_point && point.crs.is_geographic);
    assert_eq!(point.crs.label(), "EPSG:4326");
    let custom = open("f32_custom_crs.tif");
    assert_eq!(custom.crs.epsg, None);
    assert!(
        custom.crs.label().contains("Transverse Mercator"),
        "{}",
        custom.crs.label()
    );
    assert!(custom.crs.geo_ascii.is_some() && !custom.crs.geo_doubles.is_empty());
    assert_eq!(open("f32_2band_band.tif").band_count, 2);
    assert_eq!(open("f32_onestrip_deflate.tif").block_height, 45);
}

#[test]
fn every_bad_fixture_is_refused_with_its_reason() {
    for rec in records("bad") {
        let file = rec["file"].as_str().unwrap();
        let path = fixtures().join(file);
        let err = match GeoTiffReader::open(&path) {
            Err(e) => e,
            Ok(mut r) => {
                let h = r.info().height;
                r.read_rows(0, h).expect_err(file)
            }
        };
        let kind = rec["error"].as_str().unwrap();
        let ok = match kind {
            "not_tiff" => matches!(err, GeoTiffError::NotTiff { .. }),
            "rotated" => matches!(err, GeoTiffError::NotNorthUp { .. }),
            "no_georef" => matches!(err, GeoTiffError::NoGeoreferencing { .. }),
            "compression" => matches!(err, GeoTiffError::UnsupportedCompression { .. }),
            "sample_format" => matches!(err, GeoTiffError::UnsupportedSampleFormat { .. }),
            "zero_size" => matches!(err, GeoTiffError::ZeroSize { .. }),
            "truncated" => matches!(err, GeoTiffError::Truncated { .. }),
            "side_file" => matches!(err, GeoTiffError::Sidecar { .. }),
            other => panic!("unknown error kind {other}"),
        };
        let msg = err.to_string();
        assert!(ok, "{file}: expected {kind}, got {msg}");
        assert!(err.is_bad_input(), "{msg}");
        // the file at fault: the GeoTIFF, or the side file that holds the problem
        let names = rec.get("names").and_then(Value::as_str).unwrap_or(file);
        assert!(msg.contains(names) && !msg.contains('\n'), "{msg}");
    }
    let lerc = GeoTiffReader::open(&fixtures().join("bad_lerc_wrapping.tif"))
        .err()
        .unwrap()
        .to_string();
    assert!(lerc.contains("LERC with additional compression"), "{lerc}");
    let jpeg = GeoTiffReader::open(&fixtures().join("bad_jpeg.tif"))
        .err()
        .unwrap()
        .to_string();
    assert!(jpeg.contains("JPEG"), "{jpeg}");
    let missing = GeoTiffReader::open(&fixtures().join("no_such_file.tif"))
        .err()
        .unwrap();
    assert!(missing.is_bad_input() && missing.to_string().contains("no_such_file.tif"));
}

#[test]
fn truncated_copies_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    for file in [
        "f32_tile_deflate.tif",
        "f32_strip_lzw.tif",
        "i16_strip_lzw_bigtiff.tif",
        "f64_tile_zstd_p3.tif",
        "u8_tile_packbits.tif",
        "f32_onestrip_deflate.tif",
    ] {
        let bytes = std::fs::read(fixtures().join(file)).unwrap();
        let n = bytes.len();
        for cut in [
            0,
            3,
            8,
            16,
            100,
            n / 4,
            n / 3,
            n / 2,
            2 * n / 3,
            n - 100,
            n - 1,
        ] {
            let path = dir.path().join(format!("cut_{cut}_{file}"));
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let result = GeoTiffReader::open(&path).and_then(|mut r| {
                let h = r.info().height;
                r.read_rows(0, h)
            });
            let err = result.expect_err(&format!("{file} cut at {cut} of {n} bytes was accepted"));
            assert!(
                err.is_bad_input() && err.to_string().contains("cut_"),
                "{err}"
            );
        }
    }
}

#[test]
fn row_ranges_equal_the_full_read() {
    for file in [
        "f32_strip_deflate.tif",
        "i16_tile_lzw_p2.tif",
        "f32_onestrip_deflate.tif",
        "f32_tile32_deflate.tif",
        "f32_2band_pixel.tif",
    ] {
        let path = fixtures().join(file);
        let (info, full) = read_all(&path);
        let (w, h) = (info.width as usize, info.height);
        let mut reader = GeoTiffReader::open(&path).unwrap();
        let check = |reader: &mut GeoTiffReader, row0: u64, rows: u64| {
            let got = reader.read_rows(row0, rows).unwrap();
            let want = &full[row0 as usize * w..(row0 + rows) as usize * w];
            same_pixels(&format!("{file} rows {row0}+{rows}"), &got, want);
        };
        // Top to bottom in every step size (exercises the kept block row).
        for step in 1..=h {
            let mut row = 0;
            while row < h {
                let rows = step.min(h - row);
                check(&mut reader, row, rows);
                row += rows;
            }
        }
        // Pseudo-random ranges, in no particular order.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..200 {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let row0 = (state >> 33) % h;
            let rows = (state >> 13) % (h - row0 + 1);
            check(&mut reader, row0, rows);
        }
        assert!(reader.read_rows(0, 0).unwrap().is_empty());
        let err = reader.read_rows(h - 1, 2).unwrap_err();
        assert!(matches!(err, GeoTiffError::RowsOutOfRange { .. }) && !err.is_bad_input());
    }
}

#[test]
fn real_rasters_match_gdal() {
    let real = records("real");
    assert!(real.len() >= 10);
    for rec in &real {
        let file = rec["file"].as_str().unwrap();
        let (info, px) = read_all(&fixtures().join(file));
        check_info(&info, rec);
        let w = info.width as usize;
        let valid: Vec<f64> = px
            .iter()
            .filter(|v| !v.is_nan())
            .map(|&v| f64::from(v))
            .collect();
        assert_eq!(
            valid.len() as u64,
            rec["valid_count"].as_u64().unwrap(),
            "{file} valid count"
        );
        let (sum, want) = (
            valid.iter().sum::<f64>(),
            rec["valid_sum"].as_f64().unwrap(),
        );
        assert!(
            (sum - want).abs() <= 1e-9 * want.abs().max(1.0),
            "{file} sum {sum} vs GDAL {want}"
        );
        for s in rec["samples"].as_array().unwrap() {
            let (r, c) = (
                s[0].as_u64().unwrap() as usize,
                s[1].as_u64().unwrap() as usize,
            );
            let got = px[r * w + c];
            match s[2].as_f64() {
                None => assert!(got.is_nan(), "{file} ({r},{c}) {got} vs GDAL no-data"),
                Some(v) => assert_eq!(got, v as f32, "{file} ({r},{c})"),
            }
        }
    }
    let codem = GeoTiffReader::open(&fixtures().join("../real/codem/dem.tif")).unwrap();
    assert_eq!(codem.info().crs.label(), "EPSG:32616");
    assert_eq!(codem.info().sample_type, SampleType::F64);
    let srtm =
        GeoTiffReader::open(&fixtures().join("../real/demcompare_srtm/srtm_ref.tif")).unwrap();
    assert!(srtm.info().crs.is_geographic);
}

/// Throughput of a top-to-bottom streaming read of a large file (not run by
/// default). Make the file and time GDAL with tools/scripts/bench_geotiff_read.py, then:
/// `DSMSTREAM_BENCH_TIFF=/tmp/big.tif cargo test --release --lib bench_streaming_read -- --ignored --nocapture`
#[test]
#[ignore]
fn bench_streaming_read() {
    let path = PathBuf::from(std::env::var("DSMSTREAM_BENCH_TIFF").expect("DSMSTREAM_BENCH_TIFF"));
    for band_rows in [256u64, 512, 1000] {
        let t0 = std::time::Instant::now();
        let mut r = GeoTiffReader::open(&path).unwrap();
        let (w, h) = (r.info().width, r.info().height);
        let (mut valid, mut row, mut band) = (0u64, 0, Vec::new());
        while row < h {
            let rows = band_rows.min(h - row);
            r.read_rows_into(row, rows, &mut band).unwrap();
            valid += band.iter().filter(|v| !v.is_nan()).count() as u64;
            row += rows;
        }
        let dt = t0.elapsed().as_secs_f64();
        let threads = rayon::current_num_threads();
        println!(
            "dsmstream reader, {threads} threads, {band_rows}-row bands: {dt:.2} s, {:.0} Mpx/s ({valid} valid)",
            (w * h) as f64 / 1e6 / dt
        );
    }
}

#[test]
fn reader_is_send_and_reuses_buffers() {
    fn assert_send<T: Send>() {}
    assert_send::<GeoTiffReader>();
    let path = fixtures().join("f32_tile_deflate.tif");
    let (info, full) = read_all(&path);
    let w = info.width as usize;
    let mut r = GeoTiffReader::open(&path).unwrap();
    let mut buf = vec![1.0f32; 10];
    r.read_rows_into(5, 20, &mut buf).unwrap();
    same_pixels("read_rows_into", &buf, &full[5 * w..25 * w]);
    r.read_rows_into(40, 5, &mut buf).unwrap();
    same_pixels("read_rows_into", &buf, &full[40 * w..45 * w]);
}

#[test]
fn corrupted_bytes_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    for file in [
        "f32_tile_deflate_p3.tif",
        "i16_strip_lzw_bigtiff.tif",
        "u16_tile_zstd.tif",
        "u8_strip_packbits.tif",
    ] {
        let bytes = std::fs::read(fixtures().join(file)).unwrap();
        for trial in 0..80 {
            let mut b = bytes.clone();
            // Even trials hit the header and IFD, odd ones anywhere.
            let span = if trial % 2 == 0 {
                600.min(b.len())
            } else {
                b.len()
            };
            for _ in 0..1 + trial % 4 {
                let at = (next() % span as u64) as usize;
                b[at] = next() as u8;
            }
            let path = dir.path().join(format!("{trial}_{file}"));
            std::fs::write(&path, &b).unwrap();
            if let Ok(mut r) = GeoTiffReader::open(&path) {
                let h = r.info().height;
                if let Err(e) = r.read_rows(0, h) {
                    assert!(e.is_bad_input() && !e.to_string().contains('\n'), "{e}");
                }
            }
        }
    }
}
