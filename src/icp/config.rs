//! What a pairwise registration is asked to do: the residual metric and the
//! settings of the coarse-to-fine loop.

use serde::Serialize;

use crate::fit::Model;

/// How correspondences are turned into a motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Metric {
    /// Linearised point-to-plane with grid normals (sub-pixel horizontal accuracy).
    PointToPlane,
    /// Exact grid NN for outlier rejection, then the distance to the tangent
    /// plane of the bilinear reference surface right below the query.
    PointToSurface,
    /// The paper's point-to-point Kabsch fit (resolves only the pixel lattice horizontally).
    PointToPoint,
}

/// Settings of one pairwise registration.
#[derive(Clone, Debug)]
pub struct IcpConfig {
    pub model: Model,
    pub metric: Metric,
    /// Outlier threshold on the NN distance at full resolution (paper: 10 m).
    pub tau_m: f64,
    /// Query points sampled from the moving DSM.
    pub samples: usize,
    /// Iterations per level.
    pub max_iter: usize,
    /// Largest motion accepted; also caps the NN search radius at coarse levels.
    pub max_displacement_m: f64,
    pub seed: u64,
    /// Coarsest overview level used (coarse-to-fine starts there); 0 = full resolution only.
    pub max_level: usize,
    /// Point-to-surface only: skip places whose neighbourhood deviates from a
    /// plane by more than this RMS and more than 3x the median roughness (walls,
    /// tree crowns): their tangent plane is not the surface.
    pub max_roughness_m: f64,
    /// Converged when an update moves less than this (metres, at the overlap's edge).
    pub tolerance_m: f64,
}

impl Default for IcpConfig {
    fn default() -> Self {
        IcpConfig {
            model: Model::Rigid,
            metric: Metric::PointToSurface,
            tau_m: 10.0,
            samples: 200_000,
            max_iter: 40,
            max_displacement_m: 100.0,
            seed: 1,
            max_level: 3,
            tolerance_m: 1e-4,
            max_roughness_m: 1.0,
        }
    }
}

/// Constraint ratio below which a fit is called degenerate.
pub(super) const DEGENERATE_RATIO: f64 = 1e-6;

/// Samples per iteration on the coarse levels and in the first phase of the
/// full-resolution level (see `level`).
pub(super) const LADDER_SAMPLES: usize = 50_000;
