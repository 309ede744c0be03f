//! The DSM-ICP flags shared by `pair` and `align`, flattened into both. Their
//! defaults are [`IcpConfig::default`]'s, so the library and the command line
//! cannot drift apart. [`InputArgs`]: what the user brings besides the store
//! (`--mask`, `--initial`), loaded into the [`PairInputs`] every pair sees.

use std::path::PathBuf;
use std::sync::Arc;

use dsmstream::fit::Model;
use dsmstream::icp::{IcpConfig, Metric};
use dsmstream::initial::InitialPoses;
use dsmstream::mask::{MaskTarget, StableMask};
use dsmstream::store::Store;
use dsmstream::view::PairInputs;
use dsmstream::InputError;

/// A stable-terrain mask and initial poses, shared by `pair` and `align`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct InputArgs {
    /// Stable terrain: a GeoTIFF in the DSMs' CRS (non-zero = stable; 0,
    /// no-data and outside = excluded) or GeoJSON polygons (.geojson, .json)
    /// of the stable areas. Excluded points are not matched.
    #[arg(long, value_name = "FILE")]
    pub mask: Option<PathBuf>,
    /// Initial poses ({"poses": [{"id", "matrix_world"}]}, e.g. an earlier
    /// poses.json): each listed DSM starts there, the others at the identity;
    /// the poses written are full corrections.
    #[arg(long, value_name = "POSES")]
    pub initial: Option<PathBuf>,
}

impl InputArgs {
    /// Reads the mask and the initial poses for `store`; any problem with
    /// them is bad input (exit 2) naming the file. The initial poses are
    /// returned too (align re-gauges with them).
    pub fn load(&self, store: &Store) -> anyhow::Result<(PairInputs, Option<InitialPoses>)> {
        let mut inputs = PairInputs::default();
        if let Some(path) = &self.mask {
            let mask = StableMask::load(path, &MaskTarget::of_store(store))
                .map_err(|e| InputError::new(e.to_string()))?;
            tracing::info!(mask = %path.display(), stable = mask.stable_fraction(), "mask read");
            inputs.mask = Some(Arc::new(mask));
        }
        let Some(path) = &self.initial else {
            return Ok((inputs, None));
        };
        let initial = InitialPoses::read(path).map_err(InputError::new)?;
        let unknown = initial.check(store).map_err(InputError::new)?;
        if !unknown.is_empty() {
            super::common::warn_line(&format!(
                "{}: poses of {} not in the store ignored",
                path.display(),
                unknown.join(", ")
            ));
        }
        inputs.shifts_m = initial.shifts_m(store);
        inputs.initial = Some((path.clone(), initial.content_hash));
        Ok((inputs, Some(initial)))
    }
}

fn defaults() -> IcpConfig {
    IcpConfig::default()
}

/// DSM-ICP settings shared by `pair` and `align`.
#[derive(clap::Args, Debug, Clone)]
pub struct IcpArgs {
    /// rigid (6 DoF) or translation (3 DoF).
    #[arg(long, value_enum, default_value_t = defaults().model)]
    pub model: Model,
    /// Residual: point-to-surface (default, sub-pixel), point-to-plane (NN point + grid normal), point-to-point (the paper's Kabsch).
    #[arg(long, value_enum, default_value_t = defaults().metric)]
    pub metric: Metric,
    /// Upper bound on the outlier threshold (nearest-neighbour distance at full
    /// resolution, metres, doubled per overview level). Default: automatic,
    /// max(10 m, 3 pixels, 4 x the initial search's residual spread) per level.
    #[arg(long)]
    pub tau: Option<f64>,
    /// Query points sampled from the moving DSM in the overlap (all valid
    /// pixels when the overlap has fewer).
    #[arg(long, default_value_t = defaults().samples)]
    pub samples: usize,
    /// Iterations per pyramid level.
    #[arg(long, default_value_t = defaults().max_iter)]
    pub max_iter: usize,
    /// Radius of the global initial search (metres per horizontal axis) and
    /// largest motion ICP may make from there. Default: max(100 m, 40 pixels)
    /// (1.2 km on 30 m DSMs). Vertical offsets need no radius.
    #[arg(long)]
    pub max_displacement: Option<f64>,
    /// Coarsest overview level used for coarse-to-fine (0 = full resolution only).
    #[arg(long, default_value_t = defaults().max_level)]
    pub max_level: usize,
    /// Seed of the sampling.
    #[arg(long, default_value_t = defaults().seed)]
    pub seed: u64,
    /// Point-to-surface: skip reference places whose 7 x 7 neighbourhood
    /// deviates from a plane by more than this RMS (metres) and 3x the median
    /// (walls, tree crowns); default `inf`: walls are kept, each wall segment
    /// counted in the sigmas with one placement error of pixel / sqrt(6).
    #[arg(long, default_value_t = defaults().max_roughness_m)]
    pub max_roughness: f64,
    /// One-sigma prior on each pair's rotation about its start, degrees per
    /// axis: directions a narrow or flat overlap barely sees stay near the
    /// georeferenced rotation; `align` also holds each DSM's rotation about
    /// its georeferencing with it, so small yaws do not add up across a grid;
    /// `inf` for none.
    #[arg(long, default_value_t = defaults().rotation_prior_deg)]
    pub rotation_prior_deg: f64,
    /// Gridding floor of each pair's reported standard errors, in pixels of
    /// the coarser DSM on x and y (shares of it on the other axes): gridded
    /// DSMs place walls to about 1/20 pixel, an error the whole overlap shares
    /// and no fit statistic sees; 0 for none.
    #[arg(long, default_value_t = defaults().sigma_floor_px)]
    pub sigma_floor_px: f64,
}

