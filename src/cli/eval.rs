//! `dsmstream eval <store> [--poses poses.json] [--reference ref.tif|lidar.laz]`:
//! rmse_tau and robust figures over every overlapping pair before/after the
//! poses, and against a reference; a table (or `--json`) on stdout and, with
//! `--plots DIR`, the scene graph, histograms and difference map as PNG.

use std::path::PathBuf;

use dsmstream::eval::{evaluate, EvalConfig, EvalError, PairCounter};
use dsmstream::fuse::{FuseError, PoseSet};
use dsmstream::plots::write_eval_plots;
use dsmstream::InputError;

use super::common::{
    classify, emit, emit_line, open_store, progress_bar, require_file, ResourceArgs,
};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The store directory.
    pub store: PathBuf,
    /// poses.json from `dsmstream align` (omit to evaluate the raw collection).
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Inlier threshold of rmse_tau, metres (paper: 10).
    #[arg(long, default_value_t = 10.0)]
    pub tau: f64,
    /// Reference surface: a GeoTIFF DSM, or a LAS/LAZ point cloud, in the store's CRS.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Print the report as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Write PNG pictures into this folder.
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Most sample locations per pair and for the reference.
    #[arg(long, default_value_t = 1_000_000)]
    pub max_samples: u64,
    /// Use every lidar return (default: first returns only).
    #[arg(long)]
    pub all_returns: bool,
    #[command(flatten)]
    pub resources: ResourceArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.max_samples == 0 {
        return Err(InputError::new("--max-samples must be at least 1").into());
    }
    for (path, flag) in [(&args.poses, "--poses"), (&args.reference, "--reference")] {
        if let Some(p) = path {
            require_file(p, flag)?;
        }
    }
    let store = open_store(&args.store)?;
    let poses = match &args.poses {
        Some(p) => {
            Some(PoseSet::from_file(&store, p).map_err(|e| classify(e, FuseError::is_bad_input))?)
        }
        None => None,
    };
    let config = EvalConfig {
        tau_m: args.tau,
        max_samples: args.max_samples,
        threads: args.resources.threads(),
        all_returns: args.all_returns,
        progress: PairCounter::default(),
    };
    let cache = args.resources.cache();
    let bar = progress_bar("pairs");
    let result = std::thread::scope(|scope| {
        let work = scope.spawn(|| {
            evaluate(
                &store,
                &cache,
                poses.as_ref(),
                args.reference.as_deref(),
                &config,
            )
        });
        let report = || {
            let (done, total) = config.progress.get();
            bar.set_length(total);
            bar.set_position(done);
        };
        while !work.is_finished() {
            report();
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
        // A run shorter than one poll still ends its log with the final count.
        report();
        work.join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
    });
    bar.finish_and_clear();
    let (report, plot_data) = result.map_err(|e| classify(e, EvalError::is_bad_input))?;
    cache.log_stats();
    if args.json {
        emit_line(&serde_json::to_string_pretty(&report)?)?;
    } else {
        emit(&report.to_table())?;
    }
    if let Some(dir) = &args.plots {
        let written = write_eval_plots(dir, &store, poses.as_ref(), &report, &plot_data)?;
        if !args.json {
            for p in written {
                emit_line(&format!("plot written: {}", p.display()))?;
            }
        }
    }
    Ok(())
}
