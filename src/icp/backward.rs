//! The backward check of a pair: the reference DSM registered onto the moving
//! one, at full resolution, starting from the inverse of the forward answer.
//!
//! Point-to-surface ICP compares points of the moving DSM with the bilinear
//! surface of the reference, so the two directions see different samplings of
//! the same ground. Where the data pin the transform down (a wide overlap, sharp
//! relief) both directions agree to millimetres; on a narrow strip of small
//! tiles the cost is shallow along a yaw-and-shift valley and each direction can
//! settle a few decimetres and a fraction of a degree away from the truth, with
//! a sandwich standard error of centimetres that only measures the noise of its
//! own minimum. Measured on a 20 x 20 grid of 128 m tiles (docs/measurements.md,
//! "backward check"), the forward-backward disagreement tracks that error: it is
//! the part of the uncertainty the noise model cannot see.
//!
//! So when the two answers differ by more than their own noise explains on
//! some axis, the pair reports their midpoint and adds the excess squared
//! disagreement of each axis to that axis's variance (a model-error term);
//! when they agree within the noise, the forward answer and sigmas stand.

use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

use super::level::Level;
use super::start::moved_overlap;
use super::{config, final_rule, BackwardCheck, IcpConfig, IcpError, IcpResult, Rules};
use crate::fit::FitInformation;
use crate::geo::rigid::isometry_to_world;
use crate::grid::Pyramid;

/// The reference registered onto the moving DSM from the inverse of `forward`
/// (the reference's points are sampled, the moving DSM is the surface); the
/// result maps reference points into the moving DSM (p_moving = T p_ref).
pub(super) fn register_backward<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
    forward: &IcpResult,
    (pixel_m, radius_m): (f64, f64),
) -> Result<IcpResult, IcpError> {
    let t_start_world = forward.t_ref_moving.inverse();
    let centre = Vector3::from(forward.centre_m);
    let shift = t_start_world.transform_point(&centre.into()).coords - centre;
    let sampled = if shift.xy().norm() < config::PAPER_TAU_M {
        Vector3::zeros()
    } else {
        shift
    };
    let overlap = moved_overlap(moving, reference, &sampled)?.ok_or(IcpError::NoOverlap)?;
    let (centre_x, centre_y) = overlap.centre();
    let origin_xy = Vector3::new(centre_x, centre_y, 0.0);
    let level = Level::sample(moving, reference, 0, &overlap, &origin_xy, config)?;
    let origin = level.origin(&origin_xy);
    let t_start = isometry_to_world(&t_start_world, &-origin);
    let rules = Rules {
        degeneracy: final_rule(pixel_m),
        start: t_start,
        cap_m: radius_m,
    };
    let tau_m = config.tau_at(0, pixel_m, f64::NAN);
    let outcome = level.run(&origin, t_start, tau_m, &rules)?;
    let information = outcome.information(config, &final_rule(pixel_m));
    Ok(outcome.into_result(&origin, information))
}

/// How far the forward answer and the inverse of the backward one are apart,
/// at the forward fit's centroid: translation (metres) and rotation vector
/// (radians), axes of the CRS. Also the midpoint of the two answers.
pub(super) struct Disagreement {
    pub shift_m: Vector3<f64>,
    pub rotation_rad: Vector3<f64>,
    pub midpoint: Isometry3<f64>,
}

impl Disagreement {
    /// `forward` maps moving -> reference, `backward` reference -> moving.
    pub fn between(forward: &Isometry3<f64>, backward: &Isometry3<f64>, at: &Vector3<f64>) -> Self {
        let local = |t: &Isometry3<f64>| isometry_to_world(t, &-at);
        let f = local(forward);
        let b = local(&backward.inverse());
        let d = f.inverse() * b;
        let shift_m = d.translation.vector;
        let rotation_rad = d.rotation.scaled_axis();
        let half = Isometry3::from_parts(
            Translation3::from(shift_m * 0.5),
            UnitQuaternion::from_scaled_axis(rotation_rad * 0.5),
        );
        Disagreement {
            shift_m,
            rotation_rad,
            midpoint: isometry_to_world(&(f * half), at),
        }
    }

    /// Per-axis variance to add, (x, y, z, roll, pitch, yaw) in m^2 and rad^2:
    /// the squared gap beyond what the two fits' own noise (`noise`, the sum
    /// of their variances per axis) explains. Two well-posed fits differ by
    /// their noise alone and add nothing; a gap of many sigmas is model error.
    pub fn variance(&self, noise: &Vector6<f64>) -> Vector6<f64> {
        let (s, r) = (&self.shift_m, &self.rotation_rad);
        let gap = Vector6::new(s.x, s.y, s.z, r.x, r.y, r.z).map(|v| v * v);
        (gap - noise).map(|v| v.max(0.0))
    }
}

/// `forward` moved to the midpoint, with the part of `disagreement` that the
/// noise of the two fits does not explain added to its variances.
pub(super) fn reconcile(
    mut forward: IcpResult,
    backward: &IcpResult,
    disagreement: &Disagreement,
) -> IcpResult {
    let status = backward.status;
    let (s, r) = (&disagreement.shift_m, &disagreement.rotation_rad);
    forward.backward = Some(BackwardCheck {
        shift_m: [s.x, s.y, s.z],
        rotation_deg: [r.x.to_degrees(), r.y.to_degrees(), r.z.to_degrees()],
        status,
    });
    let diagonal = |r: &IcpResult| r.information.as_ref().map(|i| i.covariance_6x6.diagonal());
    if let Some(f) = diagonal(&forward) {
        let noise = f + diagonal(backward).unwrap_or(f);
        let extra = disagreement.variance(&noise);
        // agreement within the noise: the forward answer and its sigmas stand
        if extra.iter().any(|&v| v > 0.0) {
            forward.t_ref_moving = disagreement.midpoint;
            if let Some(info) = forward.information.as_mut() {
                inflate(info, &extra);
            }
        }
    }
    forward
}

