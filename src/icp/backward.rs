//! The backward check of a pair: the reference DSM registered onto the moving
//! one, at full resolution, starting from the inverse of the forward answer.
//!
//! Point-to-surface ICP compares points of the moving DSM with the bilinear
//! surface of the reference, so the two directions see different samplings of
//! the same ground. Where the data pin the transform down (a wide overlap, sharp
//! relief) both directions agree within their noise; on a narrow strip of small
//! tiles the cost is shallow along a yaw-and-shift valley and each direction can
//! settle a few decimetres and a fraction of a degree away from the truth, with
//! a sandwich standard error of centimetres that only measures the noise of its
//! own minimum. On a 20 x 20 grid of 128 m tiles the forward-backward gap
//! tracks that error (docs/notes/backward.md): it is the part of the
//! uncertainty the noise model cannot see.
//!
//! The gap (a 6-vector at the forward fit's centroid) is tested against the
//! covariance of two fits that see only noise (the sum of theirs): within the
//! 0.999 chi-square quantile the forward answer and its covariance stand, so
//! well-posed pairs are left exactly as they were. Beyond it, the forward
//! answer stays (the midpoint of the two was no closer to the truth, measured)
//! and the gap is added to its covariance along the gap's own direction,
//! sized so that the gap becomes one standard deviation.
//!
//! The two directions see different samplings of the overlap, and the
//! sandwich covariance of each is an estimate from its own samples: on sparse
//! lidar (Tommy Thompson Park's, 0.5 returns per m^2 per DSM) the backward
//! fit's standard error was up to 5-12 times the forward one's along y for
//! pairs whose answers were right, and one forward answer 2.1 m off in y
//! reported 0.26 m (8 sigma; its backward fit said 1.18 m). The pair's covariance is
//! therefore at least the backward fit's (moved to the forward centroid), in
//! every direction the forward fit measures: the least addition that covers
//! it ([`excess_over`]). A pair is as uncertain as the weaker of its two
//! directions says, and swapping the reference and the moving DSM no longer
//! changes its sigmas by such factors.
//!
//! Two ends of the backward run say the forward answer is not a place the
//! data agree on from both sides, whatever the gap: a run still sliding when
//! its iterations ran out with a gap beyond the noise (it had not found the
//! bottom, so its gap understates the disagreement), and a run that held a
//! direction the forward fit measured (from the reference's side the overlap
//! does not fix it). Such an answer is not confirmed (`confirms: false`) and
//! the pair becomes `Ambiguous` (`choice::unconfirmed`). Both were rare and
//! wrong where measured: of 4,280 converged pairs (the 20 x 20 grid of 128 m
//! tiles, the 50 x 50 grid of 64 m tiles and 160 battery collections) the
//! first ended 2 pairs (39 m off at 14 sigma; 8 m off), the second 2 (18 and
//! 21 m off at 16-21 sigma, their gaps 0.02-4.8 m).

use nalgebra::{Isometry3, Matrix6, Vector3, Vector6};

use super::level::full_resolution;
use super::{BackwardCheck, IcpConfig, IcpError, IcpResult, IcpStatus};
use crate::fit::information::standard_error;
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
    let start = forward.t_ref_moving.inverse();
    let centre = Vector3::from(forward.centre_m);
    // the rotation prior holds to the start, the inverse of the forward answer
    full_resolution(
        moving,
        reference,
        config,
        (&start, start.rotation),
        &centre,
        (pixel_m, radius_m),
    )
}

/// How far the forward answer and the inverse of the backward one are apart,
/// at the forward fit's centroid: translation (metres) and rotation vector
/// (radians), axes of the CRS.
pub(super) struct Disagreement {
    pub shift_m: Vector3<f64>,
    pub rotation_rad: Vector3<f64>,
}

impl Disagreement {
    /// `forward` maps moving -> reference, `backward` reference -> moving.
    pub fn between(forward: &Isometry3<f64>, backward: &Isometry3<f64>, at: &Vector3<f64>) -> Self {
        let local = |t: &Isometry3<f64>| isometry_to_world(t, &-at);
        let d = local(forward).inverse() * local(&backward.inverse());
        Disagreement {
            shift_m: d.translation.vector,
            rotation_rad: d.rotation.scaled_axis(),
        }
    }

