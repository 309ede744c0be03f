//! Closed-form and linearised rigid fits from weighted correspondences.
//!
//! - [`point_to_plane`]: minimises sum w (n . (R q + t - p))^2, linearised for a
//!   small rotation about the centroid of the moving points (one Gauss-Newton
//!   step per ICP iteration). Sliding along the surface is free, so sub-pixel
//!   horizontal offsets are observable wherever the surface has slopes or walls,
//!   which plain point-to-point matching on the pixel lattice cannot resolve.
//! - [`point_to_point`]: weighted Kabsch/Umeyama with a reflection guard, the
//!   paper's original fit.
//!
//! Both return the update as an isometry in the caller's (local) frame, and the
//! point-to-plane fit also reports how well each direction is constrained; it
//! holds directions it cannot see at their current value, and [`information`]
//! says what the final fit knows (6x6 information, per-axis sigmas, degenerate axes).

pub mod information;

pub use information::{
    fit_information, fit_information_with, Axis, DegeneracyRule, FitInformation, RotationPrior,
    WallSnap,
};

use information::{constrained_directions, pseudo_inverse, NormalEquations};
#[cfg(test)]
use nalgebra::Vector6;
use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3};

/// What the fit may change.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    /// Rotation and translation (6 degrees of freedom).
    Rigid,
    /// Translation only (3 degrees of freedom).
    Translation,
}

/// One matched pair: a moving point (already mapped by the current estimate),
/// its nearest reference point and the reference surface normal there.
#[derive(Clone, Copy, Debug)]
pub struct Correspondence {
    pub moving: Vector3<f64>,
    pub reference: Vector3<f64>,
    pub normal: Vector3<f64>,
    pub weight: f64,
    /// Variance of each horizontal component of `normal` that is noise of the
    /// reference heights it was fitted to (0: an exact normal). The final
    /// information takes it out (errors in variables, see
    /// [`information`]): a flat, noisy strip's random normals otherwise pass
    /// for information along the strip.
    pub normal_var: f64,
}

impl Correspondence {
    /// Signed point-to-plane residual in metres.
    pub fn plane_residual_m(&self) -> f64 {
        self.normal.dot(&(self.moving - self.reference))
    }
}

/// A fitted update and how well it is constrained.
#[derive(Clone, Copy, Debug)]
pub struct FitUpdate {
    /// Maps the moving points (as given) closer to the reference.
    pub update: Isometry3<f64>,
    /// Smallest over largest eigenvalue of the scale-normalised normal matrix:
    /// near zero when some direction is unconstrained (flat terrain).
    pub constraint_ratio: f64,
    /// Smallest eigenvalue's direction in (rx, ry, rz, tx, ty, tz) order.
    pub weakest_direction: [f64; 6],
    /// Standard errors of this step's estimate (see [`FitSigma`]).
    pub sigma: FitSigma,
}

/// One-sigma standard errors of a point-to-plane fit, from the sandwich
/// covariance H^-1 (sum w^2 r^2 a a^T) H^-1 of the weighted least squares: the
/// spread the estimate would have over other noise draws, if the residuals of
/// different correspondences are independent. Rotations about the local x, y
/// (tilt) and z (yaw) axes; translations at the weighted centroid of the moving
/// points. Zero where the model does not estimate that parameter.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FitSigma {
    pub rot_deg: [f64; 3],
    pub trans_m: [f64; 3],
}

/// One linearised point-to-plane step, holding only numerically singular
/// directions ([`DegeneracyRule::NUMERICAL`]). None when there are too few
/// correspondences or no direction is constrained.
pub fn point_to_plane(corrs: &[Correspondence], model: Model) -> Option<FitUpdate> {
    point_to_plane_with(corrs, model, &DegeneracyRule::NUMERICAL)
}

/// One linearised point-to-plane step whose update is projected onto the directions
/// `rule` calls well constrained: the others keep their current value
/// (see [`information`]).
pub fn point_to_plane_with(
    corrs: &[Correspondence],
    model: Model,
    rule: &DegeneracyRule,
) -> Option<FitUpdate> {
    point_to_plane_prior(corrs, model, rule, None)
}

