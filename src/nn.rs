//! Exact nearest-neighbour search on a DSM grid (the paper's bound, made exact
//! and early-terminating).
//!
//! A DSM is a height field: the reference points are the pixel centres
//! (x_c, y_r, h_cr). For a query q, the pixel right below it gives a distance d
//! that bounds the true nearest neighbour, so only pixels within d horizontally
//! can be nearer (Xu & Qin 2024, Sec. 3.1). We visit square rings around that
//! pixel outward and stop as soon as the nearest possible point of the next ring
//! is farther than the best distance found, which is usually ring 1 or 2. A
//! no-data pixel below the query gives no bound; the rings then run until a valid
//! pixel bounds them or the radius cap (`max_radius_m`) is reached. The result is
//! exactly the brute-force nearest neighbour within the cap.

use nalgebra::Vector3;

use crate::grid::Grid;
use crate::raster::GeoTransform;

/// Maps local-frame metric coordinates to the pixel lattice of one grid level.
/// The local frame is the world frame shifted by `origin` (UTM coordinates are
/// ~10^6 m; all arithmetic in the local frame keeps f64 precision for the fit).
#[derive(Clone, Copy, Debug)]
pub struct PixelFrame {
    /// Local x of the raster's left edge.
    left_m: f64,
    /// Local y of the raster's top edge.
    top_m: f64,
    gsd_x_m: f64,
    gsd_y_m: f64,
    /// Local z offset (heights are stored in world units).
    z_origin_m: f64,
}

impl PixelFrame {
    pub fn new(geotransform: &GeoTransform, origin: &Vector3<f64>) -> Self {
        let g = geotransform.0;
        PixelFrame {
            left_m: g[0] - origin.x,
            top_m: g[3] - origin.y,
            gsd_x_m: geotransform.gsd_x(),
            gsd_y_m: geotransform.gsd_y(),
            z_origin_m: origin.z,
        }
    }

    /// Continuous pixel coordinates (col, row) of a local point.
    #[inline]
    pub fn to_pixel(&self, p: &Vector3<f64>) -> (f64, f64) {
        (
            (p.x - self.left_m) / self.gsd_x_m,
            (self.top_m - p.y) / self.gsd_y_m,
        )
    }

    /// Local point at the centre of pixel (col, row) with world height `h`.
    #[inline]
    pub fn pixel_point(&self, col: i64, row: i64, h: f32) -> Vector3<f64> {
        Vector3::new(
            self.left_m + (col as f64 + 0.5) * self.gsd_x_m,
            self.top_m - (row as f64 + 0.5) * self.gsd_y_m,
            h as f64 - self.z_origin_m,
        )
    }

    pub fn gsd_x_m(&self) -> f64 {
        self.gsd_x_m
    }

    pub fn gsd_y_m(&self) -> f64 {
        self.gsd_y_m
    }

    fn gsd_min_m(&self) -> f64 {
        self.gsd_x_m.min(self.gsd_y_m)
    }
}

/// The nearest reference point of a query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Neighbour {
    pub col: i64,
    pub row: i64,
    /// The reference point in the local frame.
    pub point: Vector3<f64>,
    pub distance_m: f64,
}

/// Counters of one search batch, to see how much the bound saves.
#[derive(Clone, Copy, Debug, Default)]
pub struct NnStats {
    pub queries: u64,
    pub pixels_visited: u64,
    pub not_found: u64,
}