    /// The gap as one 6-vector (x, y, z [m], roll, pitch, yaw [rad]).
    pub fn gap(&self) -> Vector6<f64> {
        let (s, r) = (&self.shift_m, &self.rotation_rad);
        Vector6::new(s.x, s.y, s.z, r.x, r.y, r.z)
    }

    /// The gap against `joint`, the covariance of the difference of two fits
    /// that see only noise: its squared Mahalanobis length over the directions
    /// `joint` measures, and their number.
    pub fn test(&self, joint: &Matrix6<f64>) -> GapTest {
        let (inverse, dof) = pseudo_inverse(joint);
        let gap = self.gap();
        GapTest {
            chi_square: (gap.transpose() * inverse * gap)[(0, 0)],
            dof,
        }
    }

    /// The covariance to add when the gap is not noise: rank one along the
    /// gap, sized so that the gap becomes one standard deviation of `joint`
    /// plus the addition (Sherman-Morrison: g' (J + k g g')^-1 g = c / (1 + k c)
    /// with c the chi-square, so k = 1 - 1/c). The model error lies along the
    /// direction the two fits slid apart (a yaw-and-shift valley), not on
    /// every axis at once.
    pub fn model_error(&self, test: &GapTest) -> Matrix6<f64> {
        let gap = self.gap();
        gap * gap.transpose() * (1.0 - 1.0 / test.chi_square).max(0.0)
    }
}

/// A forward-backward gap tested against the two fits' noise.
#[derive(Clone, Copy, Debug)]
pub(super) struct GapTest {
    pub chi_square: f64,
    /// Directions the joint covariance measures (1-6).
    pub dof: usize,
}

/// Chi-square quantiles at 0.999 for 1-6 degrees of freedom: a gap this far
/// out is not the noise of two well-posed fits (1 in 1000 would be).
const CHI_SQUARE_0_999: [f64; 6] = [10.828, 13.816, 16.266, 18.467, 20.515, 22.458];

impl GapTest {
    /// More than the two fits' noise explains (beyond the 0.999 quantile).
    pub fn beyond_noise(&self) -> bool {
        self.dof > 0 && self.chi_square > CHI_SQUARE_0_999[self.dof - 1]
    }
}

/// The covariance of forward minus inverse backward under noise alone: the
/// sum of the two fits' covariances, the backward one moved from its
/// centroid (on the moving DSM, taken into the reference by `forward`) to the
/// forward centroid (the translation at c is the one at c' plus w x (c - c')).
/// The two directions share their ground and noise, so this sum overstates
/// the spread of their gap: the test errs towards leaving a pair alone.
pub(super) fn joint_covariance(
    forward: &FitInformation,
    backward: &FitInformation,
    t_ref_moving: &Isometry3<f64>,
) -> Matrix6<f64> {
    let centroid = t_ref_moving
        .transform_point(&backward.centroid.into())
        .coords;
    let lever = forward.centroid - centroid;
    let mut move_to = Matrix6::identity();
    move_to
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&-lever.cross_matrix());
    forward.covariance_6x6 + move_to * backward.covariance_6x6 * move_to.transpose()
}

/// The forward answer with the backward check recorded; when the gap to the
/// backward answer is beyond the two fits' noise, the gap is added to its
/// covariance; then the covariance is raised to cover the backward fit's.
pub(super) fn reconcile(
    mut forward: IcpResult,
    backward: &IcpResult,
    disagreement: &Disagreement,
) -> IcpResult {
    let test = forward.information.as_ref().map(|info| {
        let joint = match &backward.information {
            Some(b) => joint_covariance(info, b, &forward.t_ref_moving),
            None => info.covariance_6x6 * 2.0,
        };
        disagreement.test(&joint)
    });
    let (s, r) = (&disagreement.shift_m, &disagreement.rotation_rad);
    forward.backward = Some(BackwardCheck {
        shift_m: [s.x, s.y, s.z],
        rotation_deg: [r.x.to_degrees(), r.y.to_degrees(), r.z.to_degrees()],
        status: backward.status,
        chi_square: test.map(|t| t.chi_square),
        beyond_noise: test.is_some_and(|t| t.beyond_noise()),
        confirms: confirms(&forward, backward, test.is_some_and(|t| t.beyond_noise())),
    });
    // within the noise: the forward covariance stands
    if let (Some(test), Some(info)) = (test, forward.information.as_mut()) {
        if test.beyond_noise() {
            inflate(info, &disagreement.model_error(&test));
        }
    }
    // the pair is as uncertain as the weaker of its two directions says
    let backward_at_forward = match (&forward.information, &backward.information) {
        (Some(f), Some(b)) => Some(moved_backward(f, b, &forward.t_ref_moving)),
        _ => None,
    };
    if let (Some(b), Some(info)) = (backward_at_forward, forward.information.as_mut()) {
        let excess = excess_over(&info.covariance_6x6, &b, info.radius_m);
        inflate(info, &excess);
    }
    forward
}

