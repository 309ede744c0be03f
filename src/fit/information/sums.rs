//! The sums behind [`super::NormalEquations`]: H, g and the meats of one
//! chunk of matches, and the spatial (Conley) meat from the clustered scores.

use std::collections::BTreeMap;

use nalgebra::{Matrix6, Vector3, Vector6};

use super::{jacobian_row, CELLS_PER_BANDWIDTH};
use crate::fit::Correspondence;
use crate::nn::frame::floor_i64;

/// Matches per chunk of the parallel sums of [`NormalEquations::new`].
pub(super) const SUM_CHUNK: usize = 16_384;

/// The sums of one chunk of matches: H, g, the independent meat and the
/// clustered scores per cell.
pub(super) struct Sums {
    pub h: Matrix6<f64>,
    pub g: Vector6<f64>,
    pub meat: Matrix6<f64>,
    pub cells: BTreeMap<(i64, i64), Vector6<f64>>,
}

impl Sums {
    pub fn of(corrs: &[Correspondence], centroid: &Vector3<f64>, radius_m: f64, cell: f64) -> Self {
        let mut sums = Sums {
            h: Matrix6::zeros(),
            g: Vector6::zeros(),
            meat: Matrix6::zeros(),
            cells: BTreeMap::new(),
        };
        // matches come in block order: most fall in the cell of the last one
        let mut run: Option<((i64, i64), Vector6<f64>)> = None;
        for c in corrs {
            let q = c.moving - centroid;
            let a = jacobian_row(&q, &c.normal, radius_m);
            let r = c.plane_residual_m();
            let aat = a * a.transpose();
            sums.h += c.weight * aat;
            sums.g += c.weight * r * a;
            sums.meat += (c.weight * r).powi(2) * aat;
            let key = (floor_i64(q.x / cell), floor_i64(q.y / cell));
            match &mut run {
                Some((k, s)) if *k == key => *s += c.weight * r * a,
                _ => {
                    if let Some((k, s)) = run.take() {
                        *sums.cells.entry(k).or_insert_with(Vector6::zeros) += s;
                    }
                    run = Some((key, c.weight * r * a));
                }
            }
        }
        if let Some((k, s)) = run {
            *sums.cells.entry(k).or_insert_with(Vector6::zeros) += s;
        }
        sums
    }
}

/// Spatial (Conley) sandwich meat: sum over cell pairs of K(c, d) S_c S_d^T with
/// the product Bartlett kernel (1 - |dx| / L)(1 - |dy| / L), positive
/// semi-definite, which reaches to the bandwidth L.
pub(super) fn bartlett_meat(cells: &BTreeMap<(i64, i64), Vector6<f64>>) -> Matrix6<f64> {
    let reach = CELLS_PER_BANDWIDTH;
    let kernel = |d: i64| 1.0 - d.abs() as f64 / reach as f64;
    let mut meat = Matrix6::zeros();
    for (&(cx, cy), s) in cells {
        let mut near = Vector6::zeros();
        for dx in -reach + 1..reach {
            for dy in -reach + 1..reach {
                if let Some(t) = cells.get(&(cx + dx, cy + dy)) {
                    near += t * (kernel(dx) * kernel(dy));
                }
            }
        }
        meat += s * near.transpose();
    }
    (meat + meat.transpose()) * 0.5
}
