//! Tests of [`super::cut_collection`] on a small generated source GeoTIFF:
//! exact translation, rotation mapped back onto the source, refusals.

use super::*;
use crate::geo::Crs;
use crate::geotiff::writer::write_geotiff_f32;
use crate::poses::{GaugeLabel, GraphKind, PoseEntry, PosesFile};
use crate::synth::epsg_crs;

const W: u64 = 120;
const H: u64 = 100;

/// Height of the test source at pixel (c, r): a tilted plane with ripples
/// and a block "building"; the first 12 columns are no data.
fn source_height(c: u64, r: u64) -> f32 {
    if c < 12 {
        return f32::NAN;
    }
    let (x, y) = (c as f64, r as f64);
    let mut z = 100.0 + 0.05 * x - 0.03 * y + (x / 7.0).sin() * (y / 5.0).cos();
    if (50..62).contains(&c) && (40..55).contains(&r) {
        z += 8.0;
    }
    z as f32
}

fn write_source(dir: &Path, crs: Crs) -> PathBuf {
    let path = dir.join("source.tif");
    let data: Vec<f32> = (0..H)
        .flat_map(|r| (0..W).map(move |c| source_height(c, r)))
        .collect();
    let options = CogOptions {
        tile_size: 64,
        geotransform: GeoTransform::north_up(600_000.0, 4_500_000.0, 0.5, 0.5),
        crs,
        nodata: -9999.0,
        overviews: true,
        ..Default::default()
    };
    write_geotiff_f32(&path, W, H, options, &data).unwrap();
    path
}

fn read(path: &Path) -> (GeoTiffInfo, Vec<f32>) {
    let mut r = GeoTiffReader::open(path).unwrap();
    let info = r.info().clone();
    let data = r.read_rows(0, info.height).unwrap();
    (info, data)
}

fn params(max_rot_deg: f64) -> CutParams {
    CutParams {
        layout: Layout::Grid,
        rows: 2,
        cols: 2,
        size_px: 64,
        overlap: 0.5,
        seed: 5,
        max_rot_deg,
        anchor_first: true,
        ..Default::default()
    }
}

#[test]
fn layout_is_centred_and_translation_only_tiles_copy_the_source() {
    let windows = layout_windows(&params(0.0), W, H);
    assert_eq!(windows, vec![[12, 2], [44, 2], [12, 34], [44, 34]]);
    let dir = tempfile::tempdir().unwrap();
    let src = write_source(dir.path(), epsg_crs(32617));
    let out = dir.path().join("cut");
    let report = cut_collection(&src, &params(0.0), &out, 32).unwrap();
    let truth = Truth::load(&out.join("truth.json")).unwrap();
    assert!(truth.synthetic().is_none());
    let record = truth.cut.as_ref().unwrap();
    assert_eq!(record.params.origin_px, Some([12, 2]));
    assert_eq!(truth.crs, "EPSG:32617");
    assert_eq!(truth.gsd, 0.5);
    assert!((report.valid_fraction[0] - 1.0).abs() < 1e-12);
    let pivot = truth.pivot_z_m.unwrap();
    assert!((95.0..110.0).contains(&pivot), "{pivot}");
    for (k, tile) in truth.tiles.iter().enumerate() {
        let (info, data) = read(&out.join(&tile.file));
        assert_eq!((info.width, info.height), (64, 64));
        assert_eq!(info.nodata, Some(-9999.0));
        assert_eq!(info.crs.epsg, Some(32617));
        let [dx, dy, dz] = tile.shift_m;
        if k == 0 {
            assert_eq!([dx, dy, dz], [0.0; 3]);
        } else {
            assert!(dx.abs() > 1e-3 && dx.abs() <= 3.0 && dz.abs() <= 2.0);
        }
        // the geotransform carries the horizontal shift exactly
        let w = windows[k];
        let g = info.geotransform.0;
        assert!((g[0] + dx - (600_000.0 + 0.5 * w[0] as f64)).abs() < 1e-9);
        assert!((g[3] + dy - (4_500_000.0 - 0.5 * w[1] as f64)).abs() < 1e-9);
        for r in 0..64u64 {
            for c in 0..64u64 {
                let s = source_height(w[0] as u64 + c, w[1] as u64 + r);
                let want = (s as f64 - dz) as f32;
                let got = data[(r * 64 + c) as usize];
                assert!(
                    got.to_bits() == want.to_bits() || (got.is_nan() && s.is_nan()),
                    "{}: ({c}, {r}) {got} vs {want}",
                    tile.id
                );
            }
        }
    }
}

