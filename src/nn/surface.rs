//! The reference surface right below a query: bilinear height, tangent plane
//! from a ring of pixels (memoised per query while it stays over one pixel), and
//! the grid normal at a pixel for point-to-plane.

use nalgebra::Vector3;

use super::frame::floor_i64;
use super::plane::{plane_fit, Plane};
use super::planes::PlaneTable;
use super::PixelFrame;
use crate::grid::Grid;

/// A point of the reference surface with its tangent plane.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    pub point: Vector3<f64>,
    pub normal: Vector3<f64>,
    /// RMS deviation of the neighbourhood from the fitted plane (walls, crowns).
    pub roughness_m: f64,
    /// How far the bilinear height may be from the true one: the variance,
    /// over the four pixels with their bilinear weights, of their departures
    /// from the ring's plane. Where the cell holds a step (a wall whose
    /// position within the cell its pixels do not tell), the true height under
    /// the query is one side or the other, and this is the variance of that
    /// guess (h^2 f (1 - f) for a step of h at fraction f); on a smooth slope
    /// it is the pixel noise's share, whatever the slope.
    pub cell_var_m2: f64,
    /// Largest distance of one of those departures from their weighted mean:
    /// the band of residuals a query height consistent with the cell can have.
    pub cell_band_m: f64,
    /// Variance of each horizontal component of `normal` that is noise of
    /// the ring's heights (see [`crate::fit::Correspondence::normal_var`]).
    pub normal_var: f64,
}

/// The reference surface right below a query: the bilinear height of the four
/// surrounding pixel centres, at the query's own (x, y), and a normal fitted on a
/// ring of pixels around them that excludes those four. With no horizontal
/// offset between query and surface point, and normal noise independent of the
/// height noise, the plane residual is unbiased even on noisy DSMs (a 3D nearest
/// neighbour picked among noisy pixels, or a normal sharing their noise, is
/// not). None when any of the four is no-data: never interpolate across holes.
pub fn surface_below<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    query: &Vector3<f64>,
) -> Option<SurfacePoint> {
    surface_below_memo(grid, frame, query, &mut PlaneMemo::default(), None)
}

/// The ring plane last fitted for one query, reused while the query stays over
/// the same reference pixel (ICP's late iterations move queries by millimetres,
/// so most of them do); valid for one grid only.
#[derive(Clone, Copy, Debug)]
pub struct PlaneMemo {
    pixel: (i64, i64),
    plane: Option<Plane>,
}

impl Default for PlaneMemo {
    fn default() -> Self {
        PlaneMemo {
            pixel: (i64::MIN, i64::MIN),
            plane: None,
        }
    }
}

/// `surface_below`, reusing the ring plane kept in `memo` when the query is
/// over the same pixel as last time, else the one `table` keeps for that
/// pixel of this grid (same result, fewer fits).
pub fn surface_below_memo<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    query: &Vector3<f64>,
    memo: &mut PlaneMemo,
    table: Option<&PlaneTable>,
) -> Option<SurfacePoint> {
    let (col_f, row_f) = frame.to_pixel(query);
    let (u, v) = (col_f - 0.5, row_f - 0.5);
    let (c0, r0) = (floor_i64(u), floor_i64(v));
    let (fx, fy) = (u - c0 as f64, v - r0 as f64);
    let h00 = grid.get(c0, r0) as f64;
    let h10 = grid.get(c0 + 1, r0) as f64;
    let h01 = grid.get(c0, r0 + 1) as f64;
    let h11 = grid.get(c0 + 1, r0 + 1) as f64;
    if h00.is_nan() || h10.is_nan() || h01.is_nan() || h11.is_nan() {
        return None;
    }
    let h = h00 * (1.0 - fx) * (1.0 - fy)
        + h10 * fx * (1.0 - fy)
        + h01 * (1.0 - fx) * fy
        + h11 * fx * fy;
    let point = Vector3::new(query.x, query.y, h - frame.z_origin_m());
    let (col, row) = (floor_i64(col_f), floor_i64(row_f));
    if memo.pixel != (col, row) {
        let mut fit = || plane_fit(grid, frame, col, row, 2);
        let plane = match table {
            Some(t) => t.plane_or(col, row, fit),
            None => fit(),
        };
        *memo = PlaneMemo {
            pixel: (col, row),
            plane,
        };
    }
    let plane = memo.plane?;
    // The four interpolated pixels must lie on the ring's plane: a spike or a
    // wall among them makes the bilinear height meaningless.
    let limit_m = (4.0 * plane.rms_m).max(0.5);
    let pixels = [
        (c0, r0, h00, (1.0 - fx) * (1.0 - fy)),
        (c0 + 1, r0, h10, fx * (1.0 - fy)),
        (c0, r0 + 1, h01, (1.0 - fx) * fy),
        (c0 + 1, r0 + 1, h11, fx * fy),
    ];
    let mut departure_m = [0.0f64; 4];
    for (k, &(c, r, hv, _)) in pixels.iter().enumerate() {
        let dx = (c - col) as f64 * frame.gsd_x_m();
        let dy = -((r - row) as f64) * frame.gsd_y_m();
        departure_m[k] = hv - plane.height_at(dx, dy);
        if departure_m[k].abs() > limit_m {
            return None;
        }
    }
    let (cell_var_m2, cell_band_m) = cell_spread(&pixels.map(|p| p.3), &departure_m);
    Some(SurfacePoint {
        point,
        normal: plane.normal(),
        roughness_m: plane.rms_m,
        cell_var_m2,
        cell_band_m,
        normal_var: plane.slope_var / (1.0 + plane.a * plane.a + plane.b * plane.b),
    })
}