/// [`point_to_plane_with`] with a prior on the rotation ([`RotationPrior`]).
pub fn point_to_plane_prior(
    corrs: &[Correspondence],
    model: Model,
    rule: &DegeneracyRule,
    prior: Option<&RotationPrior>,
) -> Option<FitUpdate> {
    let eq = NormalEquations::new(corrs, rule)?.with_rotation_prior(prior);
    let (h, g, radius) = (eq.h, eq.g, eq.radius_m);
    let (ratio, weakest) = match model {
        Model::Rigid => conditioning(&h)?,
        Model::Translation => {
            let h3: Matrix3<f64> = h.fixed_view::<3, 3>(3, 3).into_owned();
            let (ratio, w3) = conditioning3(&h3)?;
            (ratio, [0.0, 0.0, 0.0, w3[0], w3[1], w3[2]])
        }
    };
    let (eig, keep) = constrained_directions(&eq, model, rule);
    if !keep.iter().any(|&k| k) {
        return None;
    }
    let x = -(pseudo_inverse(&eig, &keep) * g);
    let sigma = sandwich_sigma(&h, &eq.meat, model, radius);
    let omega = Vector3::new(x[0], x[1], x[2]) / radius;
    let t = Vector3::new(x[3], x[4], x[5]);
    let rotation = UnitQuaternion::from_scaled_axis(omega);
    // q -> R (q - c) + c + t
    let translation = eq.centroid + t - rotation * eq.centroid;
    Some(FitUpdate {
        update: Isometry3::from_parts(Translation3::from(translation), rotation),
        constraint_ratio: ratio,
        weakest_direction: weakest,
        sigma,
    })
}

/// Standard errors from the sandwich covariance (see [`FitSigma`]); the
/// rotation block is unscaled by `radius_m` back to radians.
fn sandwich_sigma(h: &Matrix6<f64>, meat: &Matrix6<f64>, model: Model, radius_m: f64) -> FitSigma {
    let (lo, n) = match model {
        Model::Rigid => (0, 6),
        Model::Translation => (3, 3),
    };
    let hs = h.view((lo, lo), (n, n)).into_owned();
    let ms = meat.view((lo, lo), (n, n)).into_owned();
    let Some(inv) = hs.try_inverse() else {
        return FitSigma::default();
    };
    let cov = &inv * ms * &inv;
    let mut sigma = FitSigma::default();
    for k in 0..n {
        let sd = cov[(k, k)].max(0.0).sqrt();
        match lo + k {
            i @ 0..=2 => sigma.rot_deg[i] = (sd / radius_m).to_degrees(),
            i => sigma.trans_m[i - 3] = sd,
        }
    }
    sigma
}

/// Smallest over largest eigenvalue of a 6x6 symmetric H and the smallest one's
/// direction; None when H has no positive eigenvalue.
fn conditioning(h: &Matrix6<f64>) -> Option<(f64, [f64; 6])> {
    let eig = h.symmetric_eigen();
    let (imin, max) = (eig.eigenvalues.imin(), eig.eigenvalues.max());
    if max <= 0.0 {
        return None;
    }
    let mut weakest = [0.0; 6];
    for (k, w) in weakest.iter_mut().enumerate() {
        *w = eig.eigenvectors[(k, imin)];
    }
    Some(((eig.eigenvalues[imin] / max).max(0.0), weakest))
}

fn conditioning3(h: &Matrix3<f64>) -> Option<(f64, [f64; 3])> {
    let eig = h.symmetric_eigen();
    let (imin, max) = (eig.eigenvalues.imin(), eig.eigenvalues.max());
    if max <= 0.0 {
        return None;
    }
    let v = eig.eigenvectors.column(imin);
    Some(((eig.eigenvalues[imin] / max).max(0.0), [v[0], v[1], v[2]]))
}