/// Exact nearest neighbour in a grid, within `max_radius_m` horizontally.
pub fn nearest<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    query: &Vector3<f64>,
    max_radius_m: f64,
    stats: &mut NnStats,
) -> Option<Neighbour> {
    stats.queries += 1;
    let (col_f, row_f) = frame.to_pixel(query);
    if !col_f.is_finite() || !row_f.is_finite() {
        stats.not_found += 1;
        return None;
    }
    let c0 = col_f.floor() as i64;
    let r0 = row_f.floor() as i64;
    let gsd_min = frame.gsd_min_m();
    let max_ring = (max_radius_m / gsd_min).ceil() as i64 + 1;
    // The query lies within half a pixel of (c0, r0)'s centre on each axis, so
    // every pixel of ring k is at least (k - 0.5) * gsd away horizontally.
    let mut best = Best {
        neighbour: None,
        d2: f64::INFINITY,
    };
    let (w, h) = (grid.width(), grid.height());
    for k in 0..=max_ring {
        let ring_min_m = (k as f64 - 0.5).max(0.0) * gsd_min;
        if ring_min_m * ring_min_m >= best.d2 || ring_min_m > max_radius_m {
            break;
        }
        // Rings that cannot touch the raster are skipped cheaply.
        if ring_fully_outside(c0, r0, k, w, h) {
            continue;
        }
        let mut visit = |col: i64, row: i64| {
            stats.pixels_visited += 1;
            best.offer(grid, frame, query, max_radius_m, col, row);
        };
        if k == 0 {
            visit(c0, r0);
            continue;
        }
        let (cl, cr, rt, rb) = (c0 - k, c0 + k, r0 - k, r0 + k);
        let (col_lo, col_hi) = (cl.max(0), cr.min(w - 1));
        for row in [rt, rb] {
            if (0..h).contains(&row) {
                for c in col_lo..=col_hi {
                    visit(c, row);
                }
            }
        }
        let (row_lo, row_hi) = ((rt + 1).max(0), (rb - 1).min(h - 1));
        for col in [cl, cr] {
            if (0..w).contains(&col) {
                for r in row_lo..=row_hi {
                    visit(col, r);
                }
            }
        }
    }
    let best = best.neighbour;
    match best {
        Some(n) if n.distance_m.is_finite() => Some(n),
        _ => {
            stats.not_found += 1;
            None
        }
    }
}

/// The running best of one search.
struct Best {
    neighbour: Option<Neighbour>,
    d2: f64,
}

impl Best {
    #[inline]
    fn offer<G: Grid + ?Sized>(
        &mut self,
        grid: &mut G,
        frame: &PixelFrame,
        query: &Vector3<f64>,
        max_radius_m: f64,
        col: i64,
        row: i64,
    ) {
        let h = grid.get(col, row);
        if h.is_nan() {
            return;
        }
        let p = frame.pixel_point(col, row, h);
        if (p.x - query.x).abs() > max_radius_m || (p.y - query.y).abs() > max_radius_m {
            return;
        }
        let d2 = (p - query).norm_squared();
        if d2 < self.d2 {
            self.d2 = d2;
            self.neighbour = Some(Neighbour {
                col,
                row,
                point: p,
                distance_m: d2.sqrt(),
            });
        }
    }
}

/// True when the square ring of radius k around (c0, r0) misses the raster.
fn ring_fully_outside(c0: i64, r0: i64, k: i64, w: i64, h: i64) -> bool {
    c0 + k < 0 || r0 + k < 0 || c0 - k >= w || r0 - k >= h
}

