//! The tile cutter: overlapping DSM tiles of the synthetic world in a `chain`
//! (1 x N) or `grid` (rows x cols) layout, each seen through a known rigid
//! perturbation and with its own noise, outliers, voids and changed buildings.
//!
//! Frames. `m_world` (truth.json's `matrix_world`) maps a point of the written,
//! perturbed tile, in CRS coordinates (x', y', h'), to its true position:
//! p = M p'. The tile therefore shows the world moved by M^-1. For the pixel
//! centre (x', y') the written height h' is the one that puts M (x', y', h') on
//! the true surface S:
//!
//! ```text
//!   (x, y, z) = M (x', y', h'),   z = S(x, y)
//!   => h' = (S(x, y) - m20 x' - m21 y' - m23) / m22
//! ```
//!
//! x and y depend on h' only through m02 and m12 (rotations of hundredths of a
//! degree, ~1e-4), so fixed-point iteration from h' = S(x', y') contracts by that
//! factor and converges in two or three steps (except exactly at building walls,
//! where the two candidate heights are a few centimetres apart horizontally).
//! M rotates about the tile centre at the surface's base elevation:
//! M = T(c + shift) R T(-c), R = Rz(yaw) Ry(pitch) Rx(roll).

use nalgebra::{Matrix4, Rotation3, Translation3, Vector3};
use serde::{Deserialize, Serialize};

use super::render::{render_points, Rendering};
use super::surface::{Sampler, Surface};
use crate::geo::GeoTransform;
use crate::rng::{derive_seed, hash2, unit_f64, SplitMix64};

/// Void patches are discs centred in cells of this many pixels.
const VOID_CELL_PX: i64 = 32;

/// Arrangement of the tiles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// One row of `cols` tiles along x.
    Chain,
    /// `rows` x `cols` tiles.
    Grid,
}

/// Everything that defines a tile set besides the surface.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TileSetParams {
    pub layout: Layout,
    pub rows: u32,
    pub cols: u32,
    pub size_px: u32,
    pub gsd_m: f64,
    /// Fraction of a tile's width shared with its neighbour (0.6 = 60 %).
    pub overlap: f64,
    /// Top-left corner of tile_00 in CRS metres.
    pub origin_x_m: f64,
    pub origin_y_m: f64,
    pub epsg: u32,
    pub seed: u64,
    pub noise_sigma_m: f64,
    /// Fraction of pixels replaced by spikes of +-5..40 m.
    pub outlier_fraction: f64,
    /// Fraction of 32 x 32 px cells holding a void disc (radius 2-14 px).
    pub void_fraction: f64,
    pub max_shift_xy_m: f64,
    pub max_shift_z_m: f64,
    pub max_rot_deg: f64,
    /// Changed buildings appear in some tiles and not others.
    pub changes: bool,
    /// Leave tile_00 unperturbed (identity matrix_world).
    pub anchor_first: bool,
    /// How pixels are made from the world (see [`super::render`]).
    #[serde(default)]
    pub rendering: Rendering,
    /// Mean points per pixel of the point renderings (0: the rendering's default).
    #[serde(default)]
    pub points_per_px: f64,
    /// A vertical datum offset added to the z shift of every tile whose
    /// (row + col) is odd, so that neighbours differ by it (metres).
    #[serde(default)]
    pub dz_offset_m: f64,
    /// Every tile whose (row + col) is odd is written at this many times the
    /// pixel over the same footprint (`size_px` / factor pixels a side): a
    /// collection that mixes resolutions, as a 1 m lidar DSM beside 0.5 m
    /// stereo ones. 1: one pixel for all.
    #[serde(default = "one")]
    pub odd_gsd_factor: u32,
}

fn one() -> u32 {
    1
}

