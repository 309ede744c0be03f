//! The correspondence step of DSM-ICP: every query point, mapped by the current
//! estimate, is matched to its exact nearest reference point through the grid
//! search, outliers beyond tau are dropped, and the reference normal is taken
//! from the grid. Blocks of queries run in parallel (rayon), each with its own
//! view of the reference; results are concatenated in input order, so the
//! outcome does not depend on the thread count.

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use super::robust::Cell;
use super::Metric;
use crate::fit::Correspondence;
use crate::grid::{Grid, GridError, Pyramid};
use crate::nn::{
    nearest_or_within, normal_at, surface_below_memo, within_below, NnStats, PixelFrame, PlaneMemo,
    PlaneTable, Window, NORMAL_RADIUS_PX,
};

const BLOCK: usize = 4096;
/// The side of the reference tiles a block's queries are grouped by, pixels
/// (as [`block_order`] sorts them), each read through one [`Window`].
const WINDOW_TILE_PX: i64 = 256;
/// Fewer queries on a tile than this read the grid directly (a window of the
/// search margin around one query costs more than it saves).
const MIN_WINDOW_RUN: usize = 16;
/// Pixels around a query its matching reads in the common case: the plane
/// window of the surface below and the first rings of a search, plus one
/// (farther reads, rare, go to the grid).
const MARGIN_PX: i64 = NORMAL_RADIUS_PX + 3;

/// The nearest neighbour is searched this much beyond tau (a share of tau):
/// a query found beyond tau may then move by its margin and stay beyond,
/// with no search (spikes, voids, the parts of a sample that miss the
/// reference are found again each iteration otherwise).
pub(super) const FAR_REACH: f64 = 0.5;

/// What one query's matching keeps between calls on one level: its ring
/// plane, and once its nearest neighbour proved beyond tau, how far it may
/// move and stay so. The matches are those of matching afresh.
#[derive(Clone, Copy, Debug, Default)]
pub struct QueryMemo {
    plane: PlaneMemo,
    far: Option<Far>,
}

/// A query whose nearest reference point, from `at`, was `clear_m` farther
/// than `tau_m`: moved by less, it is still beyond (the distance to a set
/// changes by at most the motion).
#[derive(Clone, Copy, Debug)]
struct Far {
    at: Vector3<f64>,
    tau_m: f64,
    clear_m: f64,
}

/// Matches of one iteration.
#[derive(Clone, Debug, Default)]
pub struct Association {
    /// Inlier correspondences (NN distance below tau), weight 1.
    pub corrs: Vec<Correspondence>,
    /// NN distance of each inlier, same order as `corrs` (with
    /// [`Distances::Bound`], point-to-surface: at most that, see there).
    pub distances_m: Vec<f64>,
    /// The reference surface at each inlier (zero unless point-to-surface).
    pub cells: Vec<Cell>,
    /// Queries with a valid reference pixel right below them.
    pub with_reference_below: usize,
    pub queries: usize,
    pub nn: NnStats,
}

/// Sort key that groups queries by reference block, so each chunk is decoded
/// once per iteration.
pub fn block_order(points: &mut [Vector3<f64>], frame: &PixelFrame, block_px: i64) {
    points.sort_by_cached_key(|p| {
        let (c, r) = frame.cell_of(p);
        (r.div_euclid(block_px), c.div_euclid(block_px), r, c)
    });
}

/// What the correspondence step needs of one level: the reference pyramid and
/// level, that level's lattice in the local frame, the outlier distance, the
/// metric and whether the NN distances are wanted.
pub struct Matcher<'a, P> {
    pub reference: &'a P,
    pub level: usize,
    pub frame: PixelFrame,
    pub tau_m: f64,
    pub metric: Metric,
    pub distances: Distances,
}

/// What point-to-surface matching needs of the nearest neighbour.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Distances {
    /// Its exact distance (the residuals a result reports).
    Exact,
    /// Only whether it lies within tau, the outlier rule (the loop's
    /// iterations): the pixel right below within tau settles that without a
    /// search, its distance kept as the bound. The same matches as `Exact`.
    Bound,
}