/// The backward fit's covariance moved to the forward fit's centroid (see
/// [`joint_covariance`]).
fn moved_backward(
    forward: &FitInformation,
    backward: &FitInformation,
    t_ref_moving: &Isometry3<f64>,
) -> Matrix6<f64> {
    joint_covariance(forward, backward, t_ref_moving) - forward.covariance_6x6
}

/// The least covariance to add to `c` so that it covers `b` on the
/// directions `c` measures (c + E >= b there, in the order of covariances):
/// with W = c^-1/2 b c^-1/2 = V diag(l) V', E = c^1/2 V diag(max(l - 1, 0))
/// V' c^1/2. Zero where `c` already covers `b`. Computed with the rotations
/// as arcs at `radius_m` (the result does not depend on it but for rounding).
fn excess_over(c: &Matrix6<f64>, b: &Matrix6<f64>, radius_m: f64) -> Matrix6<f64> {
    let r = radius_m.max(1e-6);
    let s = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, r, r, r));
    let s_inv = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, 1.0 / r, 1.0 / r, 1.0 / r));
    let (cs, bs) = (s * c * s, s * b * s);
    let eig = cs.symmetric_eigen();
    let max = eig.eigenvalues.amax();
    let (mut half, mut inv_half) = (Matrix6::zeros(), Matrix6::zeros());
    for k in (0..6).filter(|&k| max > 0.0 && eig.eigenvalues[k] > EMPTY * max) {
        let v = eig.eigenvectors.column(k);
        let root = eig.eigenvalues[k].sqrt();
        half += v * v.transpose() * root;
        inv_half += v * v.transpose() / root;
    }
    let w = inv_half * bs * inv_half;
    let w = (w + w.transpose()) * 0.5;
    let we = w.symmetric_eigen();
    let mut grow = Matrix6::zeros();
    for k in 0..6 {
        let v = we.eigenvectors.column(k);
        grow += v * v.transpose() * (we.eigenvalues[k] - 1.0).max(0.0);
    }
    let e = half * grow * half;
    s_inv * ((e + e.transpose()) * 0.5) * s_inv
}

/// Whether the backward run confirms the forward answer (module docs): it
/// did not stop still sliding with its gap `beyond_noise`, and it held no
/// direction the forward fit measured.
fn confirms(forward: &IcpResult, backward: &IcpResult, beyond_noise: bool) -> bool {
    let sliding = backward.status == IcpStatus::MaxIterations && beyond_noise;
    let lost = (backward.degenerate.iter()).any(|axis| !forward.degenerate.contains(axis));
    !sliding && !lost
}

/// Adds `extra` (a covariance, physical units) to the covariance of `info`
/// on the directions it measures (held directions keep no information);
/// its information and standard errors follow.
pub(crate) fn inflate(info: &mut FitInformation, extra: &Matrix6<f64>) {
    let range = projector_for_extras(&info.covariance_6x6, info.radius_m);
    info.covariance_6x6 += range * extra * range.transpose();
    info.covariance_6x6 = (info.covariance_6x6 + info.covariance_6x6.transpose()) * 0.5;
    info.info_6x6 = pseudo_inverse(&info.covariance_6x6).0;
    for k in 0..6 {
        if info.sigma[k].is_some() {
            info.sigma[k] = Some(standard_error(&info.covariance_6x6, k));
        }
    }
}

