//! `bench_nn`: the paper's memory/speed experiment (Xu & Qin 2024, Fig. 5/6):
//! DSM-ICP through the chunk cache against a k-d tree ICP, on reference DSMs of
//! growing size and one fixed query set.
//!
//! - `bench_nn run`: generates the inputs with `dsmgen big` (reference of N x N
//!   px, moving DSM of 700 x 700 px inside its top-left corner with a known
//!   shift), ingests them, then runs each method in its own process per size and
//!   prints a table (plus CSV and Markdown) of NN time per iteration, end-to-end
//!   wall time and peak RSS.
//! - `bench_nn dsm` / `bench_nn kdtree`: one method on one store, one JSON line.
//!
//! Both methods use the same `IcpConfig` (point-to-point Kabsch, full
//! resolution, tau 10 m), the same samples, and the same rayon pool.

mod kdtree_icp;
mod report;
mod run;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};
use dsmstream::cache::ChunkCache;
use dsmstream::fit::Model;
use dsmstream::grid::Grid;
use dsmstream::icp::{matrix_rows, register, IcpConfig, Metric};
use dsmstream::nn::{nearest, NnStats};
use dsmstream::store::{Store, StoreGrid, StorePyramid};
use nalgebra::{Matrix4, Point3, Vector3};
use rayon::prelude::*;
use serde_json::{json, Value};

use kdtree_icp::{load_cloud, queries, register_kd, KdReference, Queries};
pub use run::Prep;

#[derive(Parser)]
#[command(
    name = "bench_nn",
    about = "Grid NN (DSM-ICP) vs k-d tree ICP, paper Fig. 5/6"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate, ingest and run both methods for every size.
    Run(RunArgs),
    /// DSM-ICP through the chunk cache on one store (prints one JSON line).
    Dsm(SideArgs),
    /// k-d tree ICP on one store (prints one JSON line).
    Kdtree(SideArgs),
}

#[derive(clap::Args, Clone)]
struct SideArgs {
    store: PathBuf,
    #[arg(long)]
    reference: String,
    #[arg(long, default_value = "moving")]
    moving: String,
    #[arg(long, default_value_t = 50_000)]
    samples: usize,
    #[arg(long, default_value_t = 64)]
    cache_mb: usize,
    /// Timed NN passes at the identity after the ICP (median reported).
    #[arg(long, default_value_t = 3)]
    nn_repeats: usize,
}

#[derive(clap::Args)]
pub struct RunArgs {
    /// Working directory for the generated DSMs and stores.
    #[arg(long, default_value = "/tmp/bench_nn")]
    pub work: PathBuf,
    /// Reference edge lengths in pixels (0.5, 25, 106, 300 M points).
    #[arg(long, value_delimiter = ',', default_value = "707,5000,10300,17320")]
    pub sizes: Vec<u64>,
    #[arg(long, default_value_t = 50_000)]
    pub samples: usize,
    #[arg(long, default_value_t = 64)]
    pub cache_mb: usize,
    /// Skip the k-d tree above this many reference pixels (0 = never skip).
    #[arg(long, default_value_t = 0)]
    pub kd_max_pixels: u64,
    #[arg(long, default_value = "tools/results/bench_nn_results.csv")]
    pub csv: PathBuf,
    #[arg(long, default_value = "tools/results/bench_nn_results.md")]
    pub markdown: PathBuf,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Run(a) => run::run(a),
        Command::Dsm(a) => {
            println!("{}", dsm_side(&a)?);
            Ok(())
        }
        Command::Kdtree(a) => {
            println!("{}", kd_side(&a)?);
            Ok(())
        }
    }
}

/// The configuration both methods run: the paper's point-to-point ICP at full resolution.
fn icp_config(samples: usize) -> IcpConfig {
    IcpConfig {
        model: Model::Rigid,
        metric: Metric::PointToPoint,
        tau_m: 10.0,
        samples,
        max_level: 0,
        ..IcpConfig::default()
    }
}