impl Default for TileSetParams {
    fn default() -> Self {
        TileSetParams {
            layout: Layout::Chain,
            rows: 1,
            cols: 4,
            size_px: 256,
            gsd_m: 0.5,
            overlap: 0.6,
            origin_x_m: 500_000.0,
            origin_y_m: 4_800_000.0,
            epsg: 32617,
            seed: 1,
            noise_sigma_m: 0.3,
            outlier_fraction: 0.02,
            void_fraction: 0.03,
            max_shift_xy_m: 3.0,
            max_shift_z_m: 2.0,
            max_rot_deg: 0.03,
            changes: true,
            anchor_first: false,
            rendering: Rendering::Centre,
            points_per_px: 0.0,
            dz_offset_m: 0.0,
            odd_gsd_factor: 1,
        }
    }
}

/// Per-pixel degradations of a rendered tile.
#[derive(Clone, Copy, Debug)]
pub struct PixelEffects {
    pub noise_sigma_m: f64,
    pub outlier_fraction: f64,
    pub void_fraction: f64,
    /// Show the changed buildings of this tile's epoch.
    pub changes: bool,
    /// How pixels are made from the world; noise is per point for the point renderings.
    pub rendering: Rendering,
    /// Mean points per pixel of the point renderings (0: the rendering's default).
    pub points_per_px: f64,
}

impl PixelEffects {
    /// No noise, outliers, voids or changes: the true surface (moved by M^-1).
    pub fn none() -> Self {
        PixelEffects {
            noise_sigma_m: 0.0,
            outlier_fraction: 0.0,
            void_fraction: 0.0,
            changes: false,
            rendering: Rendering::Centre,
            points_per_px: 0.0,
        }
    }

    pub fn from_params(p: &TileSetParams) -> Self {
        PixelEffects {
            noise_sigma_m: p.noise_sigma_m,
            outlier_fraction: p.outlier_fraction,
            void_fraction: p.void_fraction,
            changes: p.changes,
            rendering: p.rendering,
            points_per_px: p.points_per_px,
        }
    }
}

/// One tile to render: its grid, its perturbation and its random seed.
#[derive(Clone, Debug)]
pub struct TileSpec {
    pub id: String,
    pub index: usize,
    pub width: u64,
    pub height: u64,
    pub geotransform: GeoTransform,
    /// Maps a written point (x', y', h') to its true position (CRS metres).
    pub m_world: Matrix4<f64>,
    /// Seed of the tile's noise, voids and epoch (changed buildings).
    pub seed: u64,
    pub shift_m: [f64; 3],
    pub rot_deg: [f64; 3],
}

impl TileSpec {
    /// An unperturbed raster (m_world = identity), e.g. one big DSM.
    pub fn unperturbed(id: &str, width: u64, height: u64, gt: GeoTransform, seed: u64) -> Self {
        TileSpec {
            id: id.to_string(),
            index: 0,
            width,
            height,
            geotransform: gt,
            m_world: Matrix4::identity(),
            seed,
            shift_m: [0.0; 3],
            rot_deg: [0.0; 3],
        }
    }
}

/// The tiles of a set, row-major, with their perturbations drawn from the seed.
pub fn plan_tiles(p: &TileSetParams, pivot_z_m: f64) -> Vec<TileSpec> {
    let step_px = ((p.size_px as f64) * (1.0 - p.overlap)).round().max(1.0);
    let step_m = step_px * p.gsd_m;
    let side_m = p.size_px as f64 * p.gsd_m;
    let mut tiles = Vec::new();
    for r in 0..p.rows {
        for c in 0..p.cols {
            let index = (r * p.cols + c) as usize;
            let (x0, y0) = (
                p.origin_x_m + c as f64 * step_m,
                p.origin_y_m - r as f64 * step_m,
            );
            let (mut shift_m, rot_deg) = draw_perturbation(
                derive_seed(p.seed, 1000 + index as u64),
                [p.max_shift_xy_m, p.max_shift_z_m, p.max_rot_deg],
                p.anchor_first && index == 0,
            );
            let odd = (r + c) % 2 == 1;
            if odd {
                shift_m[2] += p.dz_offset_m;
            }
            let factor = if odd { p.odd_gsd_factor.max(1) } else { 1 };
            let (side_px, gsd_m) = (p.size_px / factor, p.gsd_m * factor as f64);
            let centre = Vector3::new(x0 + side_m / 2.0, y0 - side_m / 2.0, pivot_z_m);
            tiles.push(TileSpec {
                id: format!("tile_{index:02}"),
                index,
                width: side_px as u64,
                height: side_px as u64,
                geotransform: GeoTransform::north_up(x0, y0, gsd_m, gsd_m),
                m_world: rigid_about(centre, shift_m, rot_deg),
                seed: derive_seed(p.seed, 2000 + index as u64),
                shift_m,
                rot_deg,
            });
        }
    }
    tiles
}

