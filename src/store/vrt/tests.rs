//! VRT sources against hand-written VRTs over small GeoTIFFs: composition in
//! file order, clipping, no-data, and one-line refusals naming the element.

use super::*;
use crate::geotiff::writer::{write_geotiff_f32, CogOptions};

const GSD: f64 = 0.5;

/// A w x h GeoTIFF at (x0, y_top) whose pixel (c, r) is base + c + 100 r,
/// NaN at (1, 1).
fn tif(dir: &Path, name: &str, origin: (f64, f64), size: (u64, u64), base: f32) -> PathBuf {
    let (w, h) = size;
    let data: Vec<f32> = (0..w * h)
        .map(|i| {
            let (c, r) = (i % w, i / w);
            if c == 1 && r == 1 {
                f32::NAN
            } else {
                base + c as f32 + 100.0 * r as f32
            }
        })
        .collect();
    let path = dir.join(name);
    let options = CogOptions {
        tile_size: 16,
        geotransform: GeoTransform::north_up(origin.0, origin.1, GSD, GSD),
        crs: Crs {
            epsg: Some(32617),
            ..Default::default()
        },
        ..Default::default()
    };
    write_geotiff_f32(&path, w, h, options, &data).unwrap();
    path
}

fn source(
    kind: &str,
    file: &str,
    src: (i64, i64, u64, u64),
    dst: (i64, i64),
    extra: &str,
) -> String {
    format!(
        r#"<{kind}><SourceFilename relativeToVRT="1">{file}</SourceFilename><SourceBand>1</SourceBand>
        <SrcRect xOff="{}" yOff="{}" xSize="{}" ySize="{}"/><DstRect xOff="{}" yOff="{}" xSize="{}" ySize="{}"/>{extra}</{kind}>"#,
        src.0, src.1, src.2, src.3, dst.0, dst.1, src.2, src.3
    )
}