/// The projector onto the directions covariance `c` measures, orthogonal in
/// metres (rotations as arcs at the points' RMS radius `radius_m`, as the
/// degeneracy test compares them): in mixed units a held direction that mixes
/// a shift with a turn leaves a measured direction that mixes them the other
/// way, and a gap along the shift poured into it reads as a turn of radians
/// (a backward gap of 11.7 m along a held x gave a pitch sigma of 228 deg).
/// Applied to a physical vector; a covariance E maps to P E P^T.
pub(super) fn measured_projector(c: &Matrix6<f64>, radius_m: f64) -> Matrix6<f64> {
    let r = radius_m.max(1e-6);
    let s = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, r, r, r));
    let s_inv = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, 1.0 / r, 1.0 / r, 1.0 / r));
    s_inv * range_projector(&(s * c * s)) * s
}

/// The projector [`inflate`] and the gridding floor put their extras
/// through: [`measured_projector`] where `c` holds a direction; where it
/// holds none, the projector onto all of its eigen-directions (the identity
/// up to rounding, computed as it always was, so that fits with nothing held
/// keep their numbers to the last bit).
pub(super) fn projector_for_extras(c: &Matrix6<f64>, radius_m: f64) -> Matrix6<f64> {
    let (all, rank) = range_projector_and_rank(c);
    if rank == 6 {
        all
    } else {
        measured_projector(c, radius_m)
    }
}

/// Relative eigenvalue below which a covariance direction counts as empty.
const EMPTY: f64 = 1e-12;

/// The orthogonal projector onto the directions `c` gives a variance.
fn range_projector(c: &Matrix6<f64>) -> Matrix6<f64> {
    range_projector_and_rank(c).0
}

/// [`range_projector`] and the number of directions it keeps.
fn range_projector_and_rank(c: &Matrix6<f64>) -> (Matrix6<f64>, usize) {
    let eig = c.symmetric_eigen();
    let max = eig.eigenvalues.amax();
    let mut p = Matrix6::zeros();
    let mut rank = 0;
    for k in (0..6).filter(|&k| max > 0.0 && eig.eigenvalues[k] > EMPTY * max) {
        let v = eig.eigenvectors.column(k);
        p += v * v.transpose();
        rank += 1;
    }
    (p, rank)
}

