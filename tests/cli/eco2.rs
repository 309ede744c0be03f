//! Integration tests of the inputs users bring (issue 14, item 8): masks of
//! stable terrain (`--mask`, a GeoTIFF or GeoJSON polygons), initial poses
//! (`--initial`), and input list files (`ingest @list.txt`).

use std::path::{Path, PathBuf};

use nalgebra::{Matrix4, Vector3, Vector4};
use serde_json::{json, Value};

use dsmstream::geo::GeoTransform;
use dsmstream::geotiff::reader::GeoTiffReader;
use dsmstream::geotiff::writer::{write_geotiff_f32, CogOptions};
use dsmstream::synth::output::epsg_crs;

use crate::util::{dsmgen_tiles, fixtures, ingest, ok, run, text};

fn matrix(v: &Value) -> Matrix4<f64> {
    Matrix4::from_fn(|r, c| v[r][c].as_f64().unwrap())
}

fn translation(t: Vector3<f64>) -> Matrix4<f64> {
    Matrix4::new_translation(&t)
}

/// Largest displacement (m) at the corners, at 230 m height, of est^-1 truth.
fn error_m(est: &Matrix4<f64>, truth: &Matrix4<f64>, corners: &[(f64, f64)]) -> f64 {
    let e = est.try_inverse().unwrap() * truth;
    corners
        .iter()
        .map(|&(x, y)| {
            let p = Vector4::new(x, y, 230.0, 1.0);
            (e * p - p).xyz().norm()
        })
        .fold(0.0, f64::max)
}

/// `dsmgen tiles` output: the truth's matrix_world of tile `k` and its geotransform.
struct Truth(Value);

impl Truth {
    fn load(tiles: &Path) -> Truth {
        let text = std::fs::read_to_string(tiles.join("truth.json")).unwrap();
        Truth(serde_json::from_str(&text).unwrap())
    }
    fn m(&self, k: usize) -> Matrix4<f64> {
        matrix(&self.0["tiles"][k]["matrix_world"])
    }
    fn gt(&self, k: usize) -> [f64; 6] {
        std::array::from_fn(|i| self.0["tiles"][k]["geotransform"][i].as_f64().unwrap())
    }
}

/// Rewrites a GeoTIFF with `edit(x, y, height) -> height` applied to every
/// valid pixel (at its centre) and its origin moved by `move_xy_m`.
fn rewrite(path: &Path, move_xy_m: (f64, f64), edit: impl Fn(f64, f64, f32) -> f32) {
    let mut reader = GeoTiffReader::open(path).unwrap();
    let info = reader.info().clone();
    let mut data = reader.read_rows(0, info.height).unwrap();
    drop(reader);
    let gt = info.geotransform;
    for (k, h) in data.iter_mut().enumerate() {
        let (c, r) = (
            (k as u64 % info.width) as f64,
            (k as u64 / info.width) as f64,
        );
        let (x, y) = gt.pixel_to_world(c + 0.5, r + 0.5);
        if !h.is_nan() {
            *h = edit(x, y, *h);
        }
    }
    let g = gt.0;
    let options = CogOptions {
        geotransform: GeoTransform([
            g[0] + move_xy_m.0,
            g[1],
            g[2],
            g[3] + move_xy_m.1,
            g[4],
            g[5],
        ]),
        crs: info.crs.clone(),
        ..Default::default()
    };
    std::fs::remove_file(path).unwrap();
    write_geotiff_f32(path, info.width, info.height, options, &data).unwrap();
}

/// A box [min_x, max_x] x [min_y, max_y], metres.
#[derive(Clone, Copy, Debug)]
struct Box2 {
    min_x: f64,
    max_x: f64,
    min_y: f64,
    max_y: f64,
}

