//! What a pairwise registration returns: the transform named by its frames,
//! the fit statistics and how it ended, or why it could not start.

use nalgebra::Isometry3;
use serde::Serialize;

use crate::fit::{Axis, FitInformation, FitSigma};

/// How a registration ended, and so what it measured.
///
/// | status | transform | weight in a graph |
/// |---|---|---|
/// | `Converged` | measured in all directions | full, by `information` |
/// | `Degenerate` | converged; the axes in `IcpResult::degenerate` were held at their start (flat ground, a ridge, a narrow strip) | by `information` only (zero along the held axes); `None` information: nothing measured |
/// | `MaxIterations` | still moving when the iterations ran out | not at full weight |
/// | `Ambiguous` | converged, but another start converged to a different place nearly as well | not at full weight |
/// | `TooFewInliers`, `Diverged` | not measured | none |
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IcpStatus {
    Converged,
    /// Ran out of iterations while still moving: not trusted at full weight.
    MaxIterations,
    /// Converged with some directions not constrained by the surface (e.g.
    /// flat terrain): those were held at their initial value (see
    /// `IcpResult::degenerate`); the others are measured.
    Degenerate,
    TooFewInliers,
    /// The error grew, or the motion exceeded the displacement cap.
    Diverged,
    /// Two starts of the global search converged to different places with
    /// nearly the same robust cost (a repetitive or featureless scene).
    Ambiguous,
}

impl IcpStatus {
    /// The transform is measured in every direction and can be used at full weight.
    pub fn is_converged(self) -> bool {
        self == IcpStatus::Converged
    }

    /// Converged, possibly with held (degenerate) axes: the transform is
    /// measured along the directions the result's `information` constrains.
    pub fn is_converged_or_held(self) -> bool {
        matches!(self, IcpStatus::Converged | IcpStatus::Degenerate)
    }
}

/// The outcome of one pairwise registration.
#[derive(Clone, Debug, Serialize)]
pub struct IcpResult {
    /// Maps moving-DSM points (x, y, height in the CRS) to the reference:
    /// p_ref = t_ref_moving p_moving. Written as row-major 4x4 under the
    /// historical key `m_world` (`pair --json`, read by tests and tools/).
    #[serde(rename = "m_world", with = "crate::geo::rigid::rows")]
    pub t_ref_moving: Isometry3<f64>,
    /// RMS nearest-neighbour distance of the inliers at the returned transform.
    pub rmse_m: f64,
    /// RMS point-to-plane residual of the inliers at the returned transform.
    pub rmse_plane_m: f64,
    pub inliers: usize,
    pub samples: usize,
    /// Fraction of samples with a valid reference pixel below them (s_ij estimate).
    pub overlap: f64,
    pub iterations: usize,
    pub status: IcpStatus,
    /// Smallest/largest eigenvalue of the normalised fit matrix (near 0 = degenerate).
    pub constraint_ratio: f64,
    /// Standard errors of the transform from the last fit (point-to-plane
    /// metrics; zero for point-to-point), in the local frame at the overlap.
    #[serde(default)]
    pub sigma: FitSigma,
    /// What the final fit knows, in the WORLD frame: a left perturbation
    /// p_ref -> R_d (p_ref - c) + c + t_d of the returned transform, with c =
    /// `FitInformation::centroid` (world CRS metres, the weighted centroid of
    /// the final inliers mapped onto the reference) and axes along the CRS
    /// axes; order (x, y, z [m], roll, pitch, yaw [rad]). Degenerate axes carry
    /// zero information. None for point-to-point fits and when the fit had
    /// too few matches.
    #[serde(skip)]
    pub information: Option<FitInformation>,
    /// Where `shift_m` of [`IcpResult::centred`] is measured: the fit's
    /// centroid (`information`), else the overlap centre; world CRS metres.
    pub centre_m: [f64; 3],
    /// Axes held at their initial value because the overlap does not constrain
    /// them (empty when all are measured); the same as `information.degenerate`.
    pub degenerate: Vec<Axis>,
    /// The global search's best cost over its second-best (0: one clear
    /// candidate, near 1: a second place fits nearly as well); None when the
    /// search was not run.
    pub ambiguity: Option<f64>,
    /// How far the backward check (the reference registered onto the moving
    /// DSM) landed from the forward answer; None when it did not run. A gap
    /// beyond the two fits' noise is part of the covariance (see
    /// `icp::backward`).
    pub backward: Option<BackwardCheck>,
    /// What the restart check (the full-resolution loop run again from the
    /// answer pushed both ways along its weakest horizontal direction, then
    /// across it unless pinned down there with one minimum) found;
    /// None when it did not run. Gaps beyond the noise are part of the
    /// covariance (see `icp::restart`).
    pub restart: Option<RestartCheck>,
    /// A second height of the overlap at the answer (see `icp::heights`):
    /// when there is one the pair is `Ambiguous`. None without one.
    pub second_height: Option<SecondHeight>,
    /// How far the global search looked and how far the answer lies from
    /// where the pair started; None when it did not run.
    pub search: Option<SearchReach>,
    pub nn: NnStatsSummary,
}

