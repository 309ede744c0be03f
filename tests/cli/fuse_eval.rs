//! Integration tests of `fuse` and `eval` on the bundled generated collections
//! (truth.json: each tile's `matrix_world` is exactly its correct pose) and on
//! real data (CODEM photogrammetric DSM against its lidar).

use std::path::{Path, PathBuf};
use std::process::Output;

use dsmstream::eval::{diff_stats, DiffStats};
use dsmstream::geo::{Crs, GeoTransform};
use dsmstream::geotiff::reader::GeoTiffReader;
use dsmstream::geotiff::writer::{write_geotiff_f32, CogOptions};
use dsmstream::synth::output::{epsg_crs, write_truth_grid, Truth};
use serde_json::{json, Value};

use crate::util::{bin, fixtures, ok};

fn run(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Output {
    let mut c = bin();
    for a in args {
        c.arg(a);
    }
    c.output().unwrap()
}

/// Ingest a fixture folder into `dir/c.zarr`.
fn ingest(data: &Path, dir: &Path) -> PathBuf {
    let store = dir.join("c.zarr");
    ok(run(&[&"ingest", &data, &"--store", &store, &"-q"]));
    store
}

/// poses.json holding the truth's matrices (optionally edited first).
fn truth_poses(truth: &Path, out: &Path, edit: impl FnOnce(&mut Vec<Value>)) {
    let t: Value = serde_json::from_str(&std::fs::read_to_string(truth).unwrap()).unwrap();
    let mut poses: Vec<Value> = t["tiles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|tile| json!({"id": tile["id"], "matrix_world": tile["matrix_world"]}))
        .collect();
    edit(&mut poses);
    let file =
        json!({"crs": t["crs"], "poses": poses, "edges": [], "graph": "full", "gauge": "mean"});
    std::fs::write(out, serde_json::to_string_pretty(&file).unwrap()).unwrap();
}

/// The noise-free true surface over the tiles of `truth`.
fn truth_grid(truth: &Path, out: &Path) {
    let t = Truth::load(truth).unwrap();
    let (generation, surface) = t.synthetic().expect("a synthetic tile set");
    write_truth_grid(surface, t.bbox(), t.gsd, &epsg_crs(generation.epsg), out).unwrap();
}

fn read(path: &Path) -> (dsmstream::geotiff::reader::GeoTiffInfo, Vec<f32>) {
    let mut r = GeoTiffReader::open(path).unwrap();
    let info = r.info().clone();
    let data = r.read_rows(0, info.height).unwrap();
    (info, data)
}

/// dh = fused - truth at the fused pixel centres (both on the same 0.5 m lattice).
fn fused_vs_truth(fused: &Path, truth: &Path, tau_m: f64) -> DiffStats {
    let (fi, fd) = read(fused);
    let (ti, td) = read(truth);
    let mut dh = Vec::new();
    for r in 0..fi.height {
        for c in 0..fi.width {
            let (x, y) = fi
                .geotransform
                .pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            let (tc, tr) = ti.geotransform.world_to_pixel(x, y);
            let (tc, tr) = (tc.floor(), tr.floor());
            if tc < 0.0 || tr < 0.0 || tc >= ti.width as f64 || tr >= ti.height as f64 {
                continue;
            }
            let t = td[(tr as u64 * ti.width + tc as u64) as usize];
            dh.push(fd[(r * fi.width + c) as usize] - t);
        }
    }
    diff_stats(&mut dh, tau_m)
}

/// Number of images (full resolution + overviews) and the last one's size.
fn ifds(path: &Path) -> (usize, (u32, u32)) {
    let file = std::fs::File::open(path).unwrap();
    let mut d = tiff::decoder::Decoder::new(std::io::BufReader::new(file)).unwrap();
    let mut n = 1;
    while d.more_images() {
        d.next_image().unwrap();
        n += 1;
    }
    (n, d.dimensions().unwrap())
}

fn eval_json(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Value {
    let mut all: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"eval"];
    all.extend_from_slice(args);
    all.push(&"--json");
    let out = ok(run(&all));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn no_files_but(dir: &Path, keep: &[&str]) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !keep.contains(&n.as_str()))
        .collect()
}

#[test]
fn fused_with_truth_poses_matches_the_true_surface() {
    let dir = tempfile::tempdir().unwrap();
    let data = fixtures().join("synth/chain4");
    let store = ingest(&data, dir.path());
    let (poses, truth) = (dir.path().join("poses.json"), dir.path().join("truth.tif"));
    truth_poses(&data.join("truth.json"), &poses, |_| {});
    truth_grid(&data.join("truth.json"), &truth);
    let (fused, raw) = (dir.path().join("fused.tif"), dir.path().join("raw.tif"));
    ok(run(&[
        &"fuse",
        &store,
        &"--poses",
        &poses,
        &"--out",
        &fused,
        &"--threads",
        &"2",
    ]));
    ok(run(&[&"fuse", &store, &"--out", &raw, &"--threads", &"1"]));
    for tau in [3.0, 10.0] {
        let (after, before) = (
            fused_vs_truth(&fused, &truth, tau),
            fused_vs_truth(&raw, &truth, tau),
        );
        eprintln!("tau {tau}: fused vs truth, identity {before:?}\n  truth poses {after:?}");
        assert!(after.rmse_tau_m < before.rmse_tau_m, "tau {tau}");
        assert!(after.inlier_fraction > before.inlier_fraction, "tau {tau}");
        if tau == 3.0 {
            assert!(
                after.rmse_tau_m < 0.5 * before.rmse_tau_m,
                "{after:?} vs {before:?}"
            );
            assert!(after.nmad_m < 0.25 && before.nmad_m > 0.5);
            assert!(after.median_m.abs() < 0.02);
        }
    }
    // georeferencing: 0.5 m cells on tile_00's lattice, covering every corrected tile
    let (info, _) = read(&fused);
    let g = info.geotransform.0;
    assert_eq!((g[1], g[2], g[4], g[5]), (0.5, 0.0, 0.0, -0.5));
    let on_lattice = |v: f64, o: f64| ((v - o) / 0.5 - ((v - o) / 0.5).round()).abs() < 1e-6;
    assert!(on_lattice(g[0], 500_000.0) && on_lattice(g[3], 4_800_000.0));
    let b = info.geotransform.bounds(info.width, info.height);
    let t = Truth::load(&data.join("truth.json")).unwrap();
    for tile in &t.tiles {
        let m = tile.matrix_world;
        let tb = GeoTransform(tile.geotransform).bounds(tile.width, tile.height);
        for (x, y) in [(tb[0], tb[1]), (tb[2], tb[3])] {
            let cx = m[0][0] * x + m[0][1] * y + m[0][2] * 200.0 + m[0][3];
            let cy = m[1][0] * x + m[1][1] * y + m[1][2] * 200.0 + m[1][3];
            assert!(cx > b[0] - 0.6 && cx < b[2] + 0.6 && cy > b[1] - 0.6 && cy < b[3] + 0.6);
        }
    }
    assert!(info.nodata.is_some_and(|v| v.is_nan()), "{:?}", info.nodata);
    assert!(info.tiled && info.block_width == 256);
    assert_eq!(info.crs.epsg, Some(32617));
    let (n, last) = ifds(&fused);
    assert!(n >= 2, "{n} images: no overviews");
    assert!(last.0 <= 256 && last.1 <= 256, "smallest overview {last:?}");
    // per-DSM output: one file per tile, each on its own corrected footprint
    let per = dir.path().join("per");
    ok(run(&[
        &"fuse",
        &store,
        &"--poses",
        &poses,
        &"--per-dsm",
        &per,
    ]));
    assert_eq!(no_files_but(&per, &[]).len(), 4);
    let (ti, _) = read(&per.join("tile_02.tif"));
    assert!((256..=262).contains(&ti.width), "{}", ti.width);
}

#[test]
fn eval_pairs_and_reference_improve_with_truth_poses() {
    let dir = tempfile::tempdir().unwrap();
    let data = fixtures().join("synth/grid2x2");
    let store = ingest(&data, dir.path());
    let (poses, truth) = (dir.path().join("poses.json"), dir.path().join("truth.tif"));
    truth_poses(&data.join("truth.json"), &poses, |_| {});
    truth_grid(&data.join("truth.json"), &truth);
    let plots = dir.path().join("plots");
    let r = eval_json(&[
        &store,
        &"--poses",
        &poses,
        &"--reference",
        &truth,
        &"--plots",
        &plots,
    ]);
    assert_eq!(r["pairs"].as_array().unwrap().len(), 6);
    let f = |v: &Value| v.as_f64().unwrap();
    let (before, after) = (
        f(&r["mean_before"]["rmse_tau_m"]),
        f(&r["mean_after"]["rmse_tau_m"]),
    );
    eprintln!("grid2x2 mean pairwise rmse_tau: before {before:.3} m, after {after:.3} m");
    assert!(after < before);
    assert!(f(&r["mean_after"]["nmad_m"]) < f(&r["mean_before"]["nmad_m"]));
    let rb = f(&r["reference"]["before"]["rmse_tau_m"]);
    let ra = f(&r["reference"]["after"]["rmse_tau_m"]);
    eprintln!("grid2x2 fused vs truth rmse_tau: before {rb:.3} m, after {ra:.3} m");
    assert!(ra < rb);
    assert_eq!(r["rmse_tau_n"], "inliers (|dh| < tau)");
    for name in [
        "scene_graph",
        "hist_pairs",
        "hist_reference",
        "diff_map_reference",
    ] {
        let img = image::open(plots.join(format!("{name}.png"))).unwrap();
        assert!(img.width() > 400 && img.height() > 300, "{name}");
    }
    // the raw collection: before only, same figures
    let raw = eval_json(&[&store]);
    assert!(raw["mean_after"].is_null());
    assert_eq!(raw["mean_before"], r["mean_before"]);
    // the table form
    let out = ok(run(&[&"eval", &store, &"--poses", &poses]));
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(
        table.contains("mean over 6 pairs") && table.contains("after"),
        "{table}"
    );
}

#[test]
fn poses_that_do_not_match_the_store_are_refused_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let data = fixtures().join("synth/chain4");
    let store = ingest(&data, dir.path());
    let truth = data.join("truth.json");
    type Edit = Box<dyn FnOnce(&mut Vec<Value>)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "missing",
            Box::new(|p| {
                p.remove(2);
            }),
            "no pose for DSM 'tile_02'",
        ),
        (
            "unknown",
            Box::new(|p| p[1]["id"] = json!("tile_99")),
            "tile_99",
        ),
        (
            "nonrigid",
            Box::new(|p| p[3]["matrix_world"][0][0] = json!(1.05)),
            "tile_03",
        ),
        (
            "shape",
            Box::new(|p| p[0]["matrix_world"] = json!([[1, 0, 0], [0, 1, 0]])),
            "tile_00",
        ),
    ];
    for (name, edit, needle) in cases {
        let poses = dir.path().join(format!("{name}.json"));
        truth_poses(&truth, &poses, edit);
        let out_path = dir.path().join("out").join(format!("{name}.tif"));
        std::fs::create_dir_all(out_path.parent().unwrap()).unwrap();
        let out = run(&[&"fuse", &store, &"--poses", &poses, &"--out", &out_path]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{name}: {err}");
        assert!(
            err.contains(needle) && err.contains(&format!("{name}.json")),
            "{name}: {err}"
        );
        assert!(
            no_files_but(out_path.parent().unwrap(), &[]).is_empty(),
            "{name}: file left"
        );
        let out = run(&[&"eval", &store, &"--poses", &poses]);
        assert_eq!(out.status.code(), Some(2), "eval {name}");
    }
    let garbage = dir.path().join("garbage.json");
    std::fs::write(&garbage, "{ not json").unwrap();
    let out = run(&[
        &"fuse",
        &store,
        &"--poses",
        &garbage,
        &"--out",
        &dir.path().join("g.tif"),
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("garbage.json"));
    assert!(!dir.path().join("g.tif").exists());
}

#[test]
fn references_in_another_crs_or_elsewhere_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let store = ingest(&fixtures().join("synth/chain4"), dir.path());
    let write = |name: &str, crs: Crs, ox: f64| {
        let path = dir.path().join(name);
        let options = CogOptions {
            geotransform: GeoTransform::north_up(ox, 4_799_990.0, 0.5, 0.5),
            crs,
            ..Default::default()
        };
        write_geotiff_f32(&path, 32, 32, options, &vec![210.0; 32 * 32]).unwrap();
        path
    };
    // NAD83(CSRS) / UTM 17N: a CRS dsmstream does not put into WGS 84's zone
    let nad83 = write("csrs.tif", epsg_crs(2958), 500_010.0);
    let far = write("far.tif", epsg_crs(32617), 700_000.0);
    // PDAL's Autzen lidar, in feet: named for its unit, not compared in it
    let feet = fixtures().join("real/pdal/autzen_trim.laz");
    for (path, needle) in [
        (&nad83, "differs from the store"),
        (&far, "does not overlap"),
        (
            &feet,
            "horizontal unit foot (EPSG unit 9002) in the point cloud's CRS, not metres",
        ),
    ] {
        let out = run(&[&"eval", &store, &"--reference", path]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(
            err.contains(needle) && err.contains(&path.display().to_string()),
            "{err}"
        );
    }
}

#[test]
fn codem_dsm_against_its_lidar() {
    let dir = tempfile::tempdir().unwrap();
    let codem = fixtures().join("real/codem");
    let store = ingest(&codem.join("dem.tif"), dir.path());
    let r = eval_json(&[&store, &"--reference", &codem.join("pc.laz")]);
    let s = &r["reference"]["before"];
    eprintln!(
        "CODEM dem.tif - pc.laz: {}",
        serde_json::to_string(s).unwrap()
    );
    eprintln!("notes: {}", r["reference"]["notes"]);
    let f = |k: &str| s[k].as_f64().unwrap();
    // the DSM sits a decimetre or two above the lidar (xDEM ICP: dz about -0.19 m)
    assert!((0.05..0.35).contains(&f("median_m")), "{}", f("median_m"));
    assert!(f("nmad_m") < 0.6 && f("inlier_fraction") > 0.9);
    assert!(s["samples"].as_u64().unwrap() > 100_000);
    assert!(r["reference"]["notes"][0]
        .as_str()
        .unwrap()
        .contains("EPSG:32616"));
}

/// `fuse --method spread` maps where the DSMs disagree: with the true poses
/// the overlaps agree far better than uncorrected.
#[test]
fn spread_map_shrinks_with_the_true_poses() {
    let dir = tempfile::tempdir().unwrap();
    let store = ingest(&fixtures().join("synth/chain4"), dir.path());
    let poses = dir.path().join("truth_poses.json");
    truth_poses(&fixtures().join("synth/chain4/truth.json"), &poses, |_| {});
    let median_spread = |with_poses: bool| {
        let out = dir.path().join(format!("spread_{with_poses}.tif"));
        let mut args: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![
            &"fuse",
            &store,
            &"--method",
            &"spread",
            &"--out",
            &out,
            &"-q",
        ];
        if with_poses {
            args.extend([&"--poses" as &dyn AsRef<std::ffi::OsStr>, &poses]);
        }
        ok(run(&args));
        let (_, data) = read(&out);
        let mut v: Vec<f32> = data.into_iter().filter(|x| !x.is_nan()).collect();
        assert!(v.len() > 10_000, "{} overlap pixels", v.len());
        assert!(v.iter().all(|&x| x >= 0.0));
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    let (raw, aligned) = (median_spread(false), median_spread(true));
    assert!(
        aligned < 0.5 * raw,
        "median spread {aligned} m vs raw {raw} m"
    );
}
