//! Round-trip tests of the COG writer, read back with the `tiff` crate decoder.

use super::*;
use std::io::{Read, Seek, SeekFrom};
use tiff::decoder::{Decoder, DecodingResult};
use tiff::tags::Tag;

fn options(tile_size: u32, nodata: f32) -> CogOptions {
    CogOptions {
        tile_size,
        geotransform: GeoTransform::north_up(500_000.0, 4_800_000.0, 0.5, 0.5),
        crs: Crs {
            epsg: Some(32617),
            ..Default::default()
        },
        nodata,
        overviews: true,
        ..Default::default()
    }
}

/// A test raster with NaN patches and a smooth pattern.
fn pattern(width: u64, height: u64) -> Vec<f32> {
    let mut v = Vec::with_capacity((width * height) as usize);
    for r in 0..height {
        for c in 0..width {
            let nan = (c / 40 + r / 30) % 5 == 0 && (c % 40) < 13;
            v.push(if nan {
                f32::NAN
            } else {
                (c as f32 * 0.11).sin() * 7.0 + r as f32 * 0.05 + 200.0
            });
        }
    }
    v
}

/// Every image (IFD) of the file: (width, height, values with no-data as read).
fn read_all_images(path: &Path) -> Vec<(u32, u32, Vec<f32>)> {
    let mut d = Decoder::new(File::open(path).unwrap()).unwrap();
    let mut out = Vec::new();
    loop {
        let (w, h) = d.dimensions().unwrap();
        let DecodingResult::F32(v) = d.read_image().unwrap() else {
            panic!("not f32")
        };
        out.push((w, h, v));
        if !d.more_images() {
            break;
        }
        d.next_image().unwrap();
    }
    out
}

fn same(a: f32, b: f32) -> bool {
    (a.is_nan() && b.is_nan()) || a == b
}

/// Write `data` tile by tile in a scrambled order.
fn write_scrambled(path: &Path, w: u64, h: u64, opts: CogOptions, data: &[f32], big: bool) {
    let t = opts.tile_size as u64;
    let mut writer = CogWriter::create(path, w, h, opts).unwrap();
    if big {
        writer.force_bigtiff();
    }
    let n = writer.tiles_x() * writer.tiles_y();
    // 7 is coprime with the tile counts used here: a permutation of all tiles.
    for k in 0..n {
        let i = (k * 7 + 3) % n;
        let (tx, ty) = (i % writer.tiles_x(), i / writer.tiles_x());
        let mut buf = vec![12345.0f32; (t * t) as usize]; // garbage in the padding
        for r in 0..t.min(h - ty * t) {
            for c in 0..t.min(w - tx * t) {
                buf[(r * t + c) as usize] = data[((ty * t + r) * w + tx * t + c) as usize];
            }
        }
        writer.write_tile(tx, ty, &buf).unwrap();
    }
    writer.finish().unwrap();
}

#[test]
fn round_trip_values_tags_and_overviews() {
    for big in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.tif");
        let (w, h) = (600u64, 520u64); // 3 x 3 tiles of 256, edge tiles padded
        let data = pattern(w, h);
        write_scrambled(&path, w, h, options(256, f32::NAN), &data, big);
        let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(names.len(), 1, "temporary files left behind");

        let images = read_all_images(&path);
        assert_eq!(images.len(), 3, "600x520 -> 300x260 -> 150x130");
        let (iw, ih, v) = &images[0];
        assert_eq!((*iw, *ih), (600, 520));
        assert!(v.iter().zip(&data).all(|(a, b)| same(*a, *b)));

        // Overview 1: no-data-aware 2x2 mean of the full resolution.
        let (ow, oh, ov) = &images[1];
        assert_eq!((*ow, *oh), (300, 260));
        for r in 0..260usize {
            for c in 0..300usize {
                let block = [(0, 0), (1, 0), (0, 1), (1, 1)]
                    .map(|(dc, dr)| data[(2 * r + dr) * 600 + 2 * c + dc]);
                let valid: Vec<f32> = block.into_iter().filter(|x| !x.is_nan()).collect();
                let got = ov[r * 300 + c];
                if valid.is_empty() {
                    assert!(got.is_nan());
                } else {
                    let mean = valid.iter().map(|&x| x as f64).sum::<f64>() / valid.len() as f64;
                    assert!(
                        (got as f64 - mean).abs() < 1e-4,
                        "({c},{r}) {got} vs {mean}"
                    );
                }
            }
        }
        assert_eq!((images[2].0, images[2].1), (150, 130));

        let mut d = Decoder::new(File::open(&path).unwrap()).unwrap();
        assert_eq!(d.get_tag_u32(Tag::Compression).unwrap(), 8);
        assert_eq!(d.get_tag_u32(Tag::Predictor).unwrap(), 3);
        assert_eq!(d.get_tag_u32(Tag::SampleFormat).unwrap(), 3);
        assert_eq!(d.get_tag_u32(Tag::TileWidth).unwrap(), 256);
        assert_eq!(d.get_tag_u32(Tag::Unknown(254)).unwrap(), 0);
        assert_eq!(
            d.get_tag(Tag::GdalNodata).unwrap().into_string().unwrap(),
            "nan"
        );
        let scale = d
            .get_tag(Tag::ModelPixelScaleTag)
            .unwrap()
            .into_f64_vec()
            .unwrap();
        assert_eq!(scale, vec![0.5, 0.5, 0.0]);
        let tie = d
            .get_tag(Tag::ModelTiepointTag)
            .unwrap()
            .into_f64_vec()
            .unwrap();
        assert_eq!(tie, vec![0.0, 0.0, 0.0, 500_000.0, 4_800_000.0, 0.0]);
        let keys = d.get_tag_u16_vec(Tag::GeoKeyDirectoryTag).unwrap();
        assert!(keys.chunks(4).any(|k| k == [3072, 0, 1, 32617]));
        d.next_image().unwrap();
        assert_eq!(d.get_tag_u32(Tag::Unknown(254)).unwrap(), 1);

        let mut magic = [0u8; 4];
        File::open(&path).unwrap().read_exact(&mut magic).unwrap();
        assert_eq!(magic[2], if big { 43 } else { 42 });
    }
}