impl Box2 {
    fn contains(&self, x: f64, y: f64) -> bool {
        (self.min_x..=self.max_x).contains(&x) && (self.min_y..=self.max_y).contains(&y)
    }
    fn grown(&self, m: f64) -> Box2 {
        Box2 {
            min_x: self.min_x - m,
            max_x: self.max_x + m,
            min_y: self.min_y - m,
            max_y: self.max_y + m,
        }
    }
    fn corners(&self) -> [(f64, f64); 4] {
        [
            (self.min_x, self.min_y),
            (self.max_x, self.min_y),
            (self.min_x, self.max_y),
            (self.max_x, self.max_y),
        ]
    }
}

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
    // a mask in another CRS: one line, exit 2, the file named
    let utm18 = p.dir.path().join("utm18.tif");
    write_tiff_mask(&utm18, area, p.raised, 32618);
    let out = run(&[&"pair", &p.store, &"tile_00", &"tile_01", &"--mask", &utm18]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert!(
        err.contains("utm18.tif") && err.contains("EPSG:32618"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
}

/// The chain4 fixture with tile_03 moved by `shift` (its file's origin), in `dir/s.zarr`.
fn shifted_chain(dir: &Path, shift: (f64, f64)) -> (PathBuf, Truth) {
    let tiles = dir.join("tiles");
    std::fs::create_dir(&tiles).unwrap();
    let chain4 = fixtures().join("synth/chain4");
    for name in [
        "tile_00.tif",
        "tile_01.tif",
        "tile_02.tif",
        "tile_03.tif",
        "truth.json",
    ] {
        std::fs::copy(chain4.join(name), tiles.join(name)).unwrap();
    }
    rewrite(&tiles.join("tile_03.tif"), shift, |_, _, h| h);
    let store = dir.join("s.zarr");
    ingest(std::slice::from_ref(&tiles), &store);
    (store, Truth::load(&tiles))
}

/// The error of tile_02^-1 tile_03 in `poses` against the truth with tile_03
/// moved by `shift` (the correction must first undo it), at tile_03's corners.
fn chain_error(poses: &Path, truth: &Truth, shift: (f64, f64)) -> f64 {
    let doc: Value = serde_json::from_str(&std::fs::read_to_string(poses).unwrap()).unwrap();
    let pose = |id: &str| {
        let p = doc["poses"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["id"] == id)
            .unwrap();
        matrix(&p["matrix_world"])
    };
    let undo = translation(Vector3::new(-shift.0, -shift.1, 0.0));
    let rel_truth = truth.m(2).try_inverse().unwrap() * truth.m(3) * undo;
    let rel = pose("tile_02").try_inverse().unwrap() * pose("tile_03");
    let g = truth.gt(3);
    let tile = Box2 {
        min_x: g[0] + shift.0,
        max_x: g[0] + shift.0 + 128.0,
        min_y: g[3] + shift.1 - 128.0,
        max_y: g[3] + shift.1,
    };
    error_m(&rel, &rel_truth, &tile.corners())
}

#[test]
fn initial_poses_recover_a_dsm_offset_beyond_the_search_radius() {
    let dir = tempfile::tempdir().unwrap();
    let shift = (40.0, -30.0);
    let (store, truth) = shifted_chain(dir.path(), shift);
    let radius = ["--max-displacement", "15"];
    // without: the offset is beyond the search radius
    let plain = dir.path().join("plain.json");
    let out = run(&[&"align", &store, &"--out", &plain, &radius[0], &radius[1]]);
    let failed = !out.status.success() || chain_error(&plain, &truth, shift) > 5.0;
    assert!(failed, "{}", text(&out.stdout));
    // with 80 % of the offset given as tile_03's initial pose
    let initial = dir.path().join("initial.json");
    let start = translation(Vector3::new(-0.8 * shift.0, -0.8 * shift.1, 0.0));
    let rows: Vec<Vec<f64>> = (0..4)
        .map(|r| (0..4).map(|c| start[(r, c)]).collect())
        .collect();
    let doc = json!({"poses": [{"id": "tile_03", "matrix_world": rows}]});
    std::fs::write(&initial, doc.to_string()).unwrap();
    let poses = dir.path().join("poses.json");
    ok(run(&[
        &"align",
        &store,
        &"--out",
        &poses,
        &radius[0],
        &radius[1],
        &"--initial",
        &initial,
    ]));
    let e = chain_error(&poses, &truth, shift);
    assert!(e < 0.15, "with --initial: {e} m");
    // pair takes the same file
    let out = ok(run(&[
        &"pair",
        &store,
        &"tile_02",
        &"tile_03",
        &"--json",
        &radius[0],
        &radius[1],
        &"--initial",
        &initial,
    ]));
    let doc: Value = serde_json::from_slice(&out.stdout).unwrap();
    let undo = translation(Vector3::new(-shift.0, -shift.1, 0.0));
    let rel_truth = truth.m(2).try_inverse().unwrap() * truth.m(3) * undo;
    let g = truth.gt(3);
    let corner = [(g[0] + shift.0 + 10.0, g[3] + shift.1 - 10.0)];
    let e = error_m(&matrix(&doc["matrix_world"]), &rel_truth, &corner);
    assert!(e < 0.15, "pair --initial: {e} m");
    // the gauge follows the initial poses: an anchor keeps its initial pose
    let anchored = dir.path().join("anchored.json");
    ok(run(&[
        &"align", &store, &"--out", &anchored, &radius[0], &radius[1], &"--initial", &initial,
        &"--anchor", &"tile_03",
    ]));
    let doc: Value = serde_json::from_str(&std::fs::read_to_string(&anchored).unwrap()).unwrap();
    let p3 = doc["poses"].as_array().unwrap().iter().find(|p| p["id"] == "tile_03").unwrap();
    assert!((matrix(&p3["matrix_world"]) - start).amax() < 1e-9, "{}", p3);
    assert!(chain_error(&anchored, &truth, shift) < 0.15);
    // the journal records the initial poses: another file is refused
    let other = dir.path().join("other.json");
    std::fs::write(&other, r#"{"poses": []}"#).unwrap();
    let out = run(&[
        &"align",
        &store,
        &"--out",
        &poses,
        &radius[0],
        &radius[1],
        &"--initial",
        &other,
    ]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    assert!(
        text(&out.stderr).contains("--initial"),
        "{}",
        text(&out.stderr)
    );
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

#[test]
fn an_input_list_names_paths_relative_to_its_own_folder() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let lists = dir.path().join("lists");
    std::fs::create_dir(&data).unwrap();
    std::fs::create_dir(&lists).unwrap();
    let chain4 = fixtures().join("synth/chain4");
    for name in ["tile_00.tif", "tile_01.tif", "tile_03.tif"] {
        std::fs::copy(chain4.join(name), data.join(name)).unwrap();
    }
    let list = lists.join("inputs.txt");
    let abs = data.join("tile_03.tif");
    let lines = format!(
        "# relative to this file\n../data/tile_00.tif\n\n   ../data/tile_01.tif\n{}\n",
        abs.display()
    );
    std::fs::write(&list, lines).unwrap();
    let store = dir.path().join("s.zarr");
    // run from elsewhere: the paths do not depend on the current directory
    let mut cmd = crate::util::bin();
    cmd.current_dir(std::env::temp_dir())
        .arg("ingest")
        .arg(format!("@{}", list.display()))
        .arg("--store")
        .arg(&store);
    let out = ok(cmd.output().unwrap());
    assert!(
        text(&out.stdout).contains("3 ingested"),
        "{}",
        text(&out.stdout)
    );
    let missing = format!("@{}", lists.join("none.txt").display());
    let out = run(&[&"ingest", &missing, &"--store", &store]);
    assert_eq!(out.status.code(), Some(2));
    let err = text(&out.stderr);
    assert!(
        err.contains("none.txt") && err.trim_end().lines().count() == 1,
        "{err}"
    );
    // a listed file that does not exist is named
    std::fs::write(&list, "../data/tile_09.tif\n").unwrap();
    let out = run(&[
        &"ingest",
        &format!("@{}", list.display()),
        &"--store",
        &store,
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("tile_09.tif"),
        "{}",
        text(&out.stderr)
    );
}
