//! Walls' shared placement error in a fit's covariance (see [`WallSnap`]).

use super::jacobian_row;
use crate::fit::Correspondence;
use nalgebra::{Matrix6, Matrix6x2, Vector2, Vector3};
use std::collections::BTreeMap;

/// A wall's position in a gridded DSM is snapped to its lattice: one error,
/// uniform over a pixel in each of the two DSMs (variance pixel^2 / 6 for
/// both), shared by every match along the wall. The sandwich of one fit's
/// residuals sees few walls and does not measure it; each wall segment adds
/// sigma_m^2 B B^T to the meat, B the sum over its matches of w a n_h^T
/// (n_h the normal's horizontal part: how far the match's residual moves
/// when the wall does).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WallSnap {
    /// One-sigma placement error of a wall in either horizontal direction, metres.
    pub sigma_m: f64,
    /// Side of the squares that cut walls into segments of one shared error, metres.
    pub segment_m: f64,
}

impl WallSnap {
    /// Snapping to pixels of `pixel_m` in two DSMs, segments of 16 pixels.
    pub fn of_pixel(pixel_m: f64) -> Self {
        WallSnap {
            sigma_m: pixel_m / 6f64.sqrt(),
            segment_m: 16.0 * pixel_m,
        }
    }

    /// The meat of the walls among `corrs` (a match on a wall: a normal
    /// at least [`WALL_MIN_HORIZONTAL_NORMAL`] horizontal), parameters scaled as [`NormalEquations`].
    pub(super) fn meat(
        &self,
        corrs: &[Correspondence],
        centroid: &Vector3<f64>,
        radius_m: f64,
    ) -> Matrix6<f64> {
        let mut walls: BTreeMap<(i64, i64, i64), Matrix6x2<f64>> = BTreeMap::new();
        for c in corrs {
            let n_h = Vector2::new(c.normal.x, c.normal.y);
            if n_h.norm() < WALL_MIN_HORIZONTAL_NORMAL {
                continue;
            }
            let q = c.moving - centroid;
            let a = jacobian_row(&q, &c.normal, radius_m);
            // which of the four facing directions (a building's sides are apart)
            let facing =
                ((n_h.y.atan2(n_h.x) / std::f64::consts::FRAC_PI_2).round() as i64).rem_euclid(4);
            let cell = |v: f64| (v / self.segment_m).floor() as i64;
            *walls
                .entry((cell(q.x), cell(q.y), facing))
                .or_insert_with(Matrix6x2::zeros) += c.weight * a * n_h.transpose();
        }
        walls
            .values()
            .map(|b| b * b.transpose())
            .sum::<Matrix6<f64>>()
            * self.sigma_m.powi(2)
    }
}

/// A match is on a wall when its normal's horizontal part reaches this (a
/// slope of 44 degrees or more).
const WALL_MIN_HORIZONTAL_NORMAL: f64 = 0.7;
