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
use crate::nn::{nearest, normal_at, surface_below_memo, NnStats, PixelFrame, PlaneMemo};

const BLOCK: usize = 4096;

/// Matches of one iteration.
#[derive(Clone, Debug, Default)]
pub struct Association {
    /// Inlier correspondences (NN distance below tau), weight 1.
    pub corrs: Vec<Correspondence>,
    /// NN distance of each inlier, same order as `corrs`.
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
        let (c, r) = frame.to_pixel(p);
        let (c, r) = (c.floor() as i64, r.floor() as i64);
        (r.div_euclid(block_px), c.div_euclid(block_px), r, c)
    });
}

/// What the correspondence step needs of one level: the reference pyramid and
/// level, that level's lattice in the local frame, the outlier distance and the metric.
pub struct Matcher<'a, P> {
    pub reference: &'a P,
    pub level: usize,
    pub frame: PixelFrame,
    pub tau_m: f64,
    pub metric: Metric,
}

impl<P: Pyramid> Matcher<'_, P> {
    /// [`associate`] on this level.
    pub fn associate(
        &self,
        points: &[Vector3<f64>],
        memo: &mut [PlaneMemo],
        t_ref_moving: &Isometry3<f64>,
    ) -> Result<Association, GridError> {
        associate(self, points, memo, t_ref_moving)
    }
}

/// Matches `points` (moving frame) mapped by `t_ref_moving`. `memo` holds one
/// entry per point (point-to-surface reuses their ring planes between calls on
/// the same level); it must have the length of `points`.
pub fn associate<P: Pyramid>(
    matcher: &Matcher<'_, P>,
    points: &[Vector3<f64>],
    memo: &mut [PlaneMemo],
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
    memo: &mut [PlaneMemo],
    t_ref_moving: &Isometry3<f64>,
    slots: Slots<'_>,
) -> Result<(usize, NnStats), GridError> {
    let mut grid = matcher.reference.open_level(matcher.level)?;
    let (mut below, mut nn) = (0usize, NnStats::default());
    for (i, (p, memo)) in block.iter().zip(memo).enumerate() {
        let q = t_ref_moving.transform_point(&Point3::from(*p)).coords;
        let (c, r) = matcher.frame.to_pixel(&q);
        if !grid.get(c.floor() as i64, r.floor() as i64).is_nan() {
            below += 1;
        }
        let Some((corr, distance_m, cell)) = match_query(&mut grid, matcher, &q, memo, &mut nn)
        else {
            continue;
        };
        slots.corrs[i] = corr;
        slots.distances_m[i] = distance_m;
        slots.cells[i] = cell;
    }
    if let Some(e) = grid.take_error() {
        return Err(e);
    }
    Ok((below, nn))
}

/// The correspondence of one query `q` (reference frame, local): its exact
/// NN within tau, then the reference point and normal of the metric; with the
/// NN distance and the reference cell there.
fn match_query<P, G: Grid>(
    grid: &mut G,
    matcher: &Matcher<'_, P>,
    q: &Vector3<f64>,
    memo: &mut PlaneMemo,
    nn: &mut NnStats,
) -> Option<(Correspondence, f64, Cell)> {
    let frame = &matcher.frame;
    let n = nearest(grid, frame, q, matcher.tau_m, nn)?;
    if n.distance_m > matcher.tau_m {
        return None;
    }
    let (reference, normal, cell, normal_var) = match matcher.metric {
        Metric::PointToSurface => {
            let s = surface_below_memo(grid, frame, q, memo)?;
            let cell = Cell {
                roughness_m: s.roughness_m,
                var_m2: s.cell_var_m2,
                band_m: s.cell_band_m,
            };
            (s.point, s.normal, cell, s.normal_var)
        }
        _ => (
            n.point,
            normal_at(grid, frame, n.col, n.row),
            Cell::default(),
            0.0,
        ),
    };
    let corr = Correspondence {
        moving: *q,
        reference,
        normal,
        weight: 1.0,
        normal_var,
    };
    Some((corr, n.distance_m, cell))
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