/// The variance and the band of [`SurfacePoint`] from the four pixels'
/// bilinear weights and their departures from the ring plane.
fn cell_spread(weights: &[f64; 4], departure_m: &[f64; 4]) -> (f64, f64) {
    let mean: f64 = weights.iter().zip(departure_m).map(|(w, d)| w * d).sum();
    let (mut var, mut band) = (0.0f64, 0.0f64);
    for (w, d) in weights.iter().zip(departure_m) {
        var += w * (d - mean).powi(2);
        band = band.max((d - mean).abs());
    }
    (var, band)
}

/// Pixel radius of the plane fitted for normals: a 7 x 7 window keeps the
/// slope noise (sigma / (gsd * 14)) well below real slopes, so the fit is not
/// diluted by noisy normals.
pub const NORMAL_RADIUS_PX: i64 = 3;
const _: () = assert!((2 * NORMAL_RADIUS_PX + 1).pow(2) <= 49);

/// Unit surface normal at a reference pixel from a least-squares plane over its
/// (2r+1)^2 neighbourhood (valid pixels only); vertical when too few neighbours.
pub fn normal_at<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    col: i64,
    row: i64,
) -> Vector3<f64> {
    plane_fit(grid, frame, col, row, 1).map_or(Vector3::z(), |p| p.normal())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::GeoTransform;
    use crate::grid::MemGrid;

    #[test]
    fn normal_of_a_slope() {
        let gt = GeoTransform::north_up(0.0, 10.0, 0.5, 0.5);
        // z = 0.2 x  (x grows with col)
        let mut grid = MemGrid::from_fn(10, 10, gt, |c, _| 0.2 * 0.5 * c as f32);
        let frame = PixelFrame::new(&gt, &Vector3::zeros());
        let n = normal_at(&mut grid, &frame, 4, 4);
        let expected = Vector3::new(-0.2, 0.0, 1.0).normalize();
        assert!((n - expected).norm() < 1e-6, "{n:?}");
        // z = 0.3 y: y decreases with row
        let mut grid = MemGrid::from_fn(10, 10, gt, |_, r| -0.3 * 0.5 * r as f32);
        let n = normal_at(&mut grid, &frame, 4, 4);
        let expected = Vector3::new(0.0, -0.3, 1.0).normalize();
        assert!((n - expected).norm() < 1e-6, "{n:?}");
    }

    /// A wall through the cell: the guess is one side or the other (variance
    /// h^2 f (1 - f), band h max(f, 1 - f)); a plane, however steep, leaves
    /// no departures and nothing to guess.
    #[test]
    fn a_step_in_the_cell_is_a_guess_a_slope_is_not() {
        let f: f64 = 0.2;
        // query at fraction f across the cell; the two right pixels are 3 m up
        let weights = [(1.0 - f) * 0.5, f * 0.5, (1.0 - f) * 0.5, f * 0.5];
        let (var, band) = cell_spread(&weights, &[0.0, 3.0, 0.0, 3.0]);
        assert!((var - 9.0 * f * (1.0 - f)).abs() < 1e-12, "{var}");
        assert!((band - 3.0 * (1.0 - f)).abs() < 1e-12, "{band}");
        // the same heights on the ring's plane (a steep slope): no departures
        assert_eq!(cell_spread(&weights, &[0.0; 4]), (0.0, 0.0));
        // a constant offset from the plane is no guess either
        let (var, band) = cell_spread(&weights, &[0.4; 4]);
        assert!(var < 1e-24 && band < 1e-12);
    }
}