#[test]
fn cog_layout_ifds_first_smallest_overview_data_first() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.tif");
    let (w, h) = (300u64, 200u64);
    write_scrambled(&path, w, h, options(64, f32::NAN), &pattern(w, h), false);
    let mut d = Decoder::new(File::open(&path).unwrap()).unwrap();
    let mut ifd_offsets = Vec::new();
    let mut first_data = Vec::new();
    loop {
        ifd_offsets.push(d.ifd_pointer().unwrap().0);
        let offsets = d.get_tag_u64_vec(Tag::TileOffsets).unwrap();
        assert!(
            offsets.windows(2).all(|p| p[0] < p[1]),
            "tiles in row-major order"
        );
        first_data.push(offsets[0]);
        let counts = d.get_tag_u64_vec(Tag::TileByteCounts).unwrap();
        let mut f = File::open(&path).unwrap();
        for (&o, &n) in offsets.iter().zip(&counts) {
            // GDAL block framing: u32 size before the tile, last 4 bytes after it.
            let mut framed = vec![0u8; n as usize + 8];
            f.seek(SeekFrom::Start(o - 4)).unwrap();
            f.read_exact(&mut framed).unwrap();
            assert_eq!(framed[..4], (n as u32).to_le_bytes());
            let k = framed.len();
            assert_eq!(framed[k - 4..], framed[k - 8..k - 4]);
        }
        if !d.more_images() {
            break;
        }
        d.next_image().unwrap();
    }
    assert_eq!(
        ifd_offsets.len(),
        4,
        "300x200 at 64 px: 150x100, 75x50, 38x25"
    );
    assert!(ifd_offsets[0] < 300, "main IFD near the start");
    assert!(ifd_offsets.windows(2).all(|p| p[0] < p[1]));
    assert!(first_data.iter().all(|&o| o > *ifd_offsets.last().unwrap()));
    assert!(
        first_data.windows(2).all(|p| p[0] > p[1]),
        "smallest overview first"
    );
    let mut f = File::open(&path).unwrap();
    f.seek(SeekFrom::Start(8)).unwrap();
    let mut ghost = [0u8; 30];
    f.read_exact(&mut ghost).unwrap();
    assert_eq!(&ghost, b"GDAL_STRUCTURAL_METADATA_SIZE=");
}

#[test]
fn numeric_nodata_replaces_nan_and_is_tagged() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("n.tif");
    let (w, h) = (40u64, 33u64);
    let data = pattern(w, h);
    let mut opts = options(32, -9999.0);
    opts.overviews = false;
    write_geotiff_f32(&path, w, h, opts, &data).unwrap();
    let images = read_all_images(&path);
    assert_eq!(images.len(), 1);
    for (a, b) in images[0].2.iter().zip(&data) {
        if b.is_nan() {
            assert_eq!(*a, -9999.0);
        } else {
            assert_eq!(a, b);
        }
    }
    let mut d = Decoder::new(File::open(&path).unwrap()).unwrap();
    assert_eq!(
        d.get_tag(Tag::GdalNodata).unwrap().into_string().unwrap(),
        "-9999"
    );
}

#[test]
fn raw_geokeys_are_written_back_with_pixel_is_area() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("k.tif");
    let mut opts = options(16, f32::NAN);
    opts.crs = Crs {
        epsg: None,
        geokeys: vec![1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 2, 3073, 34737, 6, 0],
        geo_ascii: Some("custom|".to_string()),
        ..Default::default()
    };
    write_geotiff_f32(&path, 16, 16, opts, &[1.0; 256]).unwrap();
    let mut d = Decoder::new(File::open(&path).unwrap()).unwrap();
    let keys = d.get_tag_u16_vec(Tag::GeoKeyDirectoryTag).unwrap();
    assert_eq!(
        keys,
        vec![1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3073, 34737, 6, 0]
    );
    let ascii = d
        .get_tag(Tag::GeoAsciiParamsTag)
        .unwrap()
        .into_string()
        .unwrap();
    assert_eq!(ascii, "custom|");
}

