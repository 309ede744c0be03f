//! How a tile's pixels are made from the world: the way real DSMs are gridded
//! from points. `centre` evaluates the surface at each pixel centre (exact
//! point sampling, the original renderer, in [`super::tiles`]); the others
//! scatter points at random positions (Poisson, `points_per_px` per pixel on
//! average, drawn per pixel cell from the tile's seed) and grid them:
//!
//! - `lidar-max` / `lidar-mean`: the max / mean of the points in each pixel
//!   (an empty pixel takes its 3 x 3 neighbourhood's points);
//! - `idw`: inverse-distance (power 2) interpolation at the pixel centre from
//!   the points within 1.5 mean point spacings (stereo point clouds);
//! - `tin`: linear interpolation in the Delaunay triangle holding the pixel
//!   centre, found among the 10 nearest points (a triangle whose circumcircle
//!   holds none of them);
//! - `smooth`: `lidar-mean` then a 5 x 5 Gaussian (sigma 1 px), the footprint
//!   of a stereo matching window.
//!
//! Every point's height is the exact written height at its position (the
//! world seen through m_world^-1, see [`super::tiles`]) plus its own noise, so
//! truth.json stays exact: the truth is the rigid motion, whatever the gridding.
//! Points are a function of (seed, pixel cell) only, so a window renders the
//! same pixels whatever its bounds. Random positions keep sub-pixel motions:
//! a regular lattice of samples would lock to the pixel grid.

use serde::{Deserialize, Serialize};

use super::surface::Surface;
use super::tiles::{written_height, TileSpec};
use crate::rng::{derive_seed, hash2, SplitMix64};

/// How points become pixels (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Rendering {
    /// The surface at each pixel centre (the original renderer).
    #[default]
    Centre,
    LidarMax,
    LidarMean,
    Tin,
    Idw,
    Smooth,
}

impl Rendering {
    /// Points per pixel when none is given.
    pub fn default_points_per_px(self) -> f64 {
        match self {
            Rendering::Centre => 0.0,
            Rendering::LidarMax | Rendering::LidarMean | Rendering::Smooth => 4.0,
            Rendering::Idw => 1.0,
            Rendering::Tin => 0.5,
        }
    }
}

/// A scattered point in the tile's pixel coordinates (col, row: 0..width).
#[derive(Clone, Copy, Debug)]
struct Point {
    u: f64,
    v: f64,
    z: f64,
}

/// The points of the pixel cells [c0, c0 + w) x [r0, r0 + h).
struct PointField {
    c0: i64,
    r0: i64,
    w: i64,
    h: i64,
    cells: Vec<Vec<Point>>,
}

impl PointField {
    #[allow(clippy::too_many_arguments)]
    fn build(
        surface: &Surface,
        spec: &TileSpec,
        epoch: Option<u64>,
        noise_sigma_m: f64,
        density: f64,
        [c0, r0, w, h]: [i64; 4],
    ) -> PointField {
        let mut sampler = surface.sampler();
        let seed = derive_seed(spec.seed, 10);
        let mut cells = Vec::with_capacity((w * h) as usize);
        for r in r0..r0 + h {
            for c in c0..c0 + w {
                let mut rng = SplitMix64::new(hash2(seed, c, r));
                let n = poisson(&mut rng, density);
                let mut pts = Vec::with_capacity(n);
                for _ in 0..n {
                    let (u, v) = (c as f64 + rng.next_f64(), r as f64 + rng.next_f64());
                    let noise = noise_sigma_m * rng.normal();
                    let (x, y) = spec.geotransform.pixel_to_world(u, v);
                    let z = written_height(&mut sampler, &spec.m_world, epoch, x, y);
                    if z.is_finite() {
                        pts.push(Point { u, v, z: z + noise });
                    }
                }
                cells.push(pts);
            }
        }
        PointField {
            c0,
            r0,
            w,
            h,
            cells,
        }
    }

    fn cell(&self, c: i64, r: i64) -> &[Point] {
        let (i, j) = (c - self.c0, r - self.r0);
        if i < 0 || j < 0 || i >= self.w || j >= self.h {
            return &[];
        }
        &self.cells[(j * self.w + i) as usize]
    }

