//! Edge weights of the averaging, two ways ([`Weighting`]). The paper's (eq. 3):
//! w_ij = s_ij * r_ij, one weight for rotation and translation. Or inverse variances
//! ("information"): from the pair's one-sigma standard errors (for ICP pairs,
//! [`EdgeSigma::from_fit`]), w_rot = 1 / sigma_rot^2 and w_t = 1 / sigma_t^2, each
//! sigma^2 the mean over the three axes; these are the
//! least-squares weights that make the averaged poses the most likely ones when the
//! pairwise errors are independent with those spreads, so a tight pair counts more
//! than a loose one whatever its overlap or RMSE. Each variance is floored at
//! [`VARIANCE_FLOOR_OF_MEDIAN`] times the median over the edges (no single pair
//! claiming a tiny sigma takes over its neighbourhood), and the weights are scaled
//! to mean 1. A part no pair estimates (all sigmas zero: rotations under the
//! translation model) gets unit weights.

use super::{Edge, EdgeSigma, GraphError};
use crate::fit::FitSigma;
use nalgebra::Vector3;

/// Which weights [`crate::averaging::average`] gets.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Weighting {
    /// w = s_ij * r_ij (the paper's eq. 3), the same for rotation and translation.
    Paper,
    /// Inverse variances from each pair's standard errors.
    #[default]
    Information,
}

impl Weighting {
    pub fn label(self) -> &'static str {
        match self {
            Weighting::Paper => "paper",
            Weighting::Information => "information",
        }
    }
}

impl EdgeSigma {
    /// The standard errors the averaging should believe for a pair registered by
    /// ICP with overlap score s_ij: the fit's sigmas divided by sqrt(s_ij). ICP draws
    /// the same number of samples (`--samples`) from any overlap, and its sandwich
    /// sigma treats their residuals as independent; neighbouring residuals are not
    /// (one building, one tree), so what a pair really knows grows with the overlap
    /// area, not the sample count, and a small overlap is less sure than its sigma
    /// says. Measured on generated chains and grids (README, "align: weights"):
    /// the median |yaw error| / sigma_yaw is about twice as large at s = 0.2 as at
    /// s = 0.6, and about the same once divided by sqrt(s).
    pub fn from_fit(sigma: &FitSigma, overlap: f64) -> Self {
        let inflation = 1.0 / overlap.clamp(1e-3, 1.0).sqrt();
        EdgeSigma::new(
            Vector3::from(sigma.rot_deg).map(|d| d.to_radians() * inflation),
            Vector3::from(sigma.trans_m) * inflation,
        )
    }
}

/// A pair's variance is at least this fraction of the median variance (a sigma at
/// least 0.32 times the median sigma): caps any weight at 10x the median weight.
pub const VARIANCE_FLOOR_OF_MEDIAN: f64 = 0.1;

/// The paper's weights (eq. 3): w_ij = s_ij * r_ij, r_ij = exp(-err_ij) / sum_e exp(-err_e),
/// err = final ICP RMSE in metres. Computed with err - min(err) for stability (same ratio).
/// Rotation and translation get the same weight.
pub fn paper_weights(edges: &mut [Edge]) {
    let min_err = edges.iter().map(|e| e.rmse_m).fold(f64::INFINITY, f64::min);
    let total: f64 = edges.iter().map(|e| (-(e.rmse_m - min_err)).exp()).sum();
    for e in edges.iter_mut() {
        e.weight = e.overlap * (-(e.rmse_m - min_err)).exp() / total;
        e.translation_weight = e.weight;
    }
}

/// Inverse-variance weights (see the module doc); fails, changing nothing, when an
/// edge has no standard errors (or zero ones for its translation, as the
/// point-to-point metric reports) or a non-finite one.
pub fn information_weights(edges: &mut [Edge]) -> Result<(), GraphError> {
    let mut rotation = Vec::with_capacity(edges.len());
    let mut translation = Vec::with_capacity(edges.len());
    for (k, e) in edges.iter().enumerate() {
        let sigma = e.sigma.ok_or(GraphError::MissingSigma { edge: k })?;
        let variance = |v: &nalgebra::Vector3<f64>| v.norm_squared() / 3.0;
        let (vr, vt) = (
            variance(&sigma.rotation_rad()),
            variance(&sigma.translation_m()),
        );
        if !(vr.is_finite() && vt.is_finite()) {
            return Err(GraphError::NotFinite {
                edge: k,
                what: "sigma",
            });
        }
        // Every model estimates the translation: zero there means no sigma at all.
        if vt <= 0.0 {
            return Err(GraphError::MissingSigma { edge: k });
        }
        rotation.push(vr);
        translation.push(vt);
    }
    let rotation = inverse_variances(rotation);
    let translation = inverse_variances(translation);
    for ((e, wr), wt) in edges.iter_mut().zip(rotation).zip(translation) {
        e.weight = wr;
        e.translation_weight = wt;
    }
    Ok(())
}

