//! Real DSMs gridded independently, with a known answer: a lidar cloud split
//! at random into two halves of its points (`dsmgen grid --subset`), each half
//! moved by its own known turn, shift and datum offset and gridded over its
//! own window on its own lattice (a fraction of a cell apart). The relative
//! motion is the pair's truth; `pair` at the defaults must find it within
//! three of its sigmas per axis. `tools/scripts/real_split.py` runs hundreds
//! of such pairs (docs/measurements.md, "Real DSMs gridded independently").
//! Clouds: CODEM's lidar (fixtures/real/codem, Apache-2.0; 1.8 returns per
//! m^2) and Tommy Thompson Park's (fixtures/real/ttp2015, MIT; sparse, half
//! of it water).

use std::path::{Path, PathBuf};

use crate::util::{dsmgen_grid, fixtures, ingest, pair_json, shift_and_sigma};

/// One DSM of a pair: its window (xmin ymin xmax ymax), and the motion its
/// points get before gridding: shift (m), turn about the window's centre
/// (deg), height offset (m).
struct Half {
    window: [f64; 4],
    shift: [f64; 2],
    yaw_deg: f64,
    dz: f64,
}

impl Half {
    /// The window's centre, which the turn is about.
    fn centre(&self) -> [f64; 2] {
        [
            (self.window[0] + self.window[2]) / 2.0,
            (self.window[1] + self.window[3]) / 2.0,
        ]
    }

    /// Where the motion takes point `p` (x, y): turn about the centre, shift.
    fn moved(&self, p: [f64; 2]) -> [f64; 2] {
        let c = self.centre();
        let (sin, cos) = self.yaw_deg.to_radians().sin_cos();
        let (x, y) = (p[0] - c[0], p[1] - c[1]);
        [
            c[0] + cos * x - sin * y + self.shift[0],
            c[1] + sin * x + cos * y + self.shift[1],
        ]
    }

    /// The inverse of [`moved`](Self::moved).
    fn unmoved(&self, q: [f64; 2]) -> [f64; 2] {
        let c = self.centre();
        let (sin, cos) = (-self.yaw_deg.to_radians()).sin_cos();
        let (x, y) = (q[0] - self.shift[0] - c[0], q[1] - self.shift[1] - c[1]);
        [c[0] + cos * x - sin * y, c[1] + sin * x + cos * y]
    }
}

/// Grids half `k` of `points` with `half`'s motion into `dir`/d`k`.tif.
fn grid_half(points: &Path, dir: &Path, k: usize, cell: (&str, &str), half: &Half) -> PathBuf {
    let out = dir.join(format!("d{k}.tif"));
    let f = |v: f64| format!("{v}");
    let [x0, y0, x1, y1] = half.window.map(f);
    let (sx, sy, dz) = (f(half.shift[0]), f(half.shift[1]), f(half.dz));
    let yaw = format!("--yaw-deg={}", half.yaw_deg);
    let subset = format!("{k}/2");
    dsmgen_grid(
        points,
        &[
            "--gsd", cell.0, "--stat", cell.1, "--subset", &subset, "--shift", &sx, &sy, &yaw,
            "--dz", &dz, "--window", &x0, &y0, &x1, &y1,
        ],
        &out,
    );
    out
}

/// `pair d0 d1` at the defaults on the two halves: the JSON, the true shift
/// at the fit's centre (p_ref - p_moving) and the true yaw (deg).
fn register_halves(
    points: &Path,
    cell: (&str, &str),
    halves: [&Half; 2],
) -> (serde_json::Value, [f64; 3], f64) {
    let dir = tempfile::tempdir().unwrap();
    let tifs = [0, 1].map(|k| grid_half(points, dir.path(), k, cell, halves[k]));
    let store = dir.path().join("s.zarr");
    ingest(&tifs, &store);
    let (code, doc) = pair_json(&store, "d0", "d1");
    assert_eq!(code, Some(0), "{doc}");
    // a point q of d1 came from halves[1].unmoved(q) on the ground, which d0
    // shows at halves[0].moved(that)
    let q = [0, 1].map(|i| doc["centre_m"][i].as_f64().unwrap());
    let p = halves[0].moved(halves[1].unmoved(q));
    let want = [p[0] - q[0], p[1] - q[1], halves[0].dz - halves[1].dz];
    (doc, want, halves[0].yaw_deg - halves[1].yaw_deg)
}

