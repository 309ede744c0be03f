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
    /// Upper bound on the outlier threshold (NN distance) at full resolution,
    /// doubled per overview level; infinite (the default): the threshold
    /// follows the pyramid alone ([`IcpConfig::tau_at`]).
    pub tau_m: f64,
    /// Query points sampled from the moving DSM.
    pub samples: usize,
    /// Iterations per level.
    pub max_iter: usize,
    /// Radius of the global initial search (metres per horizontal axis) and
    /// largest motion ICP may make from its start; infinite (the default):
    /// [`IcpConfig::search_radius_m`]'s rule.
    pub max_displacement_m: f64,
    pub seed: u64,
    /// Coarsest overview level used (coarse-to-fine starts there); 0 = full resolution only.
    pub max_level: usize,
    /// Point-to-surface only: skip places whose neighbourhood deviates from a
    /// plane by more than this RMS and more than 3x the median roughness (walls,
    /// tree crowns); infinite (the default): keep them, walls counted in the
    /// sigmas with their snapping to the pixels ([`crate::fit::WallSnap`]).
    pub max_roughness_m: f64,
    /// Converged when an update moves less than this (metres, at the overlap's edge).
    pub tolerance_m: f64,
    /// One-sigma prior on the rotation about the start, degrees per axis
    /// (infinite: none); see [`crate::fit::RotationPrior`] and
    /// [`DEFAULT_ROTATION_PRIOR_DEG`].
    pub rotation_prior_deg: f64,
    /// Gridding floor of the reported standard errors, pixels of the coarser
    /// DSM on x and y, shares of it on the other axes (see [`super::floor`]);
    /// 0: none.
    pub sigma_floor_px: f64,
}

impl Default for IcpConfig {
    fn default() -> Self {
        IcpConfig {
            model: Model::Rigid,
            metric: Metric::PointToSurface,
            tau_m: f64::INFINITY,
            samples: 200_000,
            max_iter: 40,
            max_displacement_m: f64::INFINITY,
            seed: 1,
            max_level: 3,
            tolerance_m: 1e-4,
            max_roughness_m: f64::INFINITY,
            rotation_prior_deg: DEFAULT_ROTATION_PRIOR_DEG,
            sigma_floor_px: super::floor::DEFAULT_SIGMA_FLOOR_PX,
        }
    }
}

impl IcpConfig {
    /// The rotation prior at estimate `t` of a fit that started at `start`;
    /// None without one (or under the translation model).
    pub fn rotation_prior(
        &self,
        t: &nalgebra::Isometry3<f64>,
        start: &nalgebra::Isometry3<f64>,
    ) -> Option<crate::fit::RotationPrior> {
        (self.model == Model::Rigid && self.rotation_prior_deg.is_finite()).then(|| {
            crate::fit::RotationPrior {
                sigma_rad: self.rotation_prior_deg.to_radians(),
                current: (t.rotation * start.rotation.inverse()).scaled_axis(),
            }
        })
    }
}

/// The default rotation prior, degrees (one sigma per axis). Georeferenced DSMs
/// disagree in rotation by hundredths of a degree; a narrow or flat overlap
/// can leave a direction (yaw on a strip) known to tenths of a degree, where
/// the fit followed the noise to 0.5-1.8 deg. Measured on generated grids
/// (docs/measurements.md, "A rotation prior"): per-DSM worst 1.02 -> 0.75 m
/// and 2.79 -> 1.52 m on 20 x 20 grids of 128 m tiles, 1.15 -> 0.14 deg; no
/// change on 1 km tiles, whose data see every rotation far better.
pub const DEFAULT_ROTATION_PRIOR_DEG: f64 = 0.05;

/// The outlier threshold's floor at full resolution (the paper's 10 m).
pub const PAPER_TAU_M: f64 = 10.0;

/// The automatic search radius: metres, and pixels of the coarser DSM.
pub const AUTO_RADIUS_M: f64 = 100.0;
pub const AUTO_RADIUS_PX: f64 = 40.0;

impl IcpConfig {
    /// The search radius for DSMs of `gsd_m` pixels: `max_displacement_m` when
    /// set, else max(100 m, 40 pixels) (1.2 km on 30 m DSMs).
    pub fn search_radius_m(&self, gsd_m: f64) -> f64 {
        if self.max_displacement_m.is_finite() {
            self.max_displacement_m
        } else {
            AUTO_RADIUS_M.max(AUTO_RADIUS_PX * gsd_m)
        }
    }

    /// The outlier threshold on overview `level` (pixels of `pixel_m`) after a
    /// global search whose residual spread was `coarse_cost_m`:
    /// max(10 m x 2^level, 3 pixels, 4 x the spread), never above
    /// `tau_m` x 2^level. On 0.5 m city tiles this is the paper's 10 m x 2^level;
    /// on 30 m DSMs 3 pixels (the NN distance alone reaches 0.7 pixel).
    pub fn tau_at(&self, level: usize, pixel_m: f64, coarse_cost_m: f64) -> f64 {
        let scale = (1u64 << level) as f64;
        let cost = if coarse_cost_m.is_finite() {
            coarse_cost_m
        } else {
            0.0
        };
        let auto = (PAPER_TAU_M * scale).max(3.0 * pixel_m).max(4.0 * cost);
        auto.min(self.tau_m * scale)
    }
}

/// Samples per iteration on the coarse levels and in the first phase of the
/// full-resolution level (see `level`).
pub(super) const LADDER_SAMPLES: usize = 50_000;