/// A point of the reference surface with its tangent plane.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    pub point: Vector3<f64>,
    pub normal: Vector3<f64>,
    /// RMS deviation of the neighbourhood from the fitted plane (walls, crowns).
    pub roughness_m: f64,
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
    surface_below_memo(grid, frame, query, &mut PlaneMemo::default())
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
/// over the same pixel as last time (same result, fewer fits).
pub fn surface_below_memo<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    query: &Vector3<f64>,
    memo: &mut PlaneMemo,
) -> Option<SurfacePoint> {
    let (col_f, row_f) = frame.to_pixel(query);
    let (u, v) = (col_f - 0.5, row_f - 0.5);
    let (c0, r0) = (u.floor() as i64, v.floor() as i64);
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
    let point = Vector3::new(query.x, query.y, h - frame.z_origin_m);
    let (col, row) = (col_f.floor() as i64, row_f.floor() as i64);
    if memo.pixel != (col, row) {
        *memo = PlaneMemo {
            pixel: (col, row),
            plane: plane_fit(grid, frame, col, row, 2),
        };
    }
    let plane = memo.plane?;
    // The four interpolated pixels must lie on the ring's plane: a spike or a
    // wall among them makes the bilinear height meaningless.
    let limit_m = (4.0 * plane.rms_m).max(0.5);
    for (c, r, hv) in [
        (c0, r0, h00),
        (c0 + 1, r0, h10),
        (c0, r0 + 1, h01),
        (c0 + 1, r0 + 1, h11),
    ] {
        let dx = (c - col) as f64 * frame.gsd_x_m;
        let dy = -((r - row) as f64) * frame.gsd_y_m;
        if (hv - plane.height_at(dx, dy)).abs() > limit_m {
            return None;
        }
    }
    Some(SurfacePoint {
        point,
        normal: plane.normal(),
        roughness_m: plane.rms_m,
    })
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

/// Least-squares plane normal over the (2r+1)^2 window around (col, row),
/// skipping the inner square of Chebyshev radius < `skip_radius_px`
/// (1 = only the centre). The plane is fitted with an intercept.
/// A least-squares plane around a pixel: z = z0 + a dx + b dy, with dx, dy in
/// metres from that pixel's centre (y up).
#[derive(Clone, Copy, Debug)]
struct Plane {
    z0: f64,
    a: f64,
    b: f64,
    /// RMS height residual of the pixels kept by the fit (roughness).
    rms_m: f64,
}

impl Plane {
    fn normal(&self) -> Vector3<f64> {
        Vector3::new(-self.a, -self.b, 1.0).normalize()
    }

    fn height_at(&self, dx: f64, dy: f64) -> f64 {
        self.z0 + self.a * dx + self.b * dy
    }
}

/// Robust plane over the (2r+1)^2 window around (col, row), skipping the inner
/// square of Chebyshev radius < `skip_radius_px` (1 = only the centre): a
/// least-squares fit, then a refit without pixels beyond 3 robust sigmas
/// (spikes, the far side of a wall). None with fewer than 6 valid pixels.
fn plane_fit<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    col: i64,
    row: i64,
    skip_radius_px: i64,
) -> Option<Plane> {
    let k = NORMAL_RADIUS_PX;
    let mut pts: [(f64, f64, f64); 49] = [(0.0, 0.0, 0.0); 49];
    let mut n = 0;
    for dr in -k..=k {
        for dc in -k..=k {
            if dr.abs().max(dc.abs()) < skip_radius_px {
                continue;
            }
            let h = grid.get(col + dc, row + dr);
            if h.is_nan() {
                continue;
            }
            pts[n] = (
                dc as f64 * frame.gsd_x_m,
                -(dr as f64) * frame.gsd_y_m,
                h as f64,
            );
            n += 1;
        }
    }
    let mut keep = [true; 49];
    let first = fit_plane(&pts[..n], &keep[..n])?;
    let mut abs_res = [0.0f64; 49];
    for (i, &(x, y, z)) in pts[..n].iter().enumerate() {
        abs_res[i] = (z - first.height_at(x, y)).abs();
    }
    let mut scratch = abs_res;
    let median = *scratch[..n].select_nth_unstable_by(n / 2, f64::total_cmp).1;
    let limit = (3.0 * 1.4826 * median).max(0.05);
    let mut dropped = 0;
    for i in 0..n {
        if abs_res[i] > limit {
            keep[i] = false;
            dropped += 1;
        }
    }
    if dropped == 0 {
        return Some(first);
    }
    fit_plane(&pts[..n], &keep[..n])
}