#[test]
fn rotated_tiles_map_back_onto_the_source_and_truth_poses_have_no_error() {
    let dir = tempfile::tempdir().unwrap();
    let src = write_source(dir.path(), epsg_crs(32617));
    let out = dir.path().join("cut");
    let truth = cut_collection(&src, &params(0.05), &out, 32).unwrap().truth;
    let (sinfo, sdata) = read(&src);
    let source = SourceRows {
        geotransform: sinfo.geotransform,
        width: W as i64,
        row0: 0,
        rows: H as i64,
        data: sdata,
    };
    for tile in &truth.tiles[1..] {
        assert!(tile.rot_deg.iter().any(|a| a.abs() > 0.005), "{tile:?}");
        let (info, data) = read(&out.join(&tile.file));
        let m = crate::geo::rigid::from_rows::<nalgebra::Matrix4<f64>>(&tile.matrix_world);
        let (mut valid, mut worst) = (0, 0.0f64);
        for (k, z) in data.iter().enumerate() {
            if z.is_nan() {
                continue;
            }
            let (x, y) = info
                .geotransform
                .pixel_to_world((k % 64) as f64 + 0.5, (k / 64) as f64 + 0.5);
            let p = m * Vector4::new(x, y, *z as f64, 1.0);
            worst = worst.max((p[2] - source.bilinear(p[0], p[1])).abs());
            valid += 1;
        }
        assert!(valid > 3000, "{}: {valid}", tile.id);
        assert!(worst < 1e-4, "{}: {worst} m off the source", tile.id);
    }
    let poses = PosesFile {
        crs: truth.crs.clone(),
        poses: truth
            .tiles
            .iter()
            .map(|t| PoseEntry {
                id: t.id.clone(),
                matrix_world: crate::geo::rigid::from_rows(&t.matrix_world),
                sigma: None,
                status: None,
            })
            .collect(),
        edges: vec![],
        graph: GraphKind::Full,
        gauge: GaugeLabel::Mean,
        components: None,
        summary: None,
    };
    let e = truth.pairwise_error(&poses);
    assert!(e.worst_m < 1e-6 && e.worst_deg < 1e-4, "{e:?}");
    let mut off = poses.clone();
    off.poses[2].matrix_world[(0, 3)] += 0.3;
    let e = truth.pairwise_error(&off);
    assert!((e.worst_m - 0.3).abs() < 1e-9, "{e:?}");
    // same seed, same bytes
    let again = dir.path().join("again");
    cut_collection(&src, &params(0.05), &again, 32).unwrap();
    for name in ["tile_03.tif", "truth.json"] {
        assert_eq!(
            std::fs::read(out.join(name)).unwrap(),
            std::fs::read(again.join(name)).unwrap()
        );
    }
}

#[test]
fn bad_sources_and_layouts_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("cut");
    let src = write_source(dir.path(), epsg_crs(32617));
    let no_data_window = CutParams {
        origin_px: Some([-70, 0]),
        ..params(0.0)
    };
    let err = cut_collection(&src, &no_data_window, &out, 32).unwrap_err();
    assert!(
        err.to_string().contains("tile_00") && err.to_string().contains("no valid height"),
        "{err}"
    );
    assert!(err.is_bad_input() && !out.exists());
    let err = cut_collection(
        &src,
        &CutParams {
            overlap: 1.2,
            ..params(0.0)
        },
        &out,
        32,
    )
    .unwrap_err();
    assert!(err.to_string().contains("overlap"), "{err}");
    let missing = cut_collection(&dir.path().join("nope.tif"), &params(0.0), &out, 32);
    assert!(missing.unwrap_err().to_string().contains("nope.tif"));
    let geographic = Crs {
        epsg: Some(4326),
        is_geographic: true,
        ..Default::default()
    };
    let geo_dir = dir.path().join("geo");
    std::fs::create_dir_all(&geo_dir).unwrap();
    let src = write_source(&geo_dir, geographic);
    let err = cut_collection(&src, &params(0.0), &out, 32).unwrap_err();
    assert!(err.to_string().contains("geographic"), "{err}");
    assert!(err.to_string().contains("source.tif"), "{err}");
}
