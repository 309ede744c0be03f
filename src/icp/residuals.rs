//! The residual a result reports: the RMS exact nearest-neighbour distance of
//! its final matches, computed once, for the result `register` returns.
//!
//! Every run of a pair (each start's ladder and its levels, the restarts, the
//! backward check) ends with its final matches; only the returned result's
//! distances are reported. The final matches are found with the loop's
//! bounded distances (the same matches: `associate::Distances::Bound`), and
//! each run keeps its inliers' query points; the exact distances of the
//! returned result's points are searched here as the exact matching would
//! (the same search, the same points, summed in the same order): the same
//! `rmse_m` to the bit.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::associate::{in_windows, FAR_REACH};
use crate::grid::{Grid, GridError, Pyramid};
use crate::nn::{nearest_or_within, NnStats, PixelFrame};

/// Queries per parallel block.
const BLOCK: usize = 4096;

/// A run's final inliers, to measure their exact distances later.
#[derive(Debug)]
pub struct FinalQueries {
    /// The reference level they were matched on, and its lattice in the
    /// run's local frame.
    pub level: usize,
    pub frame: PixelFrame,
    /// The outlier distance they were matched with.
    pub tau_m: f64,
    /// The query points (local frame) of the inliers, in the matches' order.
    pub queries: Vec<Vector3<f64>>,
}

/// The RMS exact nearest-neighbour distance of `f`'s queries on `reference`
/// (NaN without a query), and the search counters.
pub fn exact_rmse<P: Pyramid>(
    reference: &P,
    f: &FinalQueries,
) -> Result<(f64, NnStats), GridError> {
    let reach_m = f.tau_m * (1.0 + FAR_REACH);
    let blocks: Vec<Result<(Vec<f64>, NnStats), GridError>> = f
        .queries
        .par_chunks(BLOCK)
        .map(|block| {
            let mut level = reference.open_level(f.level)?;
            let (mut distances, mut nn) = (vec![f64::NAN; block.len()], NnStats::default());
            in_windows(&mut level, &f.frame, block, |grid, i| {
                let found = nearest_or_within(
                    grid,
                    &f.frame,
                    &block[i],
                    reach_m,
                    f64::NEG_INFINITY,
                    &mut nn,
                );
                distances[i] = found.map_or(f64::NAN, |n| n.distance_m);
            });
            match level.take_error() {
                Some(e) => Err(e),
                None => Ok((distances, nn)),
            }
        })
        .collect();
    let (mut distances, mut nn) = (Vec::with_capacity(f.queries.len()), NnStats::default());
    for block in blocks {
        let (d, n) = block?;
        distances.extend(d);
        nn.add(&n);
    }
    Ok((rms(&distances), nn))
}

/// Root mean square; NaN for no values.
pub fn rms(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::icp::associate::tests::{scene, surface_matcher};
    use crate::icp::associate::{associate, Distances, QueryMemo};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    #[test]
    fn rms_of_nothing_is_nan() {
        assert!(rms(&[]).is_nan());
        assert_eq!(rms(&[3.0, 4.0, 0.0, 0.0]), 2.5);
    }

    /// The exact distances of bounded matches' inliers give the RMS of
    /// exact matching to the bit, where bounds alone would not.
    #[test]
    fn bounded_matches_measured_afterwards_report_the_exact_rmse() {
        let (pyramid, points, frame) = scene();
        let t = Isometry3::from_parts(
            Translation3::new(0.7, -0.4, 0.3),
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.002),
        );
        let match_with = |distances| {
            let matcher = surface_matcher(&pyramid, frame, distances);
            let mut memo = vec![QueryMemo::default(); points.len()];
            associate(&matcher, &points, &mut memo, &t).unwrap()
        };
        let (exact, bound) = (match_with(Distances::Exact), match_with(Distances::Bound));
        assert_eq!(exact.corrs.len(), bound.corrs.len());
        assert_ne!(rms(&exact.distances_m), rms(&bound.distances_m));
        let f = FinalQueries {
            level: 0,
            frame,
            tau_m: 10.0,
            queries: bound.corrs.iter().map(|c| c.moving).collect(),
        };
        let (measured, nn) = exact_rmse(&pyramid, &f).unwrap();
        assert_eq!(measured.to_bits(), rms(&exact.distances_m).to_bits());
        assert_eq!(nn.queries as usize, bound.corrs.len());
    }
}
