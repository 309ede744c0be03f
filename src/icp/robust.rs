//! Robust weighting of one iteration's matches: places where the reference is
//! not a surface (walls, tree crowns) are dropped, the rest get Tukey biweights
//! on their residuals.

use super::Metric;
use crate::fit::Correspondence;

/// Drops correspondences on rough places: above both `floor_m` and 3x the
/// median roughness (so steep but smooth terrain at coarse GSD is kept).
pub(super) fn smooth_only(
    corrs: Vec<Correspondence>,
    roughness_m: &[f64],
    floor_m: f64,
) -> Vec<Correspondence> {
    if roughness_m.len() != corrs.len() || corrs.is_empty() {
        return corrs;
    }
    let mut sorted = roughness_m.to_vec();
    let mid = sorted.len() / 2;
    let median = *sorted.select_nth_unstable_by(mid, f64::total_cmp).1;
    let limit = floor_m.max(3.0 * median);
    corrs
        .into_iter()
        .zip(roughness_m)
        .filter(|(_, &r)| r <= limit)
        .map(|(c, _)| c)
        .collect()
}

/// Tukey biweight on the residual, scale from the median absolute residual.
pub(super) fn weighted(mut corrs: Vec<Correspondence>, metric: Metric) -> Vec<Correspondence> {
    let residual = |c: &Correspondence| match metric {
        Metric::PointToPlane | Metric::PointToSurface => c.plane_residual_m().abs(),
        Metric::PointToPoint => (c.moving - c.reference).norm(),
    };
    let mut abs: Vec<f64> = corrs.iter().map(residual).collect();
    let mid = abs.len() / 2;
    let median = *abs.select_nth_unstable_by(mid, f64::total_cmp).1;
    let c = 4.685 * (1.4826 * median).max(0.01);
    for corr in &mut corrs {
        let u = residual(corr) / c;
        corr.weight = if u < 1.0 { (1.0 - u * u).powi(2) } else { 0.0 };
    }
    corrs
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

    #[test]
    fn rough_places_above_floor_and_three_medians_are_dropped() {
        let corrs: Vec<_> = (0..5).map(|i| corr(i as f64)).collect();
        let rough = [0.1, 0.2, 0.2, 0.3, 5.0];
        let kept = smooth_only(corrs.clone(), &rough, 1.0);
        assert_eq!(kept.len(), 4);
        assert!(kept.iter().all(|c| c.moving.z < 4.0));
        // mismatched lengths: nothing to judge, all kept
        assert_eq!(smooth_only(corrs, &rough[..2], 1.0).len(), 5);
    }

    #[test]
    fn tukey_weights_fall_to_zero_for_outliers() {
        let mut corrs: Vec<_> = (0..9).map(|i| corr(0.01 * i as f64)).collect();
        corrs.push(corr(50.0));
        let w = weighted(corrs, Metric::PointToSurface);
        assert_eq!(w[0].weight, 1.0);
        assert!(w[8].weight > 0.5 && w[8].weight < 1.0);
        assert_eq!(w[9].weight, 0.0);
    }
}