/// 1 / max(v, floor * median), scaled to mean 1; all ones when the median is 0.
fn inverse_variances(variances: Vec<f64>) -> Vec<f64> {
    let mut sorted = variances.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    if median <= 0.0 {
        return vec![1.0; variances.len()];
    }
    let floor = VARIANCE_FLOOR_OF_MEDIAN * median;
    let weights: Vec<f64> = variances.iter().map(|&v| 1.0 / v.max(floor)).collect();
    let mean = weights.iter().sum::<f64>() / weights.len() as f64;
    weights.into_iter().map(|w| w / mean).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::EdgeSigma;
    use nalgebra::{Matrix4, Vector3};

    fn edge(overlap: f64, rmse_m: f64, sigma: Option<(f64, f64)>) -> Edge {
        Edge {
            sigma: sigma.map(|(r, t)| EdgeSigma::new(Vector3::repeat(r), Vector3::repeat(t))),
            ..Edge::new(0, 1, Matrix4::identity(), overlap, rmse_m)
        }
    }

    #[test]
    fn paper_weights_follow_the_formula_and_survive_large_errors() {
        let mut edges = vec![edge(0.4, 0.5, None), edge(0.8, 1.5, None)];
        paper_weights(&mut edges);
        let z = (-0.5f64).exp() + (-1.5f64).exp();
        assert!((edges[0].weight - 0.4 * (-0.5f64).exp() / z).abs() < 1e-15);
        assert!((edges[1].weight - 0.8 * (-1.5f64).exp() / z).abs() < 1e-15);
        assert_eq!(edges[1].translation_weight, edges[1].weight);
        // Errors of 1000 m would underflow exp(-err) without the shift.
        edges[0].rmse_m = 1000.0;
        edges[1].rmse_m = 1001.0;
        paper_weights(&mut edges);
        let z = 1.0 + (-1.0f64).exp();
        assert!((edges[0].weight - 0.4 / z).abs() < 1e-15);
        assert!(edges[1].weight > 0.0);
    }

    #[test]
    fn information_weights_are_inverse_variances_with_a_floor() {
        // Rotation sigmas 1, 2, 2, 0.1 (x 1e-5 rad): median variance 4, floor 0.4,
        // so the 0.1 edge counts as variance 0.4. Translation sigmas all 0.01 m: equal weights.
        let mut edges: Vec<Edge> = [1.0, 2.0, 2.0, 0.1]
            .iter()
            .map(|&r| edge(0.5, 0.3, Some((r * 1e-5, 0.01))))
            .collect();
        information_weights(&mut edges).unwrap();
        let raw = [1.0, 0.25, 0.25, 2.5];
        let mean = raw.iter().sum::<f64>() / 4.0;
        for (e, r) in edges.iter().zip(raw) {
            assert!(
                (e.weight - r / mean).abs() < 1e-12,
                "{} vs {}",
                e.weight,
                r / mean
            );
            assert!((e.translation_weight - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn fit_sigmas_grow_as_the_overlap_shrinks() {
        let fit = FitSigma {
            rot_deg: [0.001, 0.002, 0.01],
            trans_m: [0.02, 0.01, 0.002],
        };
        let full = EdgeSigma::from_fit(&fit, 1.0);
        // stored as f32: seven digits
        let close = |a: Vector3<f64>, b: Vector3<f64>| (a - b).norm() <= 1e-7 * b.norm();
        assert!(close(
            full.rotation_rad(),
            Vector3::new(0.001, 0.002, 0.01).map(f64::to_radians)
        ));
        assert!(close(full.translation_m(), Vector3::new(0.02, 0.01, 0.002)));
        let quarter = EdgeSigma::from_fit(&fit, 0.25);
        assert!(close(quarter.rotation_rad(), full.rotation_rad() * 2.0));
        assert!(close(quarter.translation_m(), full.translation_m() * 2.0));
        // A zero overlap (never an edge, but no division by zero either).
        assert!(EdgeSigma::from_fit(&fit, 0.0)
            .translation_m()
            .iter()
            .all(|v| v.is_finite()));
    }

    #[test]
    fn missing_or_unestimated_sigmas() {
        let mut edges = vec![edge(0.5, 0.3, Some((1e-5, 0.01))), edge(0.5, 0.3, None)];
        let before = edges.clone();
        assert_eq!(
            information_weights(&mut edges),
            Err(GraphError::MissingSigma { edge: 1 })
        );
        assert_eq!(edges, before);
        // Zero translation sigmas: not estimated (point-to-point).
        let mut edges = vec![edge(0.5, 0.3, Some((1e-5, 0.0)))];
        assert_eq!(
            information_weights(&mut edges),
            Err(GraphError::MissingSigma { edge: 0 })
        );
        // The translation model estimates no rotation: unit rotation weights.
        let mut edges = vec![
            edge(0.5, 0.3, Some((0.0, 0.01))),
            edge(0.5, 0.3, Some((0.0, 0.02))),
        ];
        information_weights(&mut edges).unwrap();
        assert_eq!((edges[0].weight, edges[1].weight), (1.0, 1.0));
        assert!((edges[0].translation_weight / edges[1].translation_weight - 4.0).abs() < 1e-12);
    }
}