fn vrt(dir: &Path, size: (u64, u64), sources: &[String], band_extra: &str) -> PathBuf {
    let path = dir.join("m.vrt");
    let text = format!(
        r#"<VRTDataset rasterXSize="{}" rasterYSize="{}">
  <SRS>EPSG:32617</SRS>
  <GeoTransform> 1.0e3, 0.5, 0.0, 2.0e3, 0.0, -0.5</GeoTransform>
  <VRTRasterBand dataType="Float32" band="1">{band_extra}
    <ColorInterp>Gray</ColorInterp>
    {}
  </VRTRasterBand>
</VRTDataset>"#,
        size.0,
        size.1,
        sources.join("\n    ")
    );
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn later_sources_overwrite_where_valid_and_clip() {
    let d = tempfile::tempdir().unwrap();
    tif(d.path(), "a.tif", (1000.0, 2000.0), (6, 4), 0.0);
    tif(d.path(), "b.tif", (1002.0, 2000.0), (6, 4), 1000.0);
    let sources = [
        source("SimpleSource", "a.tif", (0, 0, 6, 4), (0, 0), ""),
        // b at column 4; its column 5 falls off the 9-wide VRT
        source(
            "ComplexSource",
            "b.tif",
            (0, 0, 6, 4),
            (4, 0),
            "<NODATA>1101</NODATA>",
        ),
    ];
    let path = vrt(d.path(), (9, 4), &sources, "");
    let mut v = VrtSource::open(&path).unwrap();
    assert_eq!((v.raster().width, v.raster().height), (9, 4));
    assert_eq!(v.raster().crs.epsg, Some(32617));
    let px = v.read_rows(0, 4).unwrap();
    let at = |c: usize, r: usize| px[r * 9 + c];
    assert_eq!(at(0, 0), 0.0);
    assert_eq!(at(3, 2), 203.0);
    assert_eq!(at(4, 0), 1000.0, "b overwrites a");
    assert_eq!(
        at(5, 1),
        1.0 + 100.0 + 4.0,
        "b's hole (1, 1) keeps a's (5, 1)"
    );
    assert_eq!(at(8, 3), 1304.0);
    assert!(at(1, 1).is_nan(), "a's hole, no b there");
    assert_eq!(at(5, 2), 1201.0);
    // a read of some rows gives the same rows
    let rows = v.read_rows(1, 2).unwrap();
    assert!(rows
        .iter()
        .zip(&px[9..27])
        .all(|(a, b)| a == b || (a.is_nan() && b.is_nan())));
}

#[test]
fn complex_nodata_and_band_nodata_become_no_data() {
    let d = tempfile::tempdir().unwrap();
    tif(d.path(), "a.tif", (1000.0, 2000.0), (6, 4), 0.0);
    let sources = [source(
        "ComplexSource",
        "a.tif",
        (1, 1, 5, 3),
        (0, 0),
        "<NODATA>102</NODATA>",
    )];
    let path = vrt(d.path(), (5, 3), &sources, "<NoDataValue>205</NoDataValue>");
    let mut v = VrtSource::open(&path).unwrap();
    assert_eq!(v.raster().nodata, Some(205.0));
    let px = v.read_rows(0, 3).unwrap();
    assert!(px[0].is_nan(), "a's hole at (1, 1)");
    assert!(px[1].is_nan(), "NODATA 102");
    assert_eq!(px[2], 103.0);
    // VRT (c, r) = source (c + 1, r + 1): 205 is source (5, 2), VRT (4, 1)
    assert!(px[5 + 4].is_nan(), "NoDataValue 205");
    assert_eq!(px[5 + 3], 204.0);
}

#[test]
fn anything_but_a_plain_mosaic_is_refused_naming_the_element() {
    let d = tempfile::tempdir().unwrap();
    tif(d.path(), "a.tif", (1000.0, 2000.0), (6, 4), 0.0);
    tif(d.path(), "fine.tif", (1000.0, 2000.0), (6, 4), 0.0);
    let plain = source("SimpleSource", "a.tif", (0, 0, 6, 4), (0, 0), "");
    let scaled = source(
        "ComplexSource",
        "a.tif",
        (0, 0, 6, 4),
        (0, 0),
        "<ScaleRatio>2</ScaleRatio>",
    );
    let resampled = plain.replace(
        r#"<DstRect xOff="0" yOff="0" xSize="6""#,
        r#"<DstRect xOff="0" yOff="0" xSize="12""#,
    );
    let half = plain.replace(r#"<DstRect xOff="0""#, r#"<DstRect xOff="0.5""#);
    let vsi = plain.replace(">a.tif<", ">/vsizip/x.zip/a.tif<");
    let band2 = plain.replace("<SourceBand>1<", "<SourceBand>2<");
    let missing = plain.replace(">a.tif<", ">missing.tif<");
    let cases: Vec<(Vec<String>, &str, &str)> = vec![
        (vec![scaled], "", "<ScaleRatio> inside <ComplexSource>"),
        (vec![resampled], "", "resampling"),
        (vec![half], "", "<DstRect xOff=\"0.5\">"),
        (vec![vsi], "", "/vsizip/x.zip/a.tif: only plain GeoTIFF"),
        (vec![band2], "", "only band 1"),
        (vec![missing], "", "<SimpleSource> "),
        (
            vec![plain.replace("SimpleSource", "AveragedSource")],
            "",
            "<AveragedSource> inside <VRTRasterBand>",
        ),
        (vec![], "", "has no source"),
        (
            vec![plain.clone()],
            "<Offset>3</Offset>",
            "<Offset> inside <VRTRasterBand>",
        ),
    ];
    for (sources, band_extra, want) in cases {
        let path = vrt(d.path(), (6, 4), &sources, band_extra);
        let err = VrtSource::open(&path).err().expect(want);
        assert!(err.bad_input, "{want}");
        assert!(
            err.message.starts_with(&path.display().to_string()),
            "{}",
            err.message
        );
        assert!(err.message.contains(want), "{} lacks {want}", err.message);
        assert!(!err.message.contains('\n'));
    }
    let warped = d.path().join("w.vrt");
    std::fs::write(
        &warped,
        r#"<VRTDataset rasterXSize="6" rasterYSize="4" subClass="VRTWarpedDataset"></VRTDataset>"#,
    )
    .unwrap();
    let err = VrtSource::open(&warped).err().unwrap();
    assert!(
        err.message.contains("subClass=\"VRTWarpedDataset\""),
        "{}",
        err.message
    );
    std::fs::write(&warped, "<VRTDataset>").unwrap();
    assert!(VrtSource::open(&warped)
        .err()
        .unwrap()
        .message
        .contains("not valid XML"));
}