/// A tile's random rigid perturbation: shifts uniform in +-max_xy, +-max_z,
/// rotations uniform in +-max_rot_deg per axis; none for an anchored tile.
pub fn draw_perturbation(
    seed: u64,
    [max_xy_m, max_z_m, max_rot_deg]: [f64; 3],
    anchored: bool,
) -> ([f64; 3], [f64; 3]) {
    if anchored {
        return ([0.0; 3], [0.0; 3]);
    }
    let mut rng = SplitMix64::new(seed);
    let mut sym = |max: f64| rng.range(-max, max);
    let shift_m = [sym(max_xy_m), sym(max_xy_m), sym(max_z_m)];
    let rot_deg = [sym(max_rot_deg), sym(max_rot_deg), sym(max_rot_deg)];
    (shift_m, rot_deg)
}

/// T(c + shift) R T(-c) with R = Rz(yaw) Ry(pitch) Rx(roll), angles in degrees.
pub fn rigid_about(centre: Vector3<f64>, shift_m: [f64; 3], rot_deg: [f64; 3]) -> Matrix4<f64> {
    let [roll, pitch, yaw] = rot_deg.map(f64::to_radians);
    let r = Rotation3::from_euler_angles(roll, pitch, yaw).to_homogeneous();
    let shift = Vector3::from(shift_m);
    Translation3::from(centre + shift).to_homogeneous()
        * r
        * Translation3::from(-centre).to_homogeneous()
}

/// Written height h' at the written pixel centre (x', y'): solves
/// M (x', y', h') = (x, y, S(x, y)) by fixed-point iteration (module doc).
pub fn written_height(
    sampler: &mut Sampler<'_>,
    m: &Matrix4<f64>,
    epoch: Option<u64>,
    xw: f64,
    yw: f64,
) -> f64 {
    solve_written_height(m, xw, yw, |x, y| match epoch {
        Some(e) => sampler.height_in_epoch(x, y, e),
        None => sampler.true_height(x, y),
    })
}

/// The fixed-point solve of [`written_height`] over any true surface
/// `surface(x, y)` (NaN = no data): the h' with M (x', y', h') on the surface,
/// or NaN when the iteration steps onto no data.
pub fn solve_written_height(
    m: &Matrix4<f64>,
    xw: f64,
    yw: f64,
    mut surface: impl FnMut(f64, f64) -> f64,
) -> f64 {
    let mut h = surface(xw, yw);
    if m.is_identity(0.0) {
        return h;
    }
    if h.is_nan() {
        h = 0.0;
    }
    for _ in 0..5 {
        let x = m[(0, 0)] * xw + m[(0, 1)] * yw + m[(0, 2)] * h + m[(0, 3)];
        let y = m[(1, 0)] * xw + m[(1, 1)] * yw + m[(1, 2)] * h + m[(1, 3)];
        let s = surface(x, y);
        if s.is_nan() {
            return f64::NAN;
        }
        let next = (s - m[(2, 0)] * xw - m[(2, 1)] * yw - m[(2, 3)]) / m[(2, 2)];
        let done = (next - h).abs() < 1e-6;
        h = next;
        if done {
            break;
        }
    }
    h
}

