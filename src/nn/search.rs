//! The exact ring search for the nearest reference point of a query (see the
//! module doc of [`crate::nn`] for the bound that makes it stop early).

use nalgebra::Vector3;

use super::frame::floor_i64;
use super::PixelFrame;
use crate::grid::Grid;

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

impl NnStats {
    /// Adds the counters of another batch.
    pub fn add(&mut self, other: &NnStats) {
        self.queries += other.queries;
        self.pixels_visited += other.pixels_visited;
        self.not_found += other.not_found;
    }
}

/// Exact nearest neighbour in a grid, within `max_radius_m` horizontally.
pub fn nearest<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    query: &Vector3<f64>,
    max_radius_m: f64,
    stats: &mut NnStats,
) -> Option<Neighbour> {
    nearest_or_within(grid, frame, query, max_radius_m, f64::NEG_INFINITY, stats)
}

/// [`nearest`], except that the search ends with the ring where a point
/// within `enough_m` is found, returning the nearest point found so far: a
/// point within `enough_m`, not always the nearest (for when only whether
/// one lies that close matters). None, or a point farther than `enough_m`,
/// as [`nearest`].
pub fn nearest_or_within<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    query: &Vector3<f64>,
    max_radius_m: f64,
    enough_m: f64,
    stats: &mut NnStats,
) -> Option<Neighbour> {
    stats.queries += 1;
    let (col_f, row_f) = frame.to_pixel(query);
    if !col_f.is_finite() || !row_f.is_finite() {
        stats.not_found += 1;
        return None;
    }
    let (c0, r0) = (floor_i64(col_f), floor_i64(row_f));
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
        for_ring_pixels(c0, r0, k, w, h, |col, row| {
            stats.pixels_visited += 1;
            best.offer(grid, frame, query, max_radius_m, col, row);
        });
        if enough_m >= 0.0 && best.d2 <= enough_m * enough_m {
            break;
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

/// Whether the nearest neighbour of `q` lies within `max_m`, settled by the
/// bound alone (module doc of [`crate::nn`]): the distance to the valid pixel
/// right below `q` when within `max_m` (the nearest neighbour is at most that
/// far); None otherwise, for [`nearest`] to decide. A query settled here is
/// counted in `nn`; one left to [`nearest`] is counted there.
pub fn within_below<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    q: &Vector3<f64>,
    max_m: f64,
    nn: &mut NnStats,
) -> Option<f64> {
    let (c, r) = frame.to_pixel(q);
    if !(c.is_finite() && r.is_finite()) {
        return None;
    }
    let (c, r) = (floor_i64(c), floor_i64(r));
    let h = grid.get(c, r);
    if h.is_nan() {
        return None;
    }
    nn.pixels_visited += 1;
    let d = (frame.pixel_point(c, r, h) - q).norm();
    nn.queries += u64::from(d <= max_m);
    (d <= max_m).then_some(d)
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

/// Calls `visit(col, row)` for the pixels of the square ring of Chebyshev
/// radius k around (c0, r0) that lie inside a w x h raster: top and bottom
/// rows left to right, then the left and right columns top to bottom.
#[inline]
fn for_ring_pixels(c0: i64, r0: i64, k: i64, w: i64, h: i64, mut visit: impl FnMut(i64, i64)) {
    if k == 0 {
        visit(c0, r0);
        return;
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

/// True when the square ring of radius k around (c0, r0) misses the raster.
fn ring_fully_outside(c0: i64, r0: i64, k: i64, w: i64, h: i64) -> bool {
    c0 + k < 0 || r0 + k < 0 || c0 - k >= w || r0 - k >= h
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::GeoTransform;
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
                let dc = (col as f64 + 0.5 - col_f).abs() * frame.gsd_x_m();
                let dr = (row as f64 + 0.5 - row_f).abs() * frame.gsd_y_m();
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

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// A query the pixel below settles has its nearest neighbour within
        /// the same cap and no farther than the bound.
        #[test]
        fn the_pixel_below_bounds_the_nearest(
            seed in any::<u64>(), nodata in 0.0f64..0.9, wall in 0.0f32..15.0,
            qs in proptest::collection::vec((-3.0f64..15.0, -15.0f64..3.0, -5.0f64..25.0), 1..30),
            cap in 0.5f64..6.0,
        ) {
            let mut grid = random_grid(12, 12, seed, nodata, wall);
            let frame = PixelFrame::new(&grid.geotransform, &Vector3::new(1000.0, 2000.0, 0.0));
            let mut stats = NnStats::default();
            for (x, y, z) in qs {
                let q = Vector3::new(x, y, z);
                if let Some(bound) = within_below(&mut grid, &frame, &q, cap, &mut stats) {
                    let n = nearest(&mut grid, &frame, &q, cap, &mut stats);
                    prop_assert!(bound <= cap);
                    prop_assert!(n.is_some_and(|n| n.distance_m <= bound + 1e-12), "{bound} {n:?}");
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
}