fn fit_plane(pts: &[(f64, f64, f64)], keep: &[bool]) -> Option<Plane> {
    // One pass of moment sums, heights taken from the first point's (the
    // window spans metres, so the sums stay far from cancellation).
    let z_ref = pts.first()?.2;
    let (mut n, mut sx, mut sy, mut sz) = (0.0, 0.0, 0.0, 0.0);
    let (mut sxx, mut syy, mut sxy, mut sxz, mut syz, mut szz) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (&(x, y, z), _) in pts.iter().zip(keep).filter(|(_, &k)| k) {
        let z = z - z_ref;
        n += 1.0;
        sx += x;
        sy += y;
        sz += z;
        sxx += x * x;
        syy += y * y;
        sxy += x * y;
        sxz += x * z;
        syz += y * z;
        szz += z * z;
    }
    if n < 6.0 {
        return None;
    }
    let (mx, my, mz) = (sx / n, sy / n, sz / n);
    // centred moments
    let (cxx, cyy, cxy) = (sxx - n * mx * mx, syy - n * my * my, sxy - n * mx * my);
    let (cxz, cyz, czz) = (sxz - n * mx * mz, syz - n * my * mz, szz - n * mz * mz);
    let det = cxx * cyy - cxy * cxy;
    if det.abs() < 1e-12 {
        return None;
    }
    let a = (cxz * cyy - cyz * cxy) / det;
    let b = (cyz * cxx - cxz * cxy) / det;
    // residual sum of squares of the least-squares plane
    let sum_sq = (czz - a * cxz - b * cyz).max(0.0);
    Some(Plane {
        z0: mz + z_ref - a * mx - b * my,
        a,
        b,
        rms_m: (sum_sq / n).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::MemGrid;
    use proptest::prelude::*;

    fn brute_force(
        grid: &mut MemGrid,
        frame: &PixelFrame,
        q: &Vector3<f64>,
        max_radius_m: f64,
    ) -> Option<f64> {
        let mut best = f64::INFINITY;
        let (col_f, row_f) = frame.to_pixel(q);
        for row in 0..grid.height {
            for col in 0..grid.width {
                let h = grid.get(col, row);
                if h.is_nan() {
                    continue;
                }
                let p = frame.pixel_point(col, row, h);
                // Same cap as the search: horizontal distance in pixels from the query.
                let dc = (col as f64 + 0.5 - col_f).abs() * frame.gsd_x_m;
                let dr = (row as f64 + 0.5 - row_f).abs() * frame.gsd_y_m;
                if dc.max(dr) > max_radius_m {
                    continue;
                }
                best = best.min((p - q).norm());
            }
        }
        best.is_finite().then_some(best)
    }

    fn random_grid(w: i64, h: i64, seed: u64, nodata_frac: f64, wall_m: f32) -> MemGrid {
        let mut s = seed;
        let mut next = move || {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        let gt = GeoTransform::north_up(1000.0, 2000.0, 0.5, 0.5);
        MemGrid::from_fn(w, h, gt, |c, r| {
            let u = next();
            if u < nodata_frac {
                return f32::NAN;
            }
            let base = (c as f32 * 0.3).sin() * 2.0 + (r as f32 * 0.2).cos();
            let wall = if (c / 5 + r / 7) % 3 == 0 {
                wall_m
            } else {
                0.0
            };
            base + wall + (next() as f32 - 0.5)
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        #[test]
        fn grid_nn_equals_brute_force(
            w in 1i64..24, h in 1i64..24, seed in any::<u64>(), nodata in 0.0f64..0.9,
            wall in 0.0f32..15.0,
            qs in proptest::collection::vec((-3.0f64..15.0, -15.0f64..3.0, -5.0f64..25.0), 1..30),
            cap in prop_oneof![Just(1000.0f64), 0.2f64..6.0],
        ) {
            let mut grid = random_grid(w, h, seed, nodata, wall);
            let origin = Vector3::new(1000.0, 2000.0, 0.0);
            let frame = PixelFrame::new(&grid.geotransform, &origin);
            let mut stats = NnStats::default();
            for (x, y, z) in qs {
                let q = Vector3::new(x, y, z);
                let fast = nearest(&mut grid, &frame, &q, cap, &mut stats).map(|n| n.distance_m);
                let slow = brute_force(&mut grid, &frame, &q, cap);
                match (fast, slow) {
                    (Some(a), Some(b)) => prop_assert!((a - b).abs() < 1e-9, "fast {a} slow {b}"),
                    (None, None) => {}
                    (a, b) => prop_assert!(false, "fast {a:?} slow {b:?}"),
                }
            }
        }
    }

    #[test]
    fn nodata_below_query_still_finds_neighbour() {
        let gt = GeoTransform::north_up(0.0, 10.0, 1.0, 1.0);
        let mut grid = MemGrid::from_fn(
            10,
            10,
            gt,
            |c, r| if c == 5 && r == 5 { f32::NAN } else { 1.0 },
        );
        let frame = PixelFrame::new(&gt, &Vector3::zeros());
        let q = Vector3::new(5.5, 4.5, 1.0);
        let n = nearest(&mut grid, &frame, &q, 50.0, &mut NnStats::default()).unwrap();
        assert!((n.distance_m - 1.0).abs() < 1e-12);
    }

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
}
