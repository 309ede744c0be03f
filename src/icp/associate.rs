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

/// The nearest neighbour is searched this much beyond tau (a share of tau):
/// a query found beyond tau may then move by its margin and stay beyond,
/// with no search (spikes, voids, the parts of a sample that miss the
/// reference are found again each iteration otherwise).
const FAR_REACH: f64 = 0.5;

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

impl<P> Matcher<'_, P> {
    /// Pixels around a query its matching reads in the common case: the
    /// plane window of the surface below and the first rings of a search,
    /// plus one (farther reads, rare, go to the grid).
    fn margin_px(&self) -> i64 {
        NORMAL_RADIUS_PX + 3
    }
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
    let tiles: Vec<(i64, i64)> = queries
        .iter()
        .map(|q| {
            let (c, r) = matcher.frame.cell_of(q);
            (r.div_euclid(WINDOW_TILE_PX), c.div_euclid(WINDOW_TILE_PX))
        })
        .collect();
    let (mut below, mut nn) = (0usize, NnStats::default());
    // runs of queries on one tile of the reference (the block order keeps
    // them together) read it through one window
    let mut start = 0;
    while start < queries.len() {
        let run = tiles[start..]
            .iter()
            .take_while(|t| **t == tiles[start])
            .count();
        let run = start..start + run;
        let mut grid = if run.len() >= MIN_WINDOW_RUN {
            let bounds = pixel_box(&matcher.frame, &queries[run.clone()]);
            Window::around(&mut level, bounds, matcher.margin_px())
        } else {
            Window::none(&mut level)
        };
        for i in run.clone() {
            let q = &queries[i];
            let (c, r) = matcher.frame.cell_of(q);
            if !grid.get(c, r).is_nan() {
                below += 1;
            }
            let Some((corr, distance_m, cell)) =
                match_query(&mut grid, matcher, table, q, &mut memo[i], &mut nn)
            else {
                continue;
            };
            slots.corrs[i] = corr;
            slots.distances_m[i] = distance_m;
            slots.cells[i] = cell;
        }
        start = run.end;
    }
    if let Some(e) = level.take_error() {
        return Err(e);
    }
    Ok((below, nn))
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
mod tests;