/// How far a pair's global search looked, and where its answer lies.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct SearchReach {
    /// The radius the search began with (the automatic one, cut to half a
    /// narrow overlap), metres.
    pub cut_m: f64,
    /// The radius it reached: larger than `cut_m` when its best place lay on
    /// the edge and the radius doubled.
    pub reached_m: f64,
    /// The answer's horizontal shift from the pair's start (the DSMs as
    /// georeferenced, or as moved by `--initial`) at `centre_m`, metres.
    pub offset_m: f64,
}

impl SearchReach {
    /// The search looked beyond the radius it began with.
    pub fn widened(&self) -> bool {
        self.reached_m > self.cut_m
    }
}

/// The restart check of a pair (see `icp::restart`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct RestartCheck {
    /// The largest gap between a restart's answer and the pair's, metres at
    /// the fit's centroid.
    pub gap_m: f64,
    /// Restarts whose gap was beyond the noise (their gap is in the covariance).
    pub beyond_noise: usize,
    /// Restarts started: two along the weakest horizontal direction, two
    /// more across it unless the fit is pinned down there (see
    /// `icp::restart`) and those found one minimum.
    pub tried: usize,
    /// Restarts that ran to an answer.
    pub ran: usize,
    /// Restarts that ran off: diverged (moved beyond the search radius, or
    /// their matches collapsed) or kept too few matches. Under a minimum the
    /// loop returns to from a few pixels away there are none.
    pub lost: usize,
    /// Restarts whose gap joined the covariance (beyond the noise, or beyond
    /// the loop's convergence scatter).
    pub widened: usize,
    /// How far the answer moved because both restarts settled together
    /// elsewhere, metres at the fit's centroid (0: the ladder's answer stands).
    pub moved_m: f64,
}

impl RestartCheck {
    /// The minimum proved not unique: a gap joined the covariance, or the
    /// answer moved to where both restarts settled.
    pub fn found_side_basins(&self) -> bool {
        self.widened > 0 || self.moved_m > 0.0
    }

    /// No restart ran off: the answer is a place the loop returns to.
    pub fn confirms(&self) -> bool {
        self.lost == 0
    }

    /// This check followed by `later` (run from this one's answer).
    pub fn and(self, later: &RestartCheck) -> RestartCheck {
        RestartCheck {
            gap_m: self.gap_m.max(later.gap_m),
            beyond_noise: self.beyond_noise + later.beyond_noise,
            tried: self.tried + later.tried,
            ran: self.ran + later.ran,
            lost: self.lost + later.lost,
            widened: self.widened + later.widened,
            moved_m: self.moved_m.max(later.moved_m),
        }
    }
}

/// A second height the overlap agrees on, one the fit treated as outliers.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SecondHeight {
    /// The second height minus the answer's, metres (reference minus moving).
    pub gap_m: f64,
    /// The share of the overlap's height differences at the second height.
    pub share: f64,
    /// How far the answer slid horizontally from where the overlap holds the
    /// second height, metres (0: at the answer; else at the georeferenced
    /// position, and the slide joins the sigmas too).
    pub slide_m: f64,
}

/// The forward answer against the inverse of the backward one, at the fit's centroid.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct BackwardCheck {
    /// [dx, dy, dz] metres, CRS axes.
    pub shift_m: [f64; 3],
    /// [roll, pitch, yaw] degrees (rotation vector components).
    pub rotation_deg: [f64; 3],
    pub status: IcpStatus,
    /// The gap's chi-square against the two fits' joint covariance (None
    /// without a covariance).
    pub chi_square: Option<f64>,
    /// Beyond the chi-square's 0.999 quantile: the gap widened the sigmas.
    pub beyond_noise: bool,
    /// The backward run settled where the forward answer is and measured
    /// every direction the forward fit measured; false when it was still
    /// sliding beyond the noise or lost a direction (`icp::backward`).
    pub confirms: bool,
}

#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct NnStatsSummary {
    pub queries: u64,
    pub pixels_visited: u64,
}