/// Adds `extra` (per-axis variances, physical units) to the covariance of
/// `info` on the directions it measures (held directions keep no information);
/// its information and standard errors follow.
pub(crate) fn inflate(info: &mut FitInformation, extra: &Vector6<f64>) {
    let range = range_projector(&info.covariance_6x6);
    info.covariance_6x6 += range * Matrix6::from_diagonal(extra) * range;
    info.covariance_6x6 = (info.covariance_6x6 + info.covariance_6x6.transpose()) * 0.5;
    info.info_6x6 = pseudo_inverse(&info.covariance_6x6);
    for k in 0..6 {
        if info.sigma[k].is_some() {
            let sd = info.covariance_6x6[(k, k)].max(0.0).sqrt();
            info.sigma[k] = Some(if k < 3 { sd } else { sd.to_degrees() });
        }
    }
}

/// Relative eigenvalue below which a covariance direction counts as empty.
const EMPTY: f64 = 1e-12;

/// The orthogonal projector onto the directions `c` gives a variance.
fn range_projector(c: &Matrix6<f64>) -> Matrix6<f64> {
    let eig = c.symmetric_eigen();
    let max = eig.eigenvalues.amax();
    let mut p = Matrix6::zeros();
    for k in (0..6).filter(|&k| max > 0.0 && eig.eigenvalues[k] > EMPTY * max) {
        let v = eig.eigenvectors.column(k);
        p += v * v.transpose();
    }
    p
}

fn pseudo_inverse(c: &Matrix6<f64>) -> Matrix6<f64> {
    let eig = c.symmetric_eigen();
    let max = eig.eigenvalues.amax();
    let mut inv = Matrix6::zeros();
    for k in (0..6).filter(|&k| max > 0.0 && eig.eigenvalues[k] > EMPTY * max) {
        let v = eig.eigenvectors.column(k);
        inv += v * v.transpose() / eig.eigenvalues[k];
    }
    inv
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::Axis;

    #[test]
    fn agreeing_directions_add_nothing_and_keep_the_answer() {
        let at = Vector3::new(500_000.0, 4_800_000.0, 200.0);
        let t = isometry_to_world(
            &Isometry3::from_parts(
                Translation3::new(1.0, -2.0, 0.5),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.001),
            ),
            &at,
        );
        let d = Disagreement::between(&t, &t.inverse(), &at);
        assert!(d.variance(&Vector6::zeros()).norm() < 1e-18);
        let p = nalgebra::Point3::from(at);
        assert!((d.midpoint.transform_point(&p) - t.transform_point(&p)).norm() < 1e-6);
    }

    #[test]
    fn the_disagreement_is_measured_at_the_centroid_and_split_in_half() {
        let at = Vector3::new(500_000.0, 4_800_000.0, 200.0);
        let forward = isometry_to_world(&Isometry3::translation(1.0, 0.0, 0.0), &at);
        // the backward answer, inverted, sits 0.2 m further east and turned 0.01 rad
        let other = isometry_to_world(
            &Isometry3::from_parts(
                Translation3::new(1.2, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.01),
            ),
            &at,
        );
        let d = Disagreement::between(&forward, &other.inverse(), &at);
        assert!((d.shift_m - Vector3::new(0.2, 0.0, 0.0)).norm() < 1e-9);
        assert!((d.rotation_rad.z - 0.01).abs() < 1e-12);
        // a gap the two fits' noise explains adds nothing; beyond it, the excess
        let v = d.variance(&Vector6::new(0.05, 0.0, 0.0, 0.0, 0.0, 1e-3));
        assert_eq!((v[0], v[5]), (0.0, 0.0));
        let v = d.variance(&Vector6::new(0.03, 0.0, 0.0, 0.0, 0.0, 0.0));
        assert!((v[0] - 0.01).abs() < 1e-9 && (v[5] - 1e-4).abs() < 1e-12);
        let p = nalgebra::Point3::from(at);
        let mid = d.midpoint.transform_point(&p) - p;
        assert!((mid.x - 1.1).abs() < 1e-6 && mid.y.abs() < 1e-6, "{mid}");
    }

    #[test]
    fn inflation_adds_variance_to_measured_axes_only() {
        let mut info = FitInformation {
            info_6x6: Matrix6::from_diagonal(&Vector6::new(100.0, 100.0, 0.0, 1e4, 1e4, 1e4)),
            covariance_6x6: Matrix6::from_diagonal(&Vector6::new(
                0.01, 0.01, 0.0, 1e-4, 1e-4, 1e-4,
            )),
            sigma: [
                Some(0.1),
                Some(0.1),
                None,
                Some(0.01f64.to_degrees()),
                Some(0.01f64.to_degrees()),
                Some(0.01f64.to_degrees()),
            ],
            degenerate: vec![Axis::Z],
            centroid: Vector3::zeros(),
            effective_samples: 100.0,
        };
        inflate(&mut info, &Vector6::new(0.03, 0.0, 5.0, 0.0, 0.0, 3e-4));
        assert!((info.sigma[0].unwrap() - 0.2).abs() < 1e-12);
        assert!((info.sigma[1].unwrap() - 0.1).abs() < 1e-12);
        assert_eq!(info.sigma[2], None);
        assert!((info.sigma[5].unwrap() - 0.02f64.to_degrees()).abs() < 1e-9);
        assert!((info.info_6x6[(0, 0)] - 25.0).abs() < 1e-9);
        assert_eq!(info.info_6x6[(2, 2)], 0.0);
        assert_eq!(info.covariance_6x6[(2, 2)], 0.0);
    }
}