impl Default for IcpArgs {
    /// The flags as if none were given.
    fn default() -> Self {
        let d = defaults();
        IcpArgs {
            model: d.model,
            metric: d.metric,
            tau: None,
            samples: d.samples,
            max_iter: d.max_iter,
            max_displacement: None,
            max_level: d.max_level,
            seed: d.seed,
            max_roughness: d.max_roughness_m,
            rotation_prior_deg: d.rotation_prior_deg,
            sigma_floor_px: d.sigma_floor_px,
        }
    }
}

impl IcpArgs {
    /// The library configuration, or bad input (exit 2) for a value that is
    /// not positive.
    // `!(x > 0.0)` on purpose: NaN must be refused too
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    pub fn to_config(&self) -> anyhow::Result<IcpConfig> {
        let positive = |v: Option<f64>| v.is_none_or(|v| v > 0.0);
        if !positive(self.tau)
            || self.samples == 0
            || self.max_iter == 0
            || !positive(self.max_displacement)
            || !(self.max_roughness > 0.0)
            || !(self.rotation_prior_deg > 0.0)
            || !(self.sigma_floor_px >= 0.0)
        {
            return Err(InputError::new(
                "--tau, --samples, --max-iter, --max-displacement, --max-roughness and --rotation-prior-deg must be positive, --sigma-floor-px not negative",
            )
            .into());
        }
        Ok(IcpConfig {
            model: self.model,
            metric: self.metric,
            tau_m: self.tau.unwrap_or(f64::INFINITY),
            samples: self.samples,
            max_iter: self.max_iter,
            max_displacement_m: self.max_displacement.unwrap_or(f64::INFINITY),
            seed: self.seed,
            max_level: self.max_level,
            max_roughness_m: self.max_roughness,
            rotation_prior_deg: self.rotation_prior_deg,
            sigma_floor_px: self.sigma_floor_px,
            ..defaults()
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser, Debug)]
    struct T {
        #[command(flatten)]
        icp: IcpArgs,
        #[command(flatten)]
        inputs: InputArgs,
    }

    #[test]
    fn mask_and_initial_are_optional_paths() {
        let none = T::try_parse_from(["t"]).unwrap().inputs;
        assert!(none.mask.is_none() && none.initial.is_none());
        let t = T::try_parse_from(["t", "--mask", "m.geojson", "--initial", "p.json"]).unwrap();
        assert_eq!(t.inputs.mask, Some(PathBuf::from("m.geojson")));
        assert_eq!(t.inputs.initial, Some(PathBuf::from("p.json")));
    }

    #[test]
    fn no_flags_give_the_library_defaults() {
        let c = T::try_parse_from(["t"]).unwrap().icp.to_config().unwrap();
        let d = IcpConfig::default();
        assert_eq!((c.model, c.metric), (d.model, d.metric));
        assert_eq!(
            (c.tau_m, c.samples, c.max_iter),
            (d.tau_m, d.samples, d.max_iter)
        );
        assert_eq!(
            (c.max_displacement_m, c.max_level),
            (d.max_displacement_m, d.max_level)
        );
        assert_eq!(
            (c.seed, c.max_roughness_m, c.tolerance_m),
            (d.seed, d.max_roughness_m, d.tolerance_m)
        );
        assert_eq!(c.rotation_prior_deg, d.rotation_prior_deg);
        let prior = T::try_parse_from(["t", "--rotation-prior-deg", "0.2"]).unwrap();
        assert_eq!(prior.icp.to_config().unwrap().rotation_prior_deg, 0.2);
        let none = T::try_parse_from(["t", "--rotation-prior-deg", "inf"]).unwrap();
        assert_eq!(
            none.icp.to_config().unwrap().rotation_prior_deg,
            f64::INFINITY
        );
        let zero = T::try_parse_from(["t", "--rotation-prior-deg", "0"]).unwrap();
        assert!(zero.icp.to_config().is_err(), "a zero prior is refused");
    }

    #[test]
    fn default_is_no_flags() {
        let parsed = T::try_parse_from(["t"]).unwrap().icp;
        assert_eq!(format!("{parsed:?}"), format!("{:?}", IcpArgs::default()));
    }

    #[test]
    fn a_non_positive_value_is_bad_input() {
        for flag in ["--tau", "--max-displacement", "--max-roughness"] {
            let t = T::try_parse_from(["t", flag, "0"]).unwrap();
            let err = t.icp.to_config().unwrap_err();
            assert!(err.downcast_ref::<InputError>().is_some(), "{flag}");
        }
        let t = T::try_parse_from(["t", "--tau", "NaN"]).unwrap();
        assert!(t.icp.to_config().is_err());
    }
}