impl IcpResult {
    /// A converged result at `t_ref_moving` measured about `centre_m`, with
    /// nothing else known (tests build on it).
    #[cfg(test)]
    pub(crate) fn converged_at(t_ref_moving: Isometry3<f64>, centre_m: [f64; 3]) -> Self {
        IcpResult {
            t_ref_moving,
            rmse_m: 0.1,
            rmse_plane_m: 0.1,
            inliers: 10,
            samples: 10,
            overlap: 1.0,
            iterations: 3,
            status: IcpStatus::Converged,
            constraint_ratio: 1.0,
            sigma: Default::default(),
            information: None,
            centre_m,
            degenerate: Vec::new(),
            ambiguity: None,
            backward: None,
            restart: None,
            second_height: None,
            search: None,
            nn: Default::default(),
        }
    }

    /// [`IcpResult::converged_at`] with a diagonal covariance: standard errors
    /// `sigmas` (x, y, z m; roll, pitch, yaw rad) at `centroid`, information to
    /// match (tests build on it).
    #[cfg(test)]
    pub(crate) fn with_diagonal(
        t_ref_moving: Isometry3<f64>,
        centroid: nalgebra::Vector3<f64>,
        sigmas: nalgebra::Vector6<f64>,
        radius_m: f64,
    ) -> Self {
        use nalgebra::Matrix6;
        let variance = sigmas.map(|s| s * s);
        IcpResult {
            information: Some(FitInformation {
                info_6x6: Matrix6::from_diagonal(&variance.map(|v| 1.0 / v)),
                covariance_6x6: Matrix6::from_diagonal(&variance),
                sigma: std::array::from_fn(|k| Some(sigmas[k])),
                degenerate: Vec::new(),
                centroid,
                effective_samples: 1.0,
                radius_m,
                gridding_6x6: Matrix6::zeros(),
            }),
            ..IcpResult::converged_at(t_ref_moving, centroid.into())
        }
    }

    /// True when the transform is measured in every direction and can be used
    /// at full weight: `Converged` only. (Before the degeneracy-aware ICP,
    /// `MaxIterations` counted too; it no longer does.)
    pub fn is_usable(&self) -> bool {
        self.status.is_converged()
    }

    /// True when the transform can be used through its information matrix:
    /// converged, or converged with degenerate axes held (their information is zero).
    pub fn is_informative(&self) -> bool {
        self.status.is_converged_or_held() && self.information.is_some()
    }
}

/// The transform as a user reads it: the shift of the moving DSM at `centre_m`
/// and the rotation about that point, with one-sigma standard errors (None:
/// degenerate, held at its start, or not estimated).
#[derive(Clone, Debug, Serialize)]
pub struct CentredPose {
    /// World CRS metres, on the reference (p_ref).
    pub centre_m: [f64; 3],
    /// p_ref - p_moving at the centre: [dx, dy, dz] metres.
    pub shift_m: [f64; 3],
    /// [roll, pitch, yaw] degrees about the CRS x, y, z axes through the
    /// centre (R = Rz(yaw) Ry(pitch) Rx(roll)).
    pub rotation_deg: [f64; 3],
    pub sigma: CentredSigma,
}

/// Standard errors of a [`CentredPose`].
#[derive(Clone, Debug, Serialize)]
pub struct CentredSigma {
    pub shift_m: [Option<f64>; 3],
    pub rotation_deg: [Option<f64>; 3],
}

impl IcpResult {
    /// The transform about `centre_m` (see [`CentredPose`]): p_ref = R (p_moving
    /// - c_m) + c_m + shift with c_m the moving point that lands on the centre.
    pub fn centred(&self) -> CentredPose {
        let c = nalgebra::Point3::from(nalgebra::Vector3::from(self.centre_m));
        let from = self.t_ref_moving.inverse_transform_point(&c);
        let shift = c - from;
        let (roll, pitch, yaw) = self.t_ref_moving.rotation.euler_angles();
        let sigma = self
            .information
            .as_ref()
            .map(|i| i.reported_sigma())
            .unwrap_or([None; 6]);
        CentredPose {
            centre_m: self.centre_m,
            shift_m: [shift.x, shift.y, shift.z],
            rotation_deg: [roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()],
            sigma: CentredSigma {
                shift_m: [sigma[0], sigma[1], sigma[2]],
                rotation_deg: [sigma[3], sigma[4], sigma[5]],
            },
        }
    }
}

/// Errors that stop a registration before it starts.
#[derive(Debug, thiserror::Error)]
pub enum IcpError {
    #[error("the two DSMs do not overlap")]
    NoOverlap,
    #[error("no valid pixels in the overlap of the two DSMs")]
    EmptyOverlap,
    #[error("reading the DSM failed: {0}")]
    Read(#[from] crate::grid::GridError),
}
