//! Integration tests of the inputs users bring (issue 14, item 8): masks of
//! stable terrain (`--mask`, a GeoTIFF or GeoJSON polygons: [`mask`]), initial
//! poses (`--initial`: [`initial`]), and input list files (`ingest
//! @list.txt`: [`lists`]). The helpers they share are here.

mod initial;
mod lists;
mod mask;

use std::path::Path;

use nalgebra::{Matrix4, Vector3, Vector4};
use serde_json::Value;

use dsmstream::geo::GeoTransform;
use dsmstream::geotiff::reader::GeoTiffReader;
use dsmstream::geotiff::writer::{write_geotiff_f32, CogOptions};

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
