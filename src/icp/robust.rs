//! Robust weighting of one iteration's matches: places where the reference is
//! not a surface (walls, tree crowns) are dropped, the rest get Tukey biweights
//! on what their residuals leave outside the band of their reference cell,
//! scaled by that cell's inverse variance.

use super::Metric;
use crate::fit::Correspondence;
use crate::select;

/// The reference surface under one match (point-to-surface; zero otherwise):
/// its roughness and the spread of its bilinear cell.
#[derive(Clone, Copy, Debug, Default)]
pub struct Cell {
    /// RMS of the ring plane's pixels about it (walls, crowns).
    pub roughness_m: f64,
    /// [`crate::nn::SurfacePoint::cell_var_m2`].
    pub var_m2: f64,
    /// [`crate::nn::SurfacePoint::cell_band_m`].
    pub band_m: f64,
}

/// Drops correspondences on rough places: above both `floor_m` and 3x the
/// median roughness (so steep but smooth terrain at coarse GSD is kept).
/// `cells` is empty (nothing to judge) or one per correspondence; the kept
/// cells come back with the kept correspondences.
pub(super) fn smooth_only(
    mut corrs: Vec<Correspondence>,
    cells: &[Cell],
    floor_m: f64,
) -> (Vec<Correspondence>, Vec<Cell>) {
    if cells.len() != corrs.len() || corrs.is_empty() {
        return (corrs, Vec::new());
    }
    let median = select::kth_of(cells.iter().map(|c| c.roughness_m), cells.len() / 2);
    let limit = floor_m.max(3.0 * median);
    // in place: a second vector of a 200,000 matches' level is 18 MB more at
    // the pair's peak
    let mut kept = Vec::with_capacity(cells.len());
    let mut k = 0;
    for (i, cell) in cells.iter().enumerate() {
        if cell.roughness_m <= limit {
            corrs[k] = corrs[i];
            kept.push(*cell);
            k += 1;
        }
    }
    corrs.truncate(k);
    (corrs, kept)
}

/// Tukey biweight, scale from the median absolute residual (sigma), on the
/// residual; in a cell that holds a step (`cells`: one per correspondence, or
/// empty for none; a step: the cell's variance above sigma^2), on how far the
/// residual falls outside the cell's band, times sigma^2 / (sigma^2 + the
/// cell's variance), band and variance scaled by [`guess_share`].
///
/// Under a wall the reference pixels do not tell where in the cell the step
/// lies, so a query there is high or low, its residual h (1 - f) or -h f, zero
/// on average. A weight that falls with the residual inside that band favours
/// the low side, so the fit slides to the lattice phase where both DSMs sample
/// the same places (measured: 0.1-0.2 m on 256 m tiles with 0.3 m noise,
/// docs/notes/lattice.md); the inverse variance weighs the guess for what it
/// is worth.
pub(super) fn weighted(
    mut corrs: Vec<Correspondence>,
    cells: &[Cell],
    metric: Metric,
) -> Vec<Correspondence> {
    let residual = |c: &Correspondence| match metric {
        Metric::PointToPlane | Metric::PointToSurface => c.plane_residual_m().abs(),
        Metric::PointToPoint => (c.moving - c.reference).norm(),
    };
    if corrs.is_empty() {
        // a restart whose final association found nothing (64 m tiles)
        return corrs;
    }
    let median = select::kth_of(corrs.iter().map(residual), corrs.len() / 2);
    let sigma = (1.4826 * median).max(0.01);
    let c = 4.685 * sigma;
    let noise_var = sigma * sigma;
    let kappa = guess_share(&corrs, cells, residual, sigma);
    let band_share = kappa.sqrt();
    for (i, corr) in corrs.iter_mut().enumerate() {
        let cell = cells.get(i).copied().unwrap_or_default();
        let (band, var) = step_of(corr, &cell, noise_var)
            .map_or((0.0, 0.0), |(band, var)| (band_share * band, kappa * var));
        let u = (residual(corr) - band).max(0.0) / c;
        let tukey = if u < 1.0 { (1.0 - u * u).powi(2) } else { 0.0 };
        corr.weight = tukey * noise_var / (noise_var + var);
    }
    corrs
}

/// The band and variance of a cell that holds a step, along the match's
/// normal (they are heights; the residual is along the normal); None for a
/// cell whose pixels depart from its plane by no more than the noise.
fn step_of(corr: &Correspondence, cell: &Cell, noise_var: f64) -> Option<(f64, f64)> {
    let nz = corr.normal.z.abs();
    let var = cell.var_m2 * nz * nz;
    (var > noise_var).then_some((cell.band_m * nz, var))
}