impl<P: Pyramid> Matcher<'_, P> {
    /// [`associate`] on this level.
    pub fn associate(
        &self,
        points: &[Vector3<f64>],
        memo: &mut [QueryMemo],
        t_ref_moving: &Isometry3<f64>,
    ) -> Result<Association, GridError> {
        associate(self, points, memo, t_ref_moving)
    }
}

/// Matches `points` (moving frame) mapped by `t_ref_moving`. `memo` holds one
/// entry per point, kept between calls on the same level ([`QueryMemo`]); it
/// must have the length of `points`.
pub fn associate<P: Pyramid>(
    matcher: &Matcher<'_, P>,
    points: &[Vector3<f64>],
    memo: &mut [QueryMemo],
    t_ref_moving: &Isometry3<f64>,
) -> Result<Association, GridError> {
    assert_eq!(points.len(), memo.len(), "one plane memo per point");
    // Every block writes its matches into its own slice of one allocation
    // (a slot per query), then the matches are moved to the front in input
    // order: no per-block vectors, no concatenation copy.
    let unmatched = Correspondence {
        moving: Vector3::zeros(),
        reference: Vector3::zeros(),
        normal: Vector3::z(),
        weight: 1.0,
        normal_var: 0.0,
    };
    let mut all = Association {
        corrs: vec![unmatched; points.len()],
        distances_m: vec![f64::NAN; points.len()],
        cells: vec![Cell::default(); points.len()],
        queries: points.len(),
        ..Default::default()
    };
    let counts: Vec<Result<(usize, NnStats), GridError>> = points
        .par_chunks(BLOCK)
        .zip(memo.par_chunks_mut(BLOCK))
        .zip(all.corrs.par_chunks_mut(BLOCK))
        .zip(all.distances_m.par_chunks_mut(BLOCK))
        .zip(all.cells.par_chunks_mut(BLOCK))
        .map(|((((block, memo), corrs), distances_m), cells)| {
            let slots = Slots {
                corrs,
                distances_m,
                cells,
            };
            match_block(matcher, block, memo, t_ref_moving, slots)
        })
        .collect();
    for count in counts {
        let (below, nn) = count?;
        all.with_reference_below += below;
        all.nn.add(&nn);
    }
    all.compact();
    Ok(all)
}

/// One block's share of the output: a slot per query.
struct Slots<'s> {
    corrs: &'s mut [Correspondence],
    /// NaN while unmatched.
    distances_m: &'s mut [f64],
    cells: &'s mut [Cell],
}

/// Matches one block of queries through its own view of the reference level;
/// returns how many had a valid pixel right below and the search counters.
fn match_block<P: Pyramid>(
    matcher: &Matcher<'_, P>,
    block: &[Vector3<f64>],
    memo: &mut [QueryMemo],
    t_ref_moving: &Isometry3<f64>,
    slots: Slots<'_>,
) -> Result<(usize, NnStats), GridError> {
    let mut level = matcher.reference.open_level(matcher.level)?;
    let table = matcher.reference.planes(matcher.level);
    let queries: Vec<Vector3<f64>> = block
        .iter()
        .map(|p| t_ref_moving.transform_point(&Point3::from(*p)).coords)
        .collect();
    let (mut below, mut nn) = (0usize, NnStats::default());
    in_windows(&mut level, &matcher.frame, &queries, |grid, i| {
        let q = &queries[i];
        let (c, r) = matcher.frame.cell_of(q);
        if !grid.get(c, r).is_nan() {
            below += 1;
        }
        let Some((corr, distance_m, cell)) =
            match_query(grid, matcher, table, q, &mut memo[i], &mut nn)
        else {
            return;
        };
        slots.corrs[i] = corr;
        slots.distances_m[i] = distance_m;
        slots.cells[i] = cell;
    });
    if let Some(e) = level.take_error() {
        return Err(e);
    }
    Ok((below, nn))
}

