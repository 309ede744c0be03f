//! The corrected surface of one DSM: its height at a horizontal location (x, y)
//! once its pose M is applied to every point (x', y', h(x', y')) of the DSM.
//! Shared by `fuse` (the mosaic) and `eval` (height differences), so both
//! measure the same surface.
//!
//! M moves points horizontally as well as vertically, so the DSM pixel that lands
//! on (x, y) is found by a fixed-point iteration: start from z0 (the DSM's mean
//! height), take (x', y') = (M^-1 (x, y, z))_xy, read h' = h(x', y') (bilinear,
//! only where every neighbour with non-zero weight is valid; never across
//! no-data), then z = (M (x', y', h'))_z. The tilt of a DSM pose is a few
//! 1e-4 rad, so each iteration shrinks the error by that factor times the
//! surface slope; [`FIXED_POINT_ITERATIONS`] = 2 leaves far below a millimetre.

use nalgebra::Matrix4;

use crate::geo::GeoTransform;
use crate::grid::Grid;

/// Fixed-point iterations of [`CorrectedSurface::height_at`].
pub const FIXED_POINT_ITERATIONS: usize = 2;

/// Fractions of a pixel closer than this to a pixel centre snap onto it, so an
/// identity pose on the DSM's own lattice reads pixels exactly (no neighbour needed).
const SNAP_PX: f64 = 1e-6;

/// A rigid pose as two 3x4 row-major blocks (forward and inverse), in world coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseXf {
    fwd: [[f64; 4]; 3],
    inv: [[f64; 4]; 3],
}

impl PoseXf {
    pub fn identity() -> PoseXf {
        PoseXf::new(&Matrix4::identity())
    }

    /// From a rigid `matrix_world` (its inverse is [R^T, -R^T t]).
    pub fn new(m_world: &Matrix4<f64>) -> PoseXf {
        let inv = crate::poses::inverse_rigid(m_world);
        let rows = |m: &Matrix4<f64>| {
            let mut out = [[0.0; 4]; 3];
            for (r, row) in out.iter_mut().enumerate() {
                for (c, v) in row.iter_mut().enumerate() {
                    *v = m[(r, c)];
                }
            }
            out
        };
        PoseXf {
            fwd: rows(m_world),
            inv: rows(&inv),
        }
    }

    /// M p.
    #[inline]
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        mul(&self.fwd, p)
    }

    /// M^-1 p.
    #[inline]
    pub fn apply_inverse(&self, p: [f64; 3]) -> [f64; 3] {
        mul(&self.inv, p)
    }

    /// Axis-aligned bounds of the box `bounds` x [z_min, z_max] after the pose.
    pub fn map_bounds(&self, bounds: [f64; 4], z_range_m: [f64; 2]) -> [f64; 4] {
        let mut out = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for x in [bounds[0], bounds[2]] {
            for y in [bounds[1], bounds[3]] {
                for z in z_range_m {
                    let p = self.apply([x, y, z]);
                    out = [
                        out[0].min(p[0]),
                        out[1].min(p[1]),
                        out[2].max(p[0]),
                        out[3].max(p[1]),
                    ];
                }
            }
        }
        out
    }
}

#[inline]
fn mul(m: &[[f64; 4]; 3], p: [f64; 3]) -> [f64; 3] {
    let row = |r: &[f64; 4]| r[0] * p[0] + r[1] * p[1] + r[2] * p[2] + r[3];
    [row(&m[0]), row(&m[1]), row(&m[2])]
}

/// One DSM level seen through its pose: [`height_at`](Self::height_at) gives the
/// corrected surface height at a world (x, y).
pub struct CorrectedSurface<'p, G: Grid> {
    grid: G,
    pose: &'p PoseXf,
    /// Start height of the fixed-point iteration (the DSM's mean height).
    z_start_m: f64,
    origin_x: f64,
    origin_y: f64,
    px_per_m_x: f64,
    px_per_m_y: f64,
}

impl<'p, G: Grid> CorrectedSurface<'p, G> {
    /// `grid` must be north-up (every store level is).
    pub fn new(grid: G, pose: &'p PoseXf, z_start_m: f64) -> Self {
        let g = grid.geotransform().0;
        CorrectedSurface {
            grid,
            pose,
            z_start_m,
            origin_x: g[0],
            origin_y: g[3],
            px_per_m_x: 1.0 / g[1],
            px_per_m_y: 1.0 / g[5],
        }
    }

    /// The corrected surface height at world (x, y); NaN where the DSM has no
    /// valid data around the pixel that lands there.
    #[inline]
    pub fn height_at(&mut self, x: f64, y: f64) -> f64 {
        let mut z = self.z_start_m;
        for _ in 0..FIXED_POINT_ITERATIONS {
            let p = self.pose.apply_inverse([x, y, z]);
            let h = self.bilinear(p[0], p[1]);
            if h.is_nan() {
                return f64::NAN;
            }
            z = self.pose.apply([p[0], p[1], h])[2];
        }
        z
    }

    /// Raw (uncorrected) height at world (x, y), bilinear, NaN across no-data.
    #[inline]
    pub fn bilinear(&mut self, x: f64, y: f64) -> f64 {
        let c = (x - self.origin_x) * self.px_per_m_x - 0.5;
        let r = (y - self.origin_y) * self.px_per_m_y - 0.5;
        bilinear_px(&mut self.grid, c, r)
    }

    /// The underlying grid (for [`Grid::take_error`]).
    pub fn grid_mut(&mut self) -> &mut G {
        &mut self.grid
    }

    pub fn geotransform(&self) -> GeoTransform {
        self.grid.geotransform()
    }
}