/// How much of the cells' guess variance the residuals show, in [0, 1]: the
/// residual variance beyond the noise in cells with a step, over those cells'
/// variance (residuals capped at the band plus three noise sigmas, so an
/// outlier counts as one far side of a wall). 1 where each DSM samples its
/// own side of every wall (gridded from points: binning, pixel centres); near
/// 0 where both DSMs carry the same ramps (resampled from one source), so
/// their walls are as exact as their flat ground. 1 with no step cells.
fn guess_share(
    corrs: &[Correspondence],
    cells: &[Cell],
    residual: impl Fn(&Correspondence) -> f64,
    sigma: f64,
) -> f64 {
    let noise_var = sigma * sigma;
    let (mut excess, mut guess) = (0.0, 0.0);
    for (corr, cell) in corrs.iter().zip(cells) {
        let Some((band, var)) = step_of(corr, cell, noise_var) else {
            continue;
        };
        let r = residual(corr).min(band + 3.0 * sigma);
        excess += r * r - noise_var;
        guess += var;
    }
    if guess > 0.0 {
        (excess / guess).clamp(0.0, 1.0)
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn corr(height_m: f64) -> Correspondence {
        Correspondence {
            moving: Vector3::new(0.0, 0.0, height_m),
            reference: Vector3::zeros(),
            normal: Vector3::z(),
            weight: 1.0,
            normal_var: 0.0,
        }
    }

    /// A fit whose final association found no match (a restart on a 64 m
    /// tile's sliver of overlap) has nothing to weigh, and no median to take.
    #[test]
    fn no_matches_weigh_to_none() {
        for metric in [Metric::PointToSurface, Metric::PointToPoint] {
            assert!(weighted(Vec::new(), &[], metric).is_empty());
        }
        assert_eq!(
            weighted(vec![corr(0.5)], &[], Metric::PointToSurface).len(),
            1
        );
    }

    #[test]
    fn rough_places_above_floor_and_three_medians_are_dropped() {
        let corrs: Vec<_> = (0..5).map(|i| corr(i as f64)).collect();
        let rough = [0.1, 0.2, 0.2, 0.3, 5.0];
        let cells: Vec<Cell> = rough
            .iter()
            .map(|&roughness_m| Cell {
                roughness_m,
                ..Cell::default()
            })
            .collect();
        let (kept, kept_cells) = smooth_only(corrs.clone(), &cells, 1.0);
        assert_eq!(kept.len(), 4);
        assert_eq!(kept_cells.len(), 4);
        assert!(kept.iter().all(|c| c.moving.z < 4.0));
        // mismatched lengths: nothing to judge, all kept
        assert_eq!(smooth_only(corrs, &cells[..2], 1.0).0.len(), 5);
    }

    #[test]
    fn tukey_weights_fall_to_zero_for_outliers() {
        let mut corrs: Vec<_> = (0..9).map(|i| corr(0.01 * i as f64)).collect();
        corrs.push(corr(50.0));
        let w = weighted(corrs, &[], Metric::PointToSurface);
        assert_eq!(w[0].weight, 1.0);
        assert!(w[8].weight > 0.5 && w[8].weight < 1.0);
        assert_eq!(w[9].weight, 0.0);
    }

    /// Queries over a wall: the reference pixels say the step lies somewhere
    /// in the cell, so a query at fraction f of it is high with probability f
    /// (residual h (1 - f)) and low otherwise (residual -h f): zero on average.
    /// A weight that falls with the residual favours the low side; judged on
    /// the band of its cell, neither side is favoured.
    #[test]
    fn a_step_cell_weighs_both_sides_of_its_wall_alike() {
        let mut rng = crate::rng::SplitMix64::new(7);
        let (mut corrs, mut cells) = (Vec::new(), Vec::new());
        // smooth ground, most of the overlap: 0.3 m noise sets the weights' scale
        for _ in 0..40_000 {
            corrs.push(corr(0.3 * rng.normal()));
            cells.push(Cell {
                var_m2: 0.045,
                band_m: 0.4,
                ..Cell::default()
            });
        }
        // 3 m walls, queries at fractions 0-0.4 of their cell
        let step = 3.0;
        for _ in 0..20_000 {
            let f = rng.range(0.0, 0.4);
            let high = rng.chance(f);
            let residual = if high { step * (1.0 - f) } else { -step * f };
            corrs.push(corr(residual + 0.3 * rng.normal()));
            cells.push(Cell {
                var_m2: step * step * f * (1.0 - f),
                band_m: step * (1.0 - f),
                ..Cell::default()
            });
        }
        let mean_at_steps = |w: &[Correspondence]| {
            let (sum, weight) = w[40_000..].iter().fold((0.0, 0.0), |(s, n), c| {
                (s + c.weight * c.moving.z, n + c.weight)
            });
            sum / weight
        };
        let plain = mean_at_steps(&weighted(corrs.clone(), &[], Metric::PointToSurface));
        let banded = mean_at_steps(&weighted(corrs, &cells, Metric::PointToSurface));
        assert!(
            plain < -0.2,
            "residual-only weights favour the low side: {plain}"
        );
        assert!(
            banded.abs() < 0.03,
            "the band favours neither side: {banded}"
        );
    }

    /// Steps the two DSMs sample each on its own side show their variance in
    /// the residuals (share 1); steps both DSMs carry as the same ramp do not
    /// (share near 0: the walls are then as exact as flat ground).
    #[test]
    fn the_guess_share_tells_sampled_steps_from_shared_ramps() {
        let mut rng = crate::rng::SplitMix64::new(3);
        let (mut sampled, mut shared, mut cells) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..5000 {
            let f = rng.range(0.0, 1.0);
            let high = rng.chance(f);
            let noise = 0.05 * rng.normal();
            sampled.push(corr(if high { 2.0 * (1.0 - f) } else { -2.0 * f } + noise));
            shared.push(corr(noise));
            cells.push(Cell {
                var_m2: 4.0 * f * (1.0 - f),
                band_m: 2.0 * f.max(1.0 - f),
                ..Cell::default()
            });
        }
        let share = |corrs: &[Correspondence]| {
            guess_share(corrs, &cells, |c| c.plane_residual_m().abs(), 0.05)
        };
        let (s, r) = (share(&sampled), share(&shared));
        assert!(s > 0.9, "sampled steps: {s}");
        assert!(r < 0.01, "shared ramps: {r}");
        // no step cells: nothing to scale down
        assert_eq!(
            guess_share(&sampled, &[], |c| c.plane_residual_m().abs(), 0.05),
            1.0
        );
    }
}