fn open(a: &SideArgs) -> anyhow::Result<(Store, usize, usize)> {
    let store = Store::open(&a.store)?;
    let find = |id: &str| {
        store
            .find(id)
            .with_context(|| format!("{}: no DSM '{id}'", a.store.display()))
    };
    let (r, m) = (find(&a.reference)?, find(&a.moving)?);
    Ok((store, r, m))
}

/// DSM-ICP: `register` end to end, then the warm per-iteration NN time.
fn dsm_side(a: &SideArgs) -> anyhow::Result<Value> {
    let started = Instant::now();
    let (store, r, m) = open(a)?;
    let cache = ChunkCache::new(a.cache_mb << 20);
    let config = icp_config(a.samples);
    let (ref_pyr, mov_pyr) = (
        StorePyramid::new(&store, &cache, r),
        StorePyramid::new(&store, &cache, m),
    );
    let result = register(&ref_pyr, &mov_pyr, &config)?;
    let end_to_end_s = started.elapsed().as_secs_f64();
    let q = queries(&ref_pyr, &mov_pyr, &config).map_err(anyhow::Error::msg)?;
    let (nn_s, check) = timed_passes(a.nn_repeats, || {
        grid_pass(&store, &cache, r, &q, config.tau_m)
    })?;
    let peak_rss_mb_compared = peak_rss_mb();
    // For information: the product's default ICP (point-to-surface, coarse to fine).
    let t_default = Instant::now();
    let default_config = IcpConfig {
        samples: a.samples,
        ..IcpConfig::default()
    };
    let default = register(&ref_pyr, &mov_pyr, &default_config)?;
    let default_s = t_default.elapsed().as_secs_f64();
    Ok(json!({
        "method": "dsmstream",
        "reference_points": store.dsms()[r].valid_count,
        "end_to_end_s": end_to_end_s,
        "nn_s_per_iteration": nn_s,
        "iterations": result.iterations,
        "status": result.status,
        "m_world": matrix_rows(&result.t_ref_moving),
        "motion": motion_at(&matrix_rows(&result.t_ref_moving), &q.origin),
        "rmse_m": result.rmse_m,
        "inliers": result.inliers,
        "check": check,
        "default_icp": {"seconds": default_s, "status": default.status, "iterations": default.iterations,
            "motion": motion_at(&matrix_rows(&default.t_ref_moving), &q.origin)},
        "cache": cache.stats(),
        "peak_rss_mb": peak_rss_mb_compared,
        "peak_rss_mb_after_default_icp": peak_rss_mb(),
    }))
}

/// One pass of exact grid NN over the query set at the identity; returns
/// (inliers within tau, sum of their distances) as a cross-check.
fn grid_pass(
    store: &Store,
    cache: &ChunkCache,
    dsm: usize,
    q: &Queries,
    tau_m: f64,
) -> anyhow::Result<(usize, f64)> {
    let parts: Vec<anyhow::Result<(usize, f64)>> = q
        .points
        .par_chunks(4096)
        .map(|block| {
            let mut grid = StoreGrid::new(store, cache, dsm, 0)?;
            let mut stats = NnStats::default();
            let mut out = (0, 0.0);
            for p in block {
                if let Some(n) = nearest(&mut grid, &q.ref_frame, p, tau_m, &mut stats) {
                    if n.distance_m <= tau_m {
                        out.0 += 1;
                        out.1 += n.distance_m;
                    }
                }
            }
            Ok(out)
        })
        .collect();
    sum_parts(parts)
}

fn sum_parts(parts: Vec<anyhow::Result<(usize, f64)>>) -> anyhow::Result<(usize, f64)> {
    let mut total = (0, 0.0);
    for p in parts {
        let (n, s) = p?;
        total.0 += n;
        total.1 += s;
    }
    Ok(total)
}