/// Render pixels [col0, col0 + w) x [row0, row0 + h) of a tile, row-major;
/// pixels outside the tile are NaN. Deterministic per pixel, whatever the window.
pub fn render_window(
    surface: &Surface,
    spec: &TileSpec,
    fx: &PixelEffects,
    col0: u64,
    row0: u64,
    w: u64,
    h: u64,
) -> Vec<f32> {
    if fx.rendering != Rendering::Centre {
        return render_window_points(surface, spec, fx, col0, row0, w, h);
    }
    let mut sampler = surface.sampler();
    let epoch = fx.changes.then_some(spec.seed);
    let void_seed = derive_seed(spec.seed, 1);
    let noise_seed = derive_seed(spec.seed, 2);
    let mut out = Vec::with_capacity((w * h) as usize);
    for row in row0..row0 + h {
        for col in col0..col0 + w {
            if col >= spec.width || row >= spec.height {
                out.push(f32::NAN);
                continue;
            }
            if fx.void_fraction > 0.0
                && in_void(void_seed, fx.void_fraction, col as i64, row as i64)
            {
                out.push(f32::NAN);
                continue;
            }
            let (xw, yw) = spec
                .geotransform
                .pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
            let mut z = written_height(&mut sampler, &spec.m_world, epoch, xw, yw);
            if fx.noise_sigma_m > 0.0 || fx.outlier_fraction > 0.0 {
                let mut rng = SplitMix64::new(hash2(noise_seed, col as i64, row as i64));
                z += fx.noise_sigma_m * rng.normal();
                if rng.chance(fx.outlier_fraction) {
                    let sign = if rng.chance(0.5) { 1.0 } else { -1.0 };
                    z += sign * rng.range(5.0, 40.0);
                }
            }
            out.push(z as f32);
        }
    }
    out
}

/// [`render_window`] for the point renderings: the gridded points, then the
/// tile's voids and per-pixel outliers (noise is already per point).
fn render_window_points(
    surface: &Surface,
    spec: &TileSpec,
    fx: &PixelEffects,
    col0: u64,
    row0: u64,
    w: u64,
    h: u64,
) -> Vec<f32> {
    let epoch = fx.changes.then_some(spec.seed);
    let heights = render_points(
        surface,
        spec,
        fx.rendering,
        fx.points_per_px,
        fx.noise_sigma_m,
        epoch,
        [col0 as i64, row0 as i64, w as i64, h as i64],
    );
    let void_seed = derive_seed(spec.seed, 1);
    let outlier_seed = derive_seed(spec.seed, 3);
    let mut out = Vec::with_capacity((w * h) as usize);
    for (k, z) in heights.into_iter().enumerate() {
        let (col, row) = (col0 + k as u64 % w, row0 + k as u64 / w);
        if col >= spec.width
            || row >= spec.height
            || (fx.void_fraction > 0.0
                && in_void(void_seed, fx.void_fraction, col as i64, row as i64))
        {
            out.push(f32::NAN);
            continue;
        }
        let mut z = z;
        if fx.outlier_fraction > 0.0 {
            let mut rng = SplitMix64::new(hash2(outlier_seed, col as i64, row as i64));
            if rng.chance(fx.outlier_fraction) {
                let sign = if rng.chance(0.5) { 1.0 } else { -1.0 };
                z += sign * rng.range(5.0, 40.0);
            }
        }
        out.push(z as f32);
    }
    out
}

/// True when pixel (col, row) falls in one of the tile's void discs.
fn in_void(seed: u64, fraction: f64, col: i64, row: i64) -> bool {
    let (ci, cj) = (col.div_euclid(VOID_CELL_PX), row.div_euclid(VOID_CELL_PX));
    for dj in -1..=1 {
        for di in -1..=1 {
            let (i, j) = (ci + di, cj + dj);
            let h = hash2(seed, i, j);
            if unit_f64(h) >= fraction {
                continue;
            }
            let mut rng = SplitMix64::new(h);
            let cx = (i * VOID_CELL_PX) as f64 + rng.range(0.0, VOID_CELL_PX as f64);
            let cy = (j * VOID_CELL_PX) as f64 + rng.range(0.0, VOID_CELL_PX as f64);
            let r = rng.range(2.0, 14.0);
            if (col as f64 + 0.5 - cx).powi(2) + (row as f64 + 0.5 - cy).powi(2) < r * r {
                return true;
            }
        }
    }
    false
}

#[cfg(test)]
mod tests;
