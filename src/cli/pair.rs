//! `dsmstream pair <store> <ref-id> <moving-id>`: one pairwise DSM-ICP through
//! the chunk cache, printed as a table or JSON. The ICP flags defined here are
//! shared with `align`.

use std::path::PathBuf;

use dsmstream::cache::ChunkCache;
use dsmstream::fit::Model;
use dsmstream::icp::{matrix_rows, register, IcpConfig, IcpError, IcpResult, Metric};
use dsmstream::store::{Store, StorePyramid};
use dsmstream::InputError;

/// DSM-ICP settings shared by `pair` and `align`.
#[derive(clap::Args, Debug, Clone)]
pub struct IcpArgs {
    /// rigid (6 DoF) or translation (3 DoF).
    #[arg(long, value_enum, default_value = "rigid")]
    pub model: Model,
    /// Residual: point-to-surface (default, sub-pixel), point-to-plane (NN point + grid normal), point-to-point (the paper's Kabsch).
    #[arg(long, value_enum, default_value = "point-to-surface")]
    pub metric: Metric,
    /// Outlier threshold on the nearest-neighbour distance, metres (paper: 10).
    #[arg(long, default_value_t = 10.0)]
    pub tau: f64,
    /// Query points sampled from the moving DSM in the overlap (all valid
    /// pixels when the overlap has fewer).
    #[arg(long, default_value_t = 200_000)]
    pub samples: usize,
    /// Iterations per pyramid level.
    #[arg(long, default_value_t = 40)]
    pub max_iter: usize,
    /// Largest motion accepted, metres; caps the search at coarse levels.
    #[arg(long, default_value_t = 100.0)]
    pub max_displacement: f64,
    /// Coarsest overview level used for coarse-to-fine (0 = full resolution only).
    #[arg(long, default_value_t = 3)]
    pub max_level: usize,
    /// Seed of the sampling.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Point-to-surface: skip reference places whose 7 x 7 neighbourhood
    /// deviates from a plane by more than this RMS (metres) and 3x the median
    /// (walls, tree crowns).
    #[arg(long, default_value_t = 1.0)]
    pub max_roughness: f64,
}

impl IcpArgs {
    // `!(x > 0.0)` on purpose: NaN must be refused too
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    pub fn to_config(&self) -> anyhow::Result<IcpConfig> {
        if !(self.tau > 0.0)
            || self.samples == 0
            || self.max_iter == 0
            || !(self.max_displacement > 0.0)
            || !(self.max_roughness > 0.0)
        {
            return Err(InputError::new(
                "--tau, --samples, --max-iter, --max-displacement and --max-roughness must be positive",
            )
            .into());
        }
        Ok(IcpConfig {
            model: self.model,
            metric: self.metric,
            tau_m: self.tau,
            samples: self.samples,
            max_iter: self.max_iter,
            max_displacement_m: self.max_displacement,
            seed: self.seed,
            max_level: self.max_level,
            max_roughness_m: self.max_roughness,
            ..IcpConfig::default()
        })
    }
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The store directory.
    pub store: PathBuf,
    /// Id of the reference DSM (stays fixed).
    pub reference: String,
    /// Id of the moving DSM (the transform maps it onto the reference).
    pub moving: String,
    #[command(flatten)]
    pub icp: IcpArgs,
    /// Chunk cache budget in MiB.
    #[arg(long, default_value_t = 256)]
    pub cache_mb: usize,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Opens a store, mapping problems with it to bad input (exit 2).
pub fn open_store(path: &std::path::Path) -> anyhow::Result<Store> {
    Store::open(path).map_err(|e| {
        if e.is_bad_input() {
            anyhow::Error::new(InputError::new(e.to_string()))
        } else {
            anyhow::Error::new(e)
        }
    })
}

/// Index of a DSM id, or a bad-input error listing what exists.
pub fn find_dsm(store: &Store, id: &str) -> anyhow::Result<usize> {
    store.find(id).ok_or_else(|| {
        let known: Vec<&str> = store
            .dsms()
            .iter()
            .map(|d| d.id.as_str())
            .take(10)
            .collect();
        InputError::new(format!(
            "{}: no DSM with id '{id}' (known: {}{})",
            store.root().display(),
            known.join(", "),
            if store.dsms().len() > 10 { ", ..." } else { "" }
        ))
        .into()
    })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = args.icp.to_config()?;
    let store = open_store(&args.store)?;
    let (i, j) = (
        find_dsm(&store, &args.reference)?,
        find_dsm(&store, &args.moving)?,
    );
    if i == j {
        return Err(InputError::new("the reference and the moving DSM are the same").into());
    }
    let cache = ChunkCache::new(args.cache_mb.max(1) << 20);
    let started = std::time::Instant::now();
    let result = register(
        &StorePyramid::new(&store, &cache, i),
        &StorePyramid::new(&store, &cache, j),
        &config,
    );
    let result = match result {
        Ok(r) => r,
        Err(e @ (IcpError::NoOverlap | IcpError::EmptyOverlap)) => {
            return Err(
                InputError::new(format!("{} and {}: {e}", args.reference, args.moving)).into(),
            )
        }
        // a chunk of the store that cannot be read or decoded (the message names its file)
        Err(e @ IcpError::Read(_)) => {
            return Err(InputError::new(format!(
                "registering {} to {}: {e}",
                args.moving, args.reference
            ))
            .into())
        }
    };
    let seconds = started.elapsed().as_secs_f64();
    cache.log_stats();
    if args.json {
        let value = serde_json::json!({
            "reference": args.reference, "moving": args.moving, "seconds": seconds,
            "result": result, "cache": cache.stats(),
        });
        println!("{}", serde_json::to_string_pretty(&value)?);
    } else {
        print_table(&args.reference, &args.moving, &result, seconds);
    }
    if !result.is_usable() {
        anyhow::bail!(
            "registration of {} to {} is not usable: {:?}",
            args.moving,
            args.reference,
            result.status
        );
    }
    Ok(())
}

fn print_table(reference: &str, moving: &str, r: &IcpResult, seconds: f64) {
    let m = matrix_rows(&r.t_ref_moving);
    let rot = nalgebra::Matrix3::from_fn(|a, b| m[a][b]);
    let angle_deg = ((rot.trace() - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    println!("pair        {moving} -> {reference}");
    println!(
        "status      {:?} after {} iterations ({seconds:.2} s)",
        r.status, r.iterations
    );
    println!(
        "rmse        {:.4} m (NN distance, inliers)   plane rmse {:.4} m",
        r.rmse_m, r.rmse_plane_m
    );
    println!(
        "inliers     {} of {} samples   overlap {:.3}",
        r.inliers, r.samples, r.overlap
    );
    println!(
        "rotation    {angle_deg:.6} deg   constraint ratio {:.2e}",
        r.constraint_ratio
    );
    let (sr, st) = (r.sigma.rot_deg, r.sigma.trans_m);
    println!(
        "1-sigma     tilt {:.5} {:.5} deg  yaw {:.5} deg  shift {:.4} {:.4} {:.4} m",
        sr[0], sr[1], sr[2], st[0], st[1], st[2]
    );
    println!("matrix_world (p_ref = M p_moving):");
    for row in m {
        println!(
            "  [{:>16.9} {:>16.9} {:>16.9} {:>18.6}]",
            row[0], row[1], row[2], row[3]
        );
    }
}