/// The same pass through the k-d tree.
fn kd_pass(kd: &KdReference, q: &Queries, tau_m: f64) -> anyhow::Result<(usize, f64)> {
    let parts: Vec<anyhow::Result<(usize, f64)>> = q
        .points
        .par_chunks(4096)
        .map(|block| {
            let mut out = (0, 0.0);
            for p in block {
                let (_, d) = kd.nearest(p);
                if d <= tau_m {
                    out.0 += 1;
                    out.1 += d;
                }
            }
            Ok(out)
        })
        .collect();
    sum_parts(parts)
}

/// Median wall time of `repeats` calls (after one untimed warm-up call), and the last result.
fn timed_passes(
    repeats: usize,
    mut pass: impl FnMut() -> anyhow::Result<(usize, f64)>,
) -> anyhow::Result<(f64, Value)> {
    let mut check = pass()?;
    let mut times = Vec::new();
    for _ in 0..repeats.max(1) {
        let t = Instant::now();
        check = pass()?;
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    let check = json!({"inliers": check.0, "sum_distance_m": check.1});
    Ok((times[times.len() / 2], check))
}

/// k-d tree ICP: read all valid reference points, build, iterate.
fn kd_side(a: &SideArgs) -> anyhow::Result<Value> {
    let started = Instant::now();
    let (store, r, m) = open(a)?;
    let config = icp_config(a.samples);
    let (q, cloud) = {
        let cache = ChunkCache::new(a.cache_mb << 20);
        let (ref_pyr, mov_pyr) = (
            StorePyramid::new(&store, &cache, r),
            StorePyramid::new(&store, &cache, m),
        );
        let q = queries(&ref_pyr, &mov_pyr, &config).map_err(anyhow::Error::msg)?;
        let mut grid = StoreGrid::new(&store, &cache, r, 0)?;
        let mut band = |g: &mut StoreGrid, row0: i64, rows: usize| {
            let w = g.width() as usize;
            g.read_window(0, row0, w, rows)
        };
        let expected = store.dsms()[r].valid_count as usize;
        let cloud = load_cloud(&mut grid, &mut band, &q.ref_frame, expected, 512);
        if let Some(e) = grid.take_error() {
            bail!("reading the reference failed: {e}");
        }
        (q, cloud)
    };
    let load_s = started.elapsed().as_secs_f64();
    let points = cloud.len();
    let t_build = Instant::now();
    let kd = KdReference::build(cloud).map_err(anyhow::Error::msg)?;
    let build_s = t_build.elapsed().as_secs_f64();
    let result = register_kd(&kd, &q, &config);
    let end_to_end_s = started.elapsed().as_secs_f64();
    let (nn_s, check) = timed_passes(a.nn_repeats, || kd_pass(&kd, &q, config.tau_m))?;
    Ok(json!({
        "method": "kdtree",
        "reference_points": points,
        "load_s": load_s,
        "build_s": build_s,
        "end_to_end_s": end_to_end_s,
        "nn_s_per_iteration": nn_s,
        "iterations": result.iterations,
        "status": result.status,
        "m_world": result.m_world,
        "motion": motion_at(&result.m_world, &q.origin),
        "rmse_m": result.rmse_m,
        "inliers": result.inliers,
        "check": check,
        "peak_rss_mb": peak_rss_mb(),
    }))
}

/// The motion of the local-frame origin (overlap centre) and the rotation angle.
fn motion_at(m: &[[f64; 4]; 4], origin: &Vector3<f64>) -> Value {
    let mat = Matrix4::from_fn(|r, c| m[r][c]);
    let p = mat.transform_point(&Point3::from(*origin));
    let r = mat.fixed_view::<3, 3>(0, 0);
    let angle_deg = ((r.trace() - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    json!({"shift_m": [p.x - origin.x, p.y - origin.y, p.z - origin.z], "rotation_deg": angle_deg})
}

/// Peak resident set of this process (VmHWM), MiB.
fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}