/// Weighted Kabsch/Umeyama: the rigid motion minimising sum w |R q + t - p|^2,
/// with the reflection guard (det R = +1).
pub fn point_to_point(corrs: &[Correspondence], model: Model) -> Option<Isometry3<f64>> {
    let total_w: f64 = corrs.iter().map(|c| c.weight).sum();
    if corrs.len() < 3 || total_w <= 0.0 {
        return None;
    }
    let cq = corrs
        .iter()
        .map(|c| c.moving * c.weight)
        .sum::<Vector3<f64>>()
        / total_w;
    let cp = corrs
        .iter()
        .map(|c| c.reference * c.weight)
        .sum::<Vector3<f64>>()
        / total_w;
    if model == Model::Translation {
        return Some(Isometry3::from_parts(
            Translation3::from(cp - cq),
            UnitQuaternion::identity(),
        ));
    }
    let mut cov = Matrix3::<f64>::zeros();
    for c in corrs {
        cov += c.weight * (c.reference - cp) * (c.moving - cq).transpose();
    }
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = u * d * v_t;
    let rotation = UnitQuaternion::from_matrix(&r);
    let t = cp - rotation * cq;
    Some(Isometry3::from_parts(Translation3::from(t), rotation))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wavy_surface(n: usize) -> Vec<(Vector3<f64>, Vector3<f64>)> {
        // points on z = sin(x/3) + cos(y/4), with analytic normals
        let mut out = Vec::new();
        for i in 0..n {
            for j in 0..n {
                let (x, y) = (i as f64 - n as f64 / 2.0, j as f64 - n as f64 / 2.0);
                let z = (x / 3.0).sin() * 3.0 + (y / 4.0).cos() * 2.0;
                let dzdx = (x / 3.0).cos();
                let dzdy = -(y / 4.0).sin() * 0.5;
                out.push((
                    Vector3::new(x, y, z),
                    Vector3::new(-dzdx, -dzdy, 1.0).normalize(),
                ));
            }
        }
        out
    }

    fn apply(m: &Isometry3<f64>, p: &Vector3<f64>) -> Vector3<f64> {
        m.transform_point(&nalgebra::Point3::from(*p)).coords
    }

    fn truth() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.3, -0.2, 0.5),
            UnitQuaternion::from_euler_angles(0.001, -0.0005, 0.002),
        )
    }

    #[test]
    fn kabsch_recovers_exact_motion_and_its_inverse() {
        let pts = wavy_surface(20);
        let t = truth();
        for motion in [t, t.inverse()] {
            let corrs: Vec<_> = pts
                .iter()
                .map(|(p, n)| Correspondence {
                    moving: apply(&motion.inverse(), p),
                    reference: *p,
                    normal: *n,
                    weight: 1.0,
                    normal_var: 0.0,
                })
                .collect();
            let fit = point_to_point(&corrs, Model::Rigid).unwrap();
            let err = fit.inverse() * motion;
            assert!(err.translation.vector.norm() < 1e-9 && err.rotation.angle() < 1e-12);
        }
    }

    #[test]
    fn point_to_plane_converges_on_exact_planes() {
        let pts = wavy_surface(30);
        let t = truth();
        // moving points are the reference points moved by t^-1; iterate the
        // linearised step with the true (tangent-plane) correspondences.
        let mut estimate = Isometry3::identity();
        for _ in 0..5 {
            let corrs: Vec<_> = pts
                .iter()
                .map(|(p, n)| Correspondence {
                    moving: apply(&estimate, &apply(&t.inverse(), p)),
                    reference: *p,
                    normal: *n,
                    weight: 1.0,
                    normal_var: 0.0,
                })
                .collect();
            let step = point_to_plane(&corrs, Model::Rigid).unwrap();
            estimate = step.update * estimate;
        }
        let err = estimate.inverse() * t;
        assert!(err.translation.vector.norm() < 1e-8, "{err:?}");
        assert!(err.rotation.angle() < 1e-10);
    }

    /// The reported sigma matches the spread of the estimate over noise draws.
    #[test]
    fn sigma_matches_the_spread_over_noise_draws() {
        let pts = wavy_surface(30);
        let mut rng = crate::rng::SplitMix64::new(7);
        let draws: Vec<(Vector6<f64>, FitSigma)> = (0..200)
            .map(|_| {
                let corrs: Vec<_> = pts
                    .iter()
                    .map(|(p, n)| Correspondence {
                        moving: p + Vector3::z() * 0.3 * rng.normal(),
                        reference: *p,
                        normal: *n,
                        weight: 1.0,
                        normal_var: 0.0,
                    })
                    .collect();
                let fit = point_to_plane(&corrs, Model::Rigid).unwrap();
                let (r, t) = (
                    fit.update.rotation.scaled_axis(),
                    fit.update.translation.vector,
                );
                (
                    Vector6::new(
                        r.x.to_degrees(),
                        r.y.to_degrees(),
                        r.z.to_degrees(),
                        t.x,
                        t.y,
                        t.z,
                    ),
                    fit.sigma,
                )
            })
            .collect();
        let n = draws.len() as f64;
        for k in 0..6 {
            let mean = draws.iter().map(|d| d.0[k]).sum::<f64>() / n;
            let spread = (draws.iter().map(|d| (d.0[k] - mean).powi(2)).sum::<f64>() / n).sqrt();
            let reported = draws
                .iter()
                .map(|d| {
                    if k < 3 {
                        d.1.rot_deg[k]
                    } else {
                        d.1.trans_m[k - 3]
                    }
                })
                .sum::<f64>()
                / n;
            assert!(
                reported > 0.7 * spread && reported < 1.4 * spread,
                "parameter {k}: reported {reported}, spread {spread}"
            );
        }
    }

    #[test]
    fn flat_plane_is_reported_unconstrained() {
        let corrs: Vec<_> = (0..400)
            .map(|i| {
                let p = Vector3::new((i % 20) as f64, (i / 20) as f64, 0.0);
                Correspondence {
                    moving: p + Vector3::new(0.1, 0.0, 0.2),
                    reference: p,
                    normal: Vector3::z(),
                    weight: 1.0,
                    normal_var: 0.0,
                }
            })
            .collect();
        // singular in x/y translation: cholesky fails or ratio ~ 0
        if let Some(fit) = point_to_plane(&corrs, Model::Rigid) {
            assert!(fit.constraint_ratio < 1e-9);
        }
    }
}