/// Calls `visit(grid, i)` for each query `i` (local frame, in order), the grid
/// a view of `level`: runs of queries on one reference tile (as
/// [`block_order`] keeps them) read it through one [`Window`] with the
/// search margin, shorter runs the level itself. The values read are the
/// level's either way.
pub(super) fn in_windows<G: Grid>(
    level: &mut G,
    frame: &PixelFrame,
    queries: &[Vector3<f64>],
    mut visit: impl FnMut(&mut Window<'_, G>, usize),
) {
    let tiles: Vec<(i64, i64)> = queries
        .iter()
        .map(|q| {
            let (c, r) = frame.cell_of(q);
            (r.div_euclid(WINDOW_TILE_PX), c.div_euclid(WINDOW_TILE_PX))
        })
        .collect();
    let mut start = 0;
    while start < queries.len() {
        let run = tiles[start..]
            .iter()
            .take_while(|t| **t == tiles[start])
            .count();
        let run = start..start + run;
        let mut grid = if run.len() >= MIN_WINDOW_RUN {
            let bounds = pixel_box(frame, &queries[run.clone()]);
            Window::around(level, bounds, MARGIN_PX)
        } else {
            Window::none(level)
        };
        for i in run.clone() {
            visit(&mut grid, i);
        }
        start = run.end;
    }
}

/// The pixels of the lattice the queries fall in, (col0, row0, col1, row1)
/// inclusive; an empty box (col0 > col1) without a finite query.
fn pixel_box(frame: &PixelFrame, queries: &[Vector3<f64>]) -> (i64, i64, i64, i64) {
    let mut b = (i64::MAX, i64::MAX, i64::MIN, i64::MIN);
    for q in queries {
        let (c, r) = frame.to_pixel(q);
        if !(c.is_finite() && r.is_finite()) {
            continue;
        }
        let (c, r) = (c.floor() as i64, r.floor() as i64);
        b = (b.0.min(c), b.1.min(r), b.2.max(c), b.3.max(r));
    }
    b
}

/// The correspondence of one query `q` (reference frame, local): its exact
/// NN within tau, then the reference point and normal of the metric (ring
/// planes from `table` when the pair keeps one); with the NN distance and the
/// reference cell there.
fn match_query<P, G: Grid>(
    grid: &mut G,
    matcher: &Matcher<'_, P>,
    table: Option<&PlaneTable>,
    q: &Vector3<f64>,
    memo: &mut QueryMemo,
    nn: &mut NnStats,
) -> Option<(Correspondence, f64, Cell)> {
    let frame = &matcher.frame;
    let tau_m = matcher.tau_m;
    if let Some(far) = memo.far {
        if far.tau_m == tau_m && (q - far.at).norm() < far.clear_m {
            return None;
        }
    }
    let bounded = (matcher.metric, matcher.distances) == (Metric::PointToSurface, Distances::Bound);
    let bound = if bounded {
        within_below(grid, frame, q, tau_m, nn)
    } else {
        None
    };
    let (n, distance_m) = match bound {
        Some(d) => (None, d),
        None => {
            // exact within tau as a search to tau would be: any point within
            // tau lies inside that search's square
            let reach_m = tau_m * (1.0 + FAR_REACH);
            // a bound needs only whether a point lies within tau: the first
            // one found settles it (its distance is at least the nearest's)
            let enough_m = if bounded { tau_m } else { f64::NEG_INFINITY };
            match nearest_or_within(grid, frame, q, reach_m, enough_m, nn) {
                Some(n) if n.distance_m <= tau_m => (Some(n), n.distance_m),
                n => {
                    // points outside the searched square are beyond reach
                    let nearest_m = n.map_or(reach_m, |n| n.distance_m.min(reach_m));
                    memo.far = Some(Far {
                        at: *q,
                        tau_m,
                        clear_m: nearest_m - tau_m,
                    });
                    return None;
                }
            }
        }
    };
    let (reference, normal, cell, normal_var) = match (matcher.metric, n) {
        (Metric::PointToSurface, _) => {
            let s = surface_below_memo(grid, frame, q, &mut memo.plane, table)?;
            let cell = Cell {
                roughness_m: s.roughness_m,
                var_m2: s.cell_var_m2,
                band_m: s.cell_band_m,
            };
            (s.point, s.normal, cell, s.normal_var)
        }
        (_, Some(n)) => (
            n.point,
            normal_at(grid, frame, n.col, n.row),
            Cell::default(),
            0.0,
        ),
        (_, None) => unreachable!("a bound only for point-to-surface"),
    };
    let corr = Correspondence {
        moving: *q,
        reference,
        normal,
        weight: 1.0,
        normal_var,
    };
    Some((corr, distance_m, cell))
}

impl Association {
    /// Moves the matched slots (a finite distance) to the front, in input
    /// order, and drops the rest.
    fn compact(&mut self) {
        let mut kept = 0;
        for i in 0..self.distances_m.len() {
            if self.distances_m[i].is_finite() {
                self.corrs[kept] = self.corrs[i];
                self.distances_m[kept] = self.distances_m[i];
                self.cells[kept] = self.cells[i];
                kept += 1;
            }
        }
        self.corrs.truncate(kept);
        self.distances_m.truncate(kept);
        self.cells.truncate(kept);
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::geo::GeoTransform;
    use crate::grid::{MemGrid, MemPyramid};
    use crate::nn::{PlaneTable, WithPlanes};
    use crate::rng::SplitMix64;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A noisy 600 x 600 px surface with walls and voids, and queries over
    /// it and beyond its edge (some outliers beyond tau).
    pub(crate) fn scene() -> (MemPyramid, Vec<Vector3<f64>>, PixelFrame) {
        let gt = GeoTransform::north_up(1000.0, 2000.0, 0.5, 0.5);
        let mut rng = SplitMix64::new(7);
        let grid = MemGrid::from_fn(600, 600, gt, |c, r| {
            if rng.next_f64() < 0.03 {
                return f32::NAN;
            }
            let wall = if (c / 23 + r / 17) % 4 == 0 {
                12.0
            } else {
                0.0
            };
            (0.02 * c as f64 + 3.0 * (r as f64 / 40.0).sin() + wall + 0.3 * rng.next_f64()) as f32
        });
        let origin = Vector3::new(1150.0, 1850.0, 0.0);
        let frame = PixelFrame::new(&gt, &origin);
        let mut points: Vec<Vector3<f64>> = (0..20_000)
            .map(|_| {
                let (x, y) = (
                    rng.next_f64() * 340.0 - 160.0,
                    rng.next_f64() * 340.0 - 160.0,
                );
                let z = if rng.next_f64() < 0.05 {
                    40.0
                } else {
                    rng.next_f64() * 15.0 - 3.0
                };
                Vector3::new(x, y, z)
            })
            .collect();
        block_order(&mut points, &frame, 256);
        (MemPyramid::build(grid, 64), points, frame)
    }

    /// Point-to-surface matching on level 0 with a tau of 10 m.
    pub(crate) fn surface_matcher<P>(
        reference: &P,
        frame: PixelFrame,
        distances: Distances,
    ) -> Matcher<'_, P> {
        Matcher {
            reference,
            level: 0,
            frame,
            tau_m: 10.0,
            metric: Metric::PointToSurface,
            distances,
        }
    }

    /// What a level keeps between calls (each query's ring plane and far
    /// mark, and the pair's shared plane table) leaves every match, distance
    /// and cell as matching afresh, through small steps (the far marks
    /// hold) and jumps (they lapse), bounded and exact.
    #[test]
    fn what_is_kept_between_calls_matches_as_afresh() {
        let (pyramid, points, frame) = scene();
        let planed = WithPlanes::new(&pyramid, 0, PlaneTable::new(0, 0, 600, 600));
        let steps = [
            (0.7, -0.4, 0.3),
            (0.71, -0.41, 0.31),
            (0.712, -0.405, 0.305),
            (3.0, 2.0, -1.0),
            (3.001, 2.0, -1.002),
        ];
        for distances in [Distances::Bound, Distances::Exact] {
            let mut memo = vec![QueryMemo::default(); points.len()];
            let mut skipped = 0;
            for (x, y, z) in steps {
                let t = Isometry3::from_parts(
                    Translation3::new(x, y, z),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, 0.002),
                );
                let fresh_matcher = surface_matcher(&pyramid, frame, distances);
                let kept_matcher = surface_matcher(&planed, frame, distances);
                let mut fresh_memo = vec![QueryMemo::default(); points.len()];
                let fresh = associate(&fresh_matcher, &points, &mut fresh_memo, &t).unwrap();
                let kept = associate(&kept_matcher, &points, &mut memo, &t).unwrap();
                assert!(fresh.corrs.len() > 10_000, "{}", fresh.corrs.len());
                assert_eq!(fresh.corrs.len(), kept.corrs.len());
                for k in 0..fresh.corrs.len() {
                    let (a, b) = (&fresh.corrs[k], &kept.corrs[k]);
                    assert_eq!(
                        (a.moving, a.reference, a.normal, a.normal_var),
                        (b.moving, b.reference, b.normal, b.normal_var)
                    );
                    assert_eq!(fresh.distances_m[k], kept.distances_m[k]);
                    let (c, d) = (&fresh.cells[k], &kept.cells[k]);
                    assert_eq!(
                        (c.roughness_m, c.var_m2, c.band_m),
                        (d.roughness_m, d.var_m2, d.band_m)
                    );
                }
                skipped += fresh.nn.pixels_visited as i64 - kept.nn.pixels_visited as i64;
            }
            // the far marks saved searches (the queries beyond the raster's
            // edge and the spikes are found again otherwise)
            assert!(skipped > 0, "{distances:?}");
        }
    }

    /// The outlier rule decided by the pixel below (Bound) keeps exactly the
    /// matches of the full search (Exact), with distances at least the
    /// nearest neighbour's; both read through windows, so they are also
    /// checked against a search without any (one query per call).
    #[test]
    fn a_bound_keeps_the_matches_of_the_full_search() {
        let (pyramid, points, frame) = scene();
        let t = Isometry3::from_parts(
            Translation3::new(0.7, -0.4, 0.3),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.002),
        );
        let matcher = |distances| surface_matcher(&pyramid, frame, distances);
        let memo = || vec![QueryMemo::default(); points.len()];
        let exact = associate(&matcher(Distances::Exact), &points, &mut memo(), &t).unwrap();
        let bound = associate(&matcher(Distances::Bound), &points, &mut memo(), &t).unwrap();
        assert!(exact.corrs.len() > 10_000, "{}", exact.corrs.len());
        assert_eq!(exact.corrs.len(), bound.corrs.len());
        assert_eq!(exact.with_reference_below, bound.with_reference_below);
        for k in 0..exact.corrs.len() {
            let (a, b) = (&exact.corrs[k], &bound.corrs[k]);
            assert_eq!(
                (a.moving, a.reference, a.normal),
                (b.moving, b.reference, b.normal)
            );
            assert!(bound.distances_m[k] >= exact.distances_m[k]);
        }
        let (b, e) = (bound.nn.pixels_visited, exact.nn.pixels_visited);
        assert!(b < e, "pixels visited: bound {b}, exact {e}");
        // one query per call: its window is its own, or none at all
        let mut grid = pyramid.open_level(0).unwrap();
        let m = matcher(Distances::Exact);
        let mut k = 0;
        for p in points.iter().step_by(97) {
            let q = t.transform_point(&Point3::from(*p)).coords;
            let single = match_query(
                &mut grid,
                &m,
                None,
                &q,
                &mut QueryMemo::default(),
                &mut NnStats::default(),
            );
            let batched = exact.corrs.iter().position(|c| c.moving == q);
            match (single, batched) {
                (Some((corr, d, _)), Some(i)) => {
                    assert_eq!(
                        (corr.reference, d),
                        (exact.corrs[i].reference, exact.distances_m[i])
                    );
                    k += 1;
                }
                (None, None) => {}
                (s, b) => panic!(
                    "query {q:?}: alone {:?}, in its block {b:?}",
                    s.map(|s| s.1)
                ),
            }
        }
        assert!(k > 100, "{k}");
    }
}
