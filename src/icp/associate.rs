//! The correspondence step of DSM-ICP: every query point, mapped by the current
//! estimate, is matched to its exact nearest reference point through the grid
//! search, outliers beyond tau are dropped, and the reference normal is taken
//! from the grid. Blocks of queries run in parallel (rayon), each with its own
//! view of the reference; results are concatenated in input order, so the
//! outcome does not depend on the thread count.

use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

use super::Metric;
use crate::fit::Correspondence;
use crate::grid::{Grid, Pyramid};
use crate::nn::{nearest, normal_at, surface_below, NnStats, PixelFrame};

const BLOCK: usize = 4096;

/// Matches of one iteration.
#[derive(Clone, Debug, Default)]
pub struct Association {
    /// Inlier correspondences (NN distance below tau), weight 1.
    pub corrs: Vec<Correspondence>,
    /// NN distance of each inlier, same order as `corrs`.
    pub distances_m: Vec<f64>,
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

pub fn associate<P: Pyramid>(
    reference: &P,
    level: usize,
    frame: &PixelFrame,
    points: &[Vector3<f64>],
    t_ref_moving: &Isometry3<f64>,
    tau_m: f64,
    metric: Metric,
    max_roughness_m: f64,
) -> Result<Association, String> {
    let blocks: Vec<Result<Association, String>> = points
        .par_chunks(BLOCK)
        .map(|block| {
            let mut grid = reference.open_level(level)?;
            let mut out = Association {
                queries: block.len(),
                ..Default::default()
            };
            for p in block {
                let q = t_ref_moving.transform_point(&Point3::from(*p)).coords;
                let (c, r) = frame.to_pixel(&q);
                if !grid.get(c.floor() as i64, r.floor() as i64).is_nan() {
                    out.with_reference_below += 1;
                }
                let Some(n) = nearest(&mut grid, frame, &q, tau_m, &mut out.nn) else {
                    continue;
                };
                if n.distance_m > tau_m {
                    continue;
                }
                let (reference, normal) = match metric {
                    Metric::PointToSurface => {
                        match surface_below(&mut grid, frame, &q, max_roughness_m) {
                            Some(s) => s,
                            None => continue,
                        }
                    }
                    _ => (n.point, normal_at(&mut grid, frame, n.col, n.row)),
                };
                out.corrs.push(Correspondence {
                    moving: q,
                    reference,
                    normal,
                    weight: 1.0,
                });
                out.distances_m.push(n.distance_m);
            }
            if let Some(e) = grid.take_error() {
                return Err(e);
            }
            Ok(out)
        })
        .collect();
    let mut all = Association::default();
    for block in blocks {
        let b = block?;
        all.corrs.extend(b.corrs);
        all.distances_m.extend(b.distances_m);
        all.with_reference_below += b.with_reference_below;
        all.queries += b.queries;
        all.nn.queries += b.nn.queries;
        all.nn.pixels_visited += b.nn.pixels_visited;
        all.nn.not_found += b.nn.not_found;
    }
    Ok(all)
}