/// Each axis within 3 sigma of the truth (x, y, z and yaw), and the shift
/// within `max_px` pixels of `cell_m`.
fn assert_within_sigmas(
    doc: &serde_json::Value,
    want: [f64; 3],
    yaw: f64,
    cell_m: f64,
    max_px: f64,
) {
    let (got, sigma) = shift_and_sigma(doc);
    for i in 0..3 {
        let err = (got[i] - want[i]).abs();
        assert!(
            err <= 3.0 * sigma[i] && err < max_px * cell_m,
            "axis {i}: {got:?} +- {sigma:?}, truth {want:?}"
        );
    }
    let yaw_got = doc["rotation_deg"][2].as_f64().unwrap();
    let yaw_sigma = doc["sigma"]["rotation_deg"][2]
        .as_f64()
        .unwrap_or(f64::INFINITY);
    assert!(
        (yaw_got - yaw).abs() <= 3.0 * yaw_sigma,
        "yaw {yaw_got} +- {yaw_sigma}, truth {yaw}"
    );
}

fn still(window: [f64; 4]) -> Half {
    Half {
        window,
        shift: [0.0; 2],
        yaw_deg: 0.0,
        dz: 0.0,
    }
}

#[test]
fn two_halves_of_codem_s_lidar_register_within_their_sigmas() {
    let points = fixtures().join("real/codem/pc.laz");
    let cases = [
        (
            ("2", "max"),
            still([627009.0, 4323549.0, 627184.0, 4323924.0]),
            Half {
                window: [627124.7, 4323549.0, 627299.0, 4323923.3],
                shift: [4.2, -3.1],
                yaw_deg: 0.06,
                dz: 1.5,
            },
        ),
        (
            ("1", "mean"),
            still([627009.0, 4323691.5, 627299.0, 4323924.0]),
            Half {
                window: [627009.4, 4323549.0, 627299.0, 4323781.9],
                shift: [-6.3, 2.4],
                yaw_deg: -0.08,
                dz: 30.0,
            },
        ),
        (
            ("2", "mean"),
            still([627009.0, 4323549.0, 627169.0, 4323924.0]),
            Half {
                window: [627139.3, 4323549.0, 627299.0, 4323922.9],
                shift: [1.7, 7.5],
                yaw_deg: 0.03,
                dz: 0.0,
            },
        ),
    ];
    for (cell, reference, moving) in &cases {
        let (doc, want, yaw) = register_halves(&points, *cell, [reference, moving]);
        assert_eq!(doc["status"], "converged", "{doc}");
        assert_within_sigmas(&doc, want, yaw, cell.0.parse().unwrap(), 0.3);
    }
}

/// Case 46 of the Tommy Thompson Park battery (`real_split.py BIN 0 100
/// --points TTP_15.laz`), its draws to the printed digits: sparse lidar (0.5
/// returns per m^2 in each half) over trees, shore and water, a 30 m strip.
/// The forward fit lands 2.3 m off with a y sigma of 0.26 m (8.2 sigma: the
/// battery's one real pair beyond 3 sigma); its backward fit's covariance says
/// 1.2 m, which the pair now carries (1.8 sigma). Not a guarantee: the same
/// draws rounded to the millimetre land 2.4 m off at 3.5 sigma (docs/measurements.md,
/// "Real DSMs gridded independently").
#[test]
fn a_sparse_pair_whose_forward_fit_is_overconfident_carries_its_backward_sigma() {
    let points = fixtures().join("real/ttp2015/TTP_15.laz");
    let reference = Half {
        window: [634006.323527, 4831662.0, 634488.0, 4832044.329240],
        shift: [4.703797, -4.896403],
        yaw_deg: 0.04741782,
        dz: 30.0,
    };
    let moving = Half {
        window: [634006.591105, 4831309.0, 634488.0, 4831690.545750],
        shift: [-9.593803, 6.187910],
        yaw_deg: -0.08665971,
        dz: 0.0,
    };
    let (doc, want, yaw) = register_halves(&points, ("2", "max"), [&reference, &moving]);
    assert_eq!(doc["status"], "converged", "{doc}");
    assert_within_sigmas(&doc, want, yaw, 2.0, 2.0);
}