#[test]
fn bad_tiles_and_missing_tiles_leave_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.tif");
    let mut writer = CogWriter::create(&path, 40, 40, options(32, f32::NAN)).unwrap();
    let tile = vec![1.0f32; 32 * 32];
    writer.write_tile(0, 0, &tile).unwrap();
    let twice = writer.write_tile(0, 0, &tile).unwrap_err().to_string();
    assert!(
        twice.contains("m.tif") && twice.contains("twice"),
        "{twice}"
    );
    assert!(writer.write_tile(2, 0, &tile).is_err());
    assert!(writer.write_tile(1, 0, &tile[..10]).is_err());
    let err = writer.finish().unwrap_err().to_string();
    assert!(err.contains("3 of 4 tiles"), "{err}");
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);

    // Dropping an unfinished writer removes its spill file too.
    let mut writer = CogWriter::create(&path, 40, 40, options(32, f32::NAN)).unwrap();
    writer.write_tile(1, 1, &tile).unwrap();
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    drop(writer);
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);

    let bad = CogWriter::create(&path, 40, 40, options(20, f32::NAN));
    assert!(matches!(bad, Err(GeoTiffWriteError::InvalidOptions { .. })));
}

#[test]
fn existing_file_is_replaced_only_on_success() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("r.tif");
    std::fs::write(&path, b"old").unwrap();
    let writer = CogWriter::create(&path, 20, 20, options(16, f32::NAN)).unwrap();
    assert!(writer.finish().is_err());
    assert_eq!(std::fs::read(&path).unwrap(), b"old");
    // the replaced file's PAM sidecar would override the new georeferencing
    let pam = dir.path().join("r.tif.aux.xml");
    std::fs::write(
        &pam,
        "<PAMDataset><GeoTransform>0,1,0,0,0,-1</GeoTransform></PAMDataset>",
    )
    .unwrap();
    write_geotiff_f32(&path, 20, 20, options(16, f32::NAN), &[2.5; 400]).unwrap();
    let images = read_all_images(&path);
    assert_eq!(images[0].2, vec![2.5; 400]);
    assert_eq!((images[1].0, images[1].1), (10, 10));
    assert!(!pam.exists());
    let info = crate::geotiff::reader::GeoTiffReader::open(&path)
        .unwrap()
        .info()
        .clone();
    assert_eq!(info.geotransform, options(16, f32::NAN).geotransform);
}

#[test]
fn uint16_band_round_trips_with_overviews_and_no_nodata_tag() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.tif");
    let (w, h) = (70u64, 45u64);
    let data: Vec<f32> = (0..w * h)
        .map(|i| {
            if i % 11 == 0 {
                f32::NAN
            } else {
                (i % 4) as f32
            }
        })
        .collect();
    let mut opts = options(32, f32::NAN);
    opts.sample = CogSample::UInt16;
    write_geotiff_f32(&path, w, h, opts, &data).unwrap();
    let mut d = Decoder::new(File::open(&path).unwrap()).unwrap();
    assert!(
        d.get_tag(Tag::GdalNodata).is_err(),
        "no GDAL_NODATA on UInt16"
    );
    let mut levels = 0;
    loop {
        let (iw, ih) = d.dimensions().unwrap();
        let DecodingResult::U16(v) = d.read_image().unwrap() else {
            panic!("not u16")
        };
        if levels == 0 {
            assert_eq!((iw as u64, ih as u64), (w, h));
            for (a, b) in v.iter().zip(&data) {
                assert_eq!(*a as f32, if b.is_nan() { 0.0 } else { *b });
            }
        }
        assert!(v.iter().all(|&c| c <= 3), "overview means stay in range");
        levels += 1;
        if !d.more_images() {
            break;
        }
        d.next_image().unwrap();
    }
    assert_eq!(levels, 3, "70 x 45 at 32 px tiles: two overviews");
}

#[test]
fn gdal_metadata_tag_carries_band_description_and_unit() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.tif");
    let mut opts = options(16, f32::NAN);
    opts.metadata = GdalMetadata {
        band_description: Some("height".into()),
        band_unit: Some("m".into()),
        items: vec![("FUSE_METHOD".into(), "median".into())],
    };
    write_geotiff_f32(&path, 40, 40, opts, &pattern(40, 40)).unwrap();
    let mut d = Decoder::new(File::open(&path).unwrap()).unwrap();
    let xml = d
        .get_tag(Tag::Unknown(42112))
        .unwrap()
        .into_string()
        .unwrap();
    assert!(xml.contains("role=\"description\">height</Item>"), "{xml}");
    assert!(xml.contains("role=\"unittype\">m</Item>"), "{xml}");
    d.next_image().unwrap();
    assert!(
        d.get_tag(Tag::Unknown(42112)).is_err(),
        "overviews carry none"
    );
}