    /// Points of the cells within `k` cells of (c, r).
    fn near(&self, c: i64, r: i64, k: i64) -> impl Iterator<Item = &Point> {
        (r - k..=r + k).flat_map(move |rr| (c - k..=c + k).flat_map(move |cc| self.cell(cc, rr)))
    }
}

/// Poisson-distributed count (Knuth; fine for the small means used here).
fn poisson(rng: &mut SplitMix64, mean: f64) -> usize {
    let limit = (-mean).exp();
    let (mut k, mut p) = (0usize, rng.next_f64());
    while p > limit {
        k += 1;
        p *= rng.next_f64();
    }
    k
}

/// Heights of the window [col0, col0 + w) x [row0, row0 + h) by a point
/// rendering (not `Centre`), before voids and outliers; row-major.
pub fn render_points(
    surface: &Surface,
    spec: &TileSpec,
    rendering: Rendering,
    points_per_px: f64,
    noise_sigma_m: f64,
    epoch: Option<u64>,
    [col0, row0, w, h]: [i64; 4],
) -> Vec<f64> {
    let density = if points_per_px > 0.0 {
        points_per_px
    } else {
        rendering.default_points_per_px()
    };
    let spacing_px = 1.0 / density.sqrt();
    let (idw_radius, reach) = match rendering {
        Rendering::Idw => (1.5 * spacing_px, (1.5 * spacing_px).ceil() as i64),
        Rendering::Tin => (0.0, (3.0 * spacing_px).ceil() as i64),
        Rendering::Smooth => (0.0, 3),
        _ => (0.0, 1),
    };
    let field = PointField::build(
        surface,
        spec,
        epoch,
        noise_sigma_m,
        density,
        [col0 - reach, row0 - reach, w + 2 * reach, h + 2 * reach],
    );
    let pixel = |c: i64, r: i64| -> f64 {
        match rendering {
            Rendering::LidarMax => binned(&field, c, r, true),
            Rendering::LidarMean | Rendering::Smooth => binned(&field, c, r, false),
            Rendering::Idw => idw(&field, c, r, idw_radius),
            Rendering::Tin => tin(&field, c, r, reach),
            Rendering::Centre => unreachable!("centre is rendered by tiles::render_window"),
        }
    };
    if rendering != Rendering::Smooth {
        let mut out = Vec::with_capacity((w * h) as usize);
        for r in row0..row0 + h {
            for c in col0..col0 + w {
                out.push(pixel(c, r));
            }
        }
        return out;
    }
    // Smooth: a lidar-mean window two pixels wider, then the 5 x 5 Gaussian.
    let (ew, eh) = (w + 4, h + 4);
    let mut base = Vec::with_capacity((ew * eh) as usize);
    for r in row0 - 2..row0 + h + 2 {
        for c in col0 - 2..col0 + w + 2 {
            base.push(pixel(c, r));
        }
    }
    gaussian_5x5(&base, ew, eh)
}

/// Max or mean of the points in pixel (c, r), else of its 3 x 3 neighbourhood.
fn binned(field: &PointField, c: i64, r: i64, max: bool) -> f64 {
    let reduce = |pts: &mut dyn Iterator<Item = &Point>| -> f64 {
        let (mut n, mut sum, mut top) = (0usize, 0.0, f64::NEG_INFINITY);
        for p in pts {
            n += 1;
            sum += p.z;
            top = top.max(p.z);
        }
        match (n, max) {
            (0, _) => f64::NAN,
            (_, true) => top,
            (_, false) => sum / n as f64,
        }
    };
    let own = reduce(&mut field.cell(c, r).iter());
    if own.is_finite() {
        own
    } else {
        reduce(&mut field.near(c, r, 1))
    }
}

/// Inverse-distance-squared mean of the points within `radius_px` of the centre.
fn idw(field: &PointField, c: i64, r: i64, radius_px: f64) -> f64 {
    let (pu, pv) = (c as f64 + 0.5, r as f64 + 0.5);
    let (mut sw, mut swz) = (0.0, 0.0);
    for p in field.near(c, r, radius_px.ceil() as i64) {
        let d2 = (p.u - pu).powi(2) + (p.v - pv).powi(2);
        if d2 <= radius_px * radius_px {
            let w = 1.0 / d2.max(1e-6);
            sw += w;
            swz += w * p.z;
        }
    }
    if sw > 0.0 {
        swz / sw
    } else {
        f64::NAN
    }
}

