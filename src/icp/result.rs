//! What a pairwise registration returns: the transform named by its frames,
//! the fit statistics and how it ended, or why it could not start.

use nalgebra::Isometry3;
use serde::Serialize;

use crate::fit::{FitInformation, FitSigma};

/// How a registration ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IcpStatus {
    Converged,
    /// Ran out of iterations while still moving (result may still be usable).
    MaxIterations,
    /// Some direction is not constrained by the surface (e.g. flat terrain).
    Degenerate,
    TooFewInliers,
    /// The error grew, or the motion exceeded the displacement cap.
    Diverged,
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
    /// The final fit's information, standard errors per axis and degenerate
    /// directions, about `FitInformation::centroid` in the world frame
    /// (None until the ICP computes it).
    #[serde(skip)]
    pub information: Option<FitInformation>,
    pub nn: NnStatsSummary,
}

#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct NnStatsSummary {
    pub queries: u64,
    pub pixels_visited: u64,
}

impl IcpResult {
    /// True when the transform can be used (converged, or stopped while still improving slightly).
    pub fn is_usable(&self) -> bool {
        matches!(self.status, IcpStatus::Converged | IcpStatus::MaxIterations)
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
    Read(String),
}