/// The pseudo-inverse of a covariance over the directions it gives a
/// variance, and their number.
pub(super) fn pseudo_inverse(c: &Matrix6<f64>) -> (Matrix6<f64>, usize) {
    let eig = c.symmetric_eigen();
    let max = eig.eigenvalues.amax();
    let mut inv = Matrix6::zeros();
    let mut rank = 0;
    for k in (0..6).filter(|&k| max > 0.0 && eig.eigenvalues[k] > EMPTY * max) {
        let v = eig.eigenvectors.column(k);
        inv += v * v.transpose() / eig.eigenvalues[k];
        rank += 1;
    }
    (inv, rank)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::Axis;
    use nalgebra::{Translation3, UnitQuaternion};

    #[test]
    fn agreeing_directions_keep_the_answer() {
        let at = Vector3::new(500_000.0, 4_800_000.0, 200.0);
        let t = isometry_to_world(
            &Isometry3::from_parts(
                Translation3::new(1.0, -2.0, 0.5),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.001),
            ),
            &at,
        );
        let d = Disagreement::between(&t, &t.inverse(), &at);
        assert!(d.gap().norm() < 1e-9);
        let test = d.test(&Matrix6::identity());
        assert!(!test.beyond_noise() && test.dof == 6, "{test:?}");
    }

    #[test]
    fn the_disagreement_is_measured_at_the_centroid() {
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
    }

    #[test]
    fn a_gap_within_the_joint_noise_passes_and_one_beyond_becomes_one_sigma() {
        let d = Disagreement {
            shift_m: Vector3::new(0.2, 0.0, 0.0),
            rotation_rad: Vector3::new(0.0, 0.0, 0.01),
        };
        // 0.2 m against 0.1 m, 0.01 rad against 0.005 rad: chi-square 8 of 6 dof
        let noisy = Matrix6::from_diagonal(&Vector6::new(0.01, 0.01, 0.01, 1.0, 1.0, 2.5e-5));
        let test = d.test(&noisy);
        assert!((test.chi_square - 8.0).abs() < 1e-9 && test.dof == 6);
        assert!(!test.beyond_noise());
        // ten times tighter: chi-square 800
        let tight = noisy * 0.01;
        let test = d.test(&tight);
        assert!(test.beyond_noise(), "{test:?}");
        let grown = tight + d.model_error(&test);
        let after = d.test(&grown);
        assert!((after.chi_square - 1.0).abs() < 1e-9, "{after:?}");
        // the addition lies along the gap: nothing on the axes it did not move
        let e = d.model_error(&test);
        assert!(e[(1, 1)] == 0.0 && e[(3, 3)] == 0.0 && e[(0, 5)] > 0.0);
        // fewer measured directions, fewer degrees of freedom
        let mut held = tight;
        held[(2, 2)] = 0.0;
        assert_eq!(d.test(&held).dof, 5);
    }

    /// A backward run confirms the forward answer unless it stopped still
    /// sliding with its gap beyond the noise, or held a direction the
    /// forward fit measured.
    #[test]
    fn a_backward_run_that_slid_on_or_lost_a_direction_does_not_confirm() {
        let fit = |status: IcpStatus, held: Vec<Axis>| {
            let mut r = IcpResult::with_diagonal(
                Isometry3::identity(),
                Vector3::zeros(),
                Vector6::repeat(0.05),
                50.0,
            );
            r.status = status;
            r.degenerate = held;
            r
        };
        let forward = fit(IcpStatus::Converged, vec![]);
        assert!(confirms(&forward, &fit(IcpStatus::Converged, vec![]), true));
        assert!(confirms(
            &forward,
            &fit(IcpStatus::MaxIterations, vec![]),
            false
        ));
        assert!(!confirms(
            &forward,
            &fit(IcpStatus::MaxIterations, vec![]),
            true
        ));
        assert!(!confirms(
            &forward,
            &fit(IcpStatus::Degenerate, vec![Axis::X]),
            false
        ));
        // a direction the forward fit held too is no loss
        let held = fit(IcpStatus::Degenerate, vec![Axis::X]);
        assert!(confirms(
            &held,
            &fit(IcpStatus::Degenerate, vec![Axis::X]),
            false
        ));
        assert!(!confirms(
            &held,
            &fit(IcpStatus::Degenerate, vec![Axis::X, Axis::Yaw]),
            false
        ));
    }

    fn information(covariance: Matrix6<f64>, centroid: Vector3<f64>) -> FitInformation {
        FitInformation {
            info_6x6: pseudo_inverse(&covariance).0,
            covariance_6x6: covariance,
            sigma: [None; 6],
            degenerate: Vec::new(),
            centroid,
            effective_samples: 100.0,
            radius_m: 100.0,
            gridding_6x6: Matrix6::zeros(),
        }
    }

    #[test]
    fn the_backward_covariance_is_moved_to_the_forward_centroid() {
        let c = Vector3::new(500_000.0, 4_800_000.0, 200.0);
        let forward = information(Matrix6::identity() * 1e-4, c);
        // yaw known to 0.001 rad about a point 100 m east (in the moving DSM,
        // which the forward answer shifts 10 m north): at c, 0.1 m of y
        let mut yaw_only = Matrix6::zeros();
        yaw_only[(5, 5)] = 1e-6;
        let backward = information(yaw_only, c + Vector3::new(100.0, -10.0, 0.0));
        let t = Isometry3::translation(0.0, 10.0, 0.0);
        let joint = joint_covariance(&forward, &backward, &t);
        assert!((joint[(1, 1)] - (1e-4 + 1e-2)).abs() < 1e-12, "{joint}");
        assert!((joint[(0, 0)] - 1e-4).abs() < 1e-15);
        assert!((joint[(5, 5)] - (1e-4 + 1e-6)).abs() < 1e-15);
        assert!((joint[(1, 5)] + 1e-4).abs() < 1e-12, "{joint}");
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
            radius_m: 100.0,
            gridding_6x6: Matrix6::zeros(),
        };
        inflate(
            &mut info,
            &Matrix6::from_diagonal(&Vector6::new(0.03, 0.0, 5.0, 0.0, 0.0, 3e-4)),
        );
        assert!((info.sigma[0].unwrap() - 0.2).abs() < 1e-12);
        assert!((info.sigma[1].unwrap() - 0.1).abs() < 1e-12);
        assert_eq!(info.sigma[2], None);
        assert!((info.sigma[5].unwrap() - 0.02f64.to_degrees()).abs() < 1e-9);
        assert!((info.info_6x6[(0, 0)] - 25.0).abs() < 1e-9);
        assert_eq!(info.info_6x6[(2, 2)], 0.0);
        assert_eq!(info.covariance_6x6[(2, 2)], 0.0);
    }

    /// case 154 of the narrow battery: x held along a direction that turns
    /// the pitch by 0.005 rad per metre (at a 20 m radius, a tenth of an
    /// arc per metre: mostly x). A backward gap of 11.7 m in x must stay
    /// (nearly all) out of the measured pitch; projected in mixed units it
    /// read as a pitch sigma of 228 deg.
    #[test]
    fn a_gap_along_a_held_shift_does_not_pour_into_a_turn() {
        let held = Vector6::new(1.0, 0.0, 0.0, 0.0, -0.005, 0.0);
        let others = [
            Vector6::new(0.0, 1.0, 0.0, 0.0, 0.0, 0.0),
            Vector6::new(0.0, 0.0, 1.0, 0.0, 0.0, 0.0),
            Vector6::new(0.0, 0.0, 0.0, 1.0, 0.0, 0.0),
            Vector6::new(0.005, 0.0, 0.0, 0.0, 1.0, 0.0),
            Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 1.0),
        ];
        let variances = [0.01, 1e-4, 1e-7, 1e-7, 1e-7];
        let mut c = Matrix6::zeros();
        for (v, var) in others.iter().zip(variances) {
            c += v * v.transpose() * var;
        }
        assert!((c * held).norm() < 1e-12, "held is the null direction");
        let mut info = information(c, Vector3::zeros());
        info.radius_m = 20.0;
        info.sigma = std::array::from_fn(|k| (k != 0).then(|| standard_error(&c, k)));
        info.degenerate = vec![Axis::X];
        let gap = Vector6::new(11.7, 0.0, 0.0, 0.0, 0.0, 0.0);
        inflate(&mut info, &(gap * gap.transpose()));
        let pitch_deg = info.sigma[4].unwrap();
        assert!(pitch_deg < 0.5, "pitch sigma {pitch_deg} deg");
        assert!(
            (info.covariance_6x6 * held).norm() < 1e-9,
            "held stays held"
        );
    }

    /// The backward covariance larger along y than the forward's: the excess
    /// lifts y to the backward's variance and leaves what already covers it;
    /// a backward covariance inside the forward's adds nothing; a direction
    /// the forward fit holds stays held.
    #[test]
    fn the_weaker_direction_s_covariance_is_covered() {
        let c = Matrix6::from_diagonal(&Vector6::new(0.04, 0.01, 1e-4, 1e-8, 1e-8, 1e-8));
        let mut b = c;
        b[(1, 1)] = 0.25;
        b[(0, 0)] = 0.01;
        let e = excess_over(&c, &b, 50.0);
        let covered = c + e;
        assert!((covered[(1, 1)] - 0.25).abs() < 1e-9, "{covered}");
        assert!((covered[(0, 0)] - 0.04).abs() < 1e-12, "x already covers");
        assert!(e.amax() - e[(1, 1)].abs() < 1e-12, "only y grows: {e}");
        // covered in every direction: c + e - b is positive semi-definite
        let gap = (covered - b).symmetric_eigen().eigenvalues;
        assert!(gap.min() > -1e-12, "{gap}");
        assert!(excess_over(&c, &(c * 0.5), 50.0).amax() < 1e-15);
        // a correlated backward covariance: still covered, and the least such
        let mut corr = c * 2.0;
        corr[(0, 5)] = 1e-5;
        corr[(5, 0)] = 1e-5;
        let e = excess_over(&c, &corr, 50.0);
        let gap = (c + e - corr).symmetric_eigen().eigenvalues;
        assert!(gap.min() > -1e-12 && gap.max() < 1e-9, "{gap}");
        // held x and y (no variance) stay held
        let mut held = c;
        held[(0, 0)] = 0.0;
        held[(1, 1)] = 0.0;
        let e = excess_over(&held, &b, 50.0);
        assert!(e[(0, 0)].abs() < 1e-15 && e[(1, 1)].abs() < 1e-15, "{e}");
    }
}