/// Linear interpolation in the (local) Delaunay triangle holding the centre.
fn tin(field: &PointField, c: i64, r: i64, reach: i64) -> f64 {
    let (pu, pv) = (c as f64 + 0.5, r as f64 + 0.5);
    let mut near: Vec<(f64, Point)> = field
        .near(c, r, reach)
        .map(|p| ((p.u - pu).powi(2) + (p.v - pv).powi(2), *p))
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    near.truncate(10);
    let pts: Vec<Point> = near.into_iter().map(|(_, p)| p).collect();
    let n = pts.len();
    let mut best: Option<(f64, f64)> = None; // (circumradius^2, height)
    for a in 0..n {
        for b in a + 1..n {
            for k in b + 1..n {
                let (pa, pb, pc) = (pts[a], pts[b], pts[k]);
                let Some(bary) = barycentric(pa, pb, pc, pu, pv) else {
                    continue;
                };
                let Some((ox, oy, rr)) = circumcircle(pa, pb, pc) else {
                    continue;
                };
                let empty = pts.iter().enumerate().all(|(i, q)| {
                    i == a || i == b || i == k || (q.u - ox).powi(2) + (q.v - oy).powi(2) >= rr
                });
                if empty && best.is_none_or(|(r0, _)| rr < r0) {
                    let z = bary[0] * pa.z + bary[1] * pb.z + bary[2] * pc.z;
                    best = Some((rr, z));
                }
            }
        }
    }
    best.map_or(f64::NAN, |(_, z)| z)
}

/// Barycentric weights of (u, v) in triangle abc, or None when outside or flat.
fn barycentric(a: Point, b: Point, c: Point, u: f64, v: f64) -> Option<[f64; 3]> {
    let det = (b.v - c.v) * (a.u - c.u) + (c.u - b.u) * (a.v - c.v);
    if det.abs() < 1e-12 {
        return None;
    }
    let l1 = ((b.v - c.v) * (u - c.u) + (c.u - b.u) * (v - c.v)) / det;
    let l2 = ((c.v - a.v) * (u - c.u) + (a.u - c.u) * (v - c.v)) / det;
    let l3 = 1.0 - l1 - l2;
    (l1 >= 0.0 && l2 >= 0.0 && l3 >= 0.0).then_some([l1, l2, l3])
}

/// Centre and squared radius of the circle through a, b, c.
fn circumcircle(a: Point, b: Point, c: Point) -> Option<(f64, f64, f64)> {
    let d = 2.0 * (a.u * (b.v - c.v) + b.u * (c.v - a.v) + c.u * (a.v - b.v));
    if d.abs() < 1e-12 {
        return None;
    }
    let (a2, b2, c2) = (
        a.u * a.u + a.v * a.v,
        b.u * b.u + b.v * b.v,
        c.u * c.u + c.v * c.v,
    );
    let ox = (a2 * (b.v - c.v) + b2 * (c.v - a.v) + c2 * (a.v - b.v)) / d;
    let oy = (a2 * (c.u - b.u) + b2 * (a.u - c.u) + c2 * (b.u - a.u)) / d;
    Some((ox, oy, (a.u - ox).powi(2) + (a.v - oy).powi(2)))
}

/// 5 x 5 Gaussian (sigma 1 px) over the valid pixels of a (w x h) window,
/// returning its interior ((w - 4) x (h - 4)); no-data stays no-data.
fn gaussian_5x5(values: &[f64], w: i64, h: i64) -> Vec<f64> {
    let k: [f64; 5] = [-2.0f64, -1.0, 0.0, 1.0, 2.0].map(|d| (-0.5 * d * d).exp());
    let mut out = Vec::with_capacity(((w - 4) * (h - 4)) as usize);
    for r in 2..h - 2 {
        for c in 2..w - 2 {
            if values[(r * w + c) as usize].is_nan() {
                out.push(f64::NAN);
                continue;
            }
            let (mut sw, mut swz) = (0.0, 0.0);
            for (dj, kj) in k.iter().enumerate() {
                for (di, ki) in k.iter().enumerate() {
                    let z = values[((r + dj as i64 - 2) * w + c + di as i64 - 2) as usize];
                    if z.is_finite() {
                        sw += ki * kj;
                        swz += ki * kj * z;
                    }
                }
            }
            out.push(swz / sw);
        }
    }
    out
}

#[cfg(test)]
mod tests;