/// Split a continuous pixel-centre coordinate into (index, fraction), snapping
/// fractions within [`SNAP_PX`] of a centre onto it.
#[inline]
fn split(v: f64) -> (i64, f64) {
    let f0 = v.floor();
    let frac = v - f0;
    if frac < SNAP_PX {
        (f0 as i64, 0.0)
    } else if frac > 1.0 - SNAP_PX {
        (f0 as i64 + 1, 0.0)
    } else {
        (f0 as i64, frac)
    }
}

/// Bilinear height at continuous pixel-centre coordinates (c, r) (pixel (0, 0)'s
/// centre is (0, 0)); NaN when any neighbour with non-zero weight is no-data.
#[inline]
pub fn bilinear_px<G: Grid>(grid: &mut G, c: f64, r: f64) -> f64 {
    if !(c.is_finite() && r.is_finite()) {
        return f64::NAN;
    }
    let (c0, fx) = split(c);
    let (r0, fy) = split(r);
    let v00 = grid.get(c0, r0) as f64;
    if fx == 0.0 && fy == 0.0 {
        return v00;
    }
    if fy == 0.0 {
        let v10 = grid.get(c0 + 1, r0) as f64;
        return v00 + (v10 - v00) * fx;
    }
    let v01 = grid.get(c0, r0 + 1) as f64;
    if fx == 0.0 {
        return v00 + (v01 - v00) * fy;
    }
    let v10 = grid.get(c0 + 1, r0) as f64;
    let v11 = grid.get(c0 + 1, r0 + 1) as f64;
    let top = v00 + (v10 - v00) * fx;
    let bottom = v01 + (v11 - v01) * fx;
    top + (bottom - top) * fy
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::MemGrid;
    use crate::poses::rigid::{from_parts, rotation_from_axis_angle};
    use nalgebra::Vector3;

    fn plane_grid() -> MemGrid {
        // z = 200 + 0.3 x_local - 0.2 y_local, 0.5 m pixels, far from the origin like UTM
        let gt = GeoTransform::north_up(500_000.0, 4_800_000.0, 0.5, 0.5);
        MemGrid::from_fn(64, 64, gt, |c, r| {
            let (x, y) = gt.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            (200.0 + 0.3 * (x - 500_000.0) - 0.2 * (y - 4_800_000.0)) as f32
        })
    }

    #[test]
    fn identity_reads_pixels_exactly_and_interpolates_between() {
        let g = plane_grid();
        let pose = PoseXf::identity();
        let mut s = CorrectedSurface::new(g.clone(), &pose, 0.0);
        let (x, y) = g.geotransform.pixel_to_world(10.5, 20.5);
        assert_eq!(s.height_at(x, y), g.data[20 * 64 + 10] as f64);
        let (x, y) = g.geotransform.pixel_to_world(11.0, 20.5); // half way between centres
        let want = (g.data[20 * 64 + 10] as f64 + g.data[20 * 64 + 11] as f64) / 2.0;
        assert!((s.height_at(x, y) - want).abs() < 1e-4);
    }

    #[test]
    fn no_interpolation_across_no_data() {
        let mut g = plane_grid();
        g.data[20 * 64 + 11] = f32::NAN;
        let pose = PoseXf::identity();
        let mut s = CorrectedSurface::new(g.clone(), &pose, 0.0);
        let at = |s: &mut CorrectedSurface<MemGrid>, c: f64, r: f64| {
            let (x, y) = g.geotransform.pixel_to_world(c, r);
            s.height_at(x, y)
        };
        assert!(at(&mut s, 10.75, 20.5).is_nan());
        assert!(at(&mut s, 10.75, 19.75).is_nan());
        assert!(!at(&mut s, 10.5, 20.5).is_nan()); // the valid pixel itself
        assert!(!at(&mut s, 9.75, 20.5).is_nan()); // left of it: neighbours valid
        assert!(at(&mut s, -1.0, 5.0).is_nan()); // outside
    }

    #[test]
    fn tilted_pose_gives_the_rotated_plane() {
        let g = plane_grid();
        // rotation of 0.05 deg about a tilted axis, about a point near the data, plus a shift
        let r = rotation_from_axis_angle(
            &(Vector3::new(0.6, -0.8, 0.3).normalize() * 0.05f64.to_radians()),
        );
        let centre = Vector3::new(500_016.0, 4_799_984.0, 200.0);
        let t = centre - r * centre + Vector3::new(1.3, -0.7, 0.9);
        let m = from_parts(&r, &t);
        let pose = PoseXf::new(&m);
        let mut s = CorrectedSurface::new(g, &pose, 150.0);
        // the corrected plane: normal R n through M p0
        let n = r * Vector3::new(-0.3, 0.2, 1.0);
        let p0 = r * Vector3::new(500_000.0, 4_800_000.0, 200.0) + t;
        for (x, y) in [(500_010.2, 4_799_990.1), (500_020.0, 4_799_975.3)] {
            let want = p0.z - (n.x * (x - p0.x) + n.y * (y - p0.y)) / n.z;
            let got = s.height_at(x, y);
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        }
    }

    #[test]
    fn pose_round_trip_and_bounds() {
        let r = rotation_from_axis_angle(&Vector3::new(0.0, 0.0, 0.01));
        let m = from_parts(&r, &Vector3::new(5.0, -3.0, 2.0));
        let pose = PoseXf::new(&m);
        let p = [500_123.0, 4_800_456.0, 231.0];
        let q = pose.apply_inverse(pose.apply(p));
        assert!((0..3).all(|k| (q[k] - p[k]).abs() < 1e-6));
        let b = PoseXf::identity().map_bounds([0.0, 1.0, 2.0, 3.0], [5.0, 9.0]);
        assert_eq!(b, [0.0, 1.0, 2.0, 3.0]);
    }
}
