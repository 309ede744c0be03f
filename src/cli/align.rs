//! `dsmstream align <store> --out poses.json`: every overlapping pair through
//! DSM-ICP, the scene graph, motion averaging (or `--graph mst`), poses.json;
//! `--shard K/N` registers one shard's pairs only, `--merge` solves from them.
//! `--mask` limits every pair to stable terrain; `--initial` starts each DSM
//! from a given pose and keeps the collection where those poses put it.

use std::path::PathBuf;

use dsmstream::align::{
    align, align_shard, AlignConfig, AlignOutcome, Shard, ShardReport, Sharding,
};
use dsmstream::cache::ChunkCache;
use dsmstream::graph::Weighting;
use dsmstream::pipeline::memory::{pinned_bytes_per_thread, plan_memory};
use dsmstream::pipeline::PipelineConfig;
use dsmstream::poses::GraphKind;
use dsmstream::InputError;

use super::common::{emit_line, open_store, progress_bar, quiet, warn_line, ResourceArgs};
use super::icp_args::{IcpArgs, InputArgs};

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum GraphArg {
    /// Every overlapping pair, motion averaging (the paper's method).
    Full,
    /// Kruskal maximum-overlap spanning tree, poses chained from the root (baseline).
    Mst,
}

#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum WeightsArg {
    /// Inverse variances from each pair's ICP standard errors, separate for
    /// rotation and translation (outliers judged in sigmas).
    Information,
    /// The paper's w = s_ij * r_ij (overlap times softmax of -RMSE), both parts.
    Paper,
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The store directory.
    pub store: PathBuf,
    /// Where to write poses.json (written to a temporary name, then renamed).
    #[arg(long)]
    pub out: PathBuf,
    #[command(flatten)]
    pub resources: ResourceArgs,
    /// full (motion averaging) or mst (greedy spanning tree baseline).
    #[arg(long, value_enum, default_value = "full")]
    pub graph: GraphArg,
    /// Edge weights of the motion averaging: information (inverse variances) or paper.
    #[arg(long, value_enum, default_value = "information")]
    pub weights: WeightsArg,
    /// Pairs whose overlap score s_ij is below this give no edge.
    #[arg(long, default_value_t = dsmstream::pipeline::DEFAULT_MIN_OVERLAP)]
    pub min_overlap: f64,
    /// Pairs whose footprints share fewer pixels (of the coarser DSM) are not
    /// registered: too small to tell a wrong place from the right one.
    #[arg(long, default_value_t = dsmstream::pipeline::DEFAULT_MIN_OVERLAP_PX)]
    pub min_overlap_px: u64,
    /// Keep this DSM fixed (identity pose) instead of the mean gauge.
    #[arg(long)]
    pub anchor: Option<String>,
    /// Skip pairs already in the journal (<out>.journal) of an earlier run with
    /// the same settings (the default; kept for scripts).
    #[arg(long, conflicts_with = "fresh")]
    pub resume: bool,
    /// Start over: discard the journal of an earlier run.
    #[arg(long)]
    pub fresh: bool,
    /// Register only shard K of N of the planned pairs (K = 0..N-1, e.g.
    /// $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT) into <out>.journal.shard-K-of-N,
    /// resuming it when the settings match; writes no poses (see --merge).
    #[arg(long, value_name = "K/N", conflicts_with = "merge")]
    pub shard: Option<Shard>,
    /// Solve from every shard journal beside --out (same flags as the shards)
    /// and write the poses: the result of a single run.
    #[arg(long, conflicts_with = "resume")]
    pub merge: bool,
    #[command(flatten)]
    pub icp: IcpArgs,
    #[command(flatten)]
    pub inputs: InputArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(0.0..=1.0).contains(&args.min_overlap) {
        return Err(InputError::new("--min-overlap must be within [0, 1]").into());
    }
    let store = open_store(&args.store)?;
    let (inputs, initial) = args.inputs.load(&store)?;
    let memory = plan_memory(
        (args.resources.cache_mb as usize) << 20,
        pinned_bytes_per_thread(&store),
        args.resources.threads(),
        args.resources.threads.is_some(),
    )
    .map_err(InputError::new)?;
    let config = AlignConfig {
        pipeline: PipelineConfig {
            threads: memory.threads,
            icp: args.icp.to_config()?,
            min_overlap: args.min_overlap,
            min_overlap_px: args.min_overlap_px,
            inputs,
        },
        graph: match args.graph {
            GraphArg::Full => GraphKind::Full,
            GraphArg::Mst => GraphKind::Mst,
        },
        weights: match args.weights {
            WeightsArg::Information => Weighting::Information,
            WeightsArg::Paper => Weighting::Paper,
        },
        anchor: args.anchor.clone(),
        resume: !args.fresh,
        output: args.out.clone(),
        sharding: match (args.shard, args.merge) {
            (Some(s), _) => Sharding::Shard(s),
            (None, true) => Sharding::Merge,
            (None, false) => Sharding::Whole,
        },
    };
    tracing::info!(
        threads = memory.threads,
        cache_mb = memory.cache_budget_bytes >> 20,
        pinned_mb = memory.pinned_bytes >> 20,
        "memory planned"
    );
    let cache = ChunkCache::new(memory.cache_budget_bytes);
    let bar = progress_bar("pairs");
    let started = std::time::Instant::now();
    let mut progress = |done: usize, total: usize| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        let s = cache.stats();
        let lookups = (s.hits + s.misses).max(1);
        bar.set_message(format!(
            "cache hit {:.0}%",
            100.0 * s.hits as f64 / lookups as f64
        ));
    };
    if let Sharding::Shard(shard) = config.sharding {
        let report = align_shard(&store, &cache, &config, shard, &mut progress);
        bar.finish_and_clear();
        let report = report.map_err(to_anyhow)?;
        cache.log_stats();
        return print_shard(&report, started.elapsed().as_secs_f64());
    }
    let outcome = align(&store, &cache, &config, &mut progress);
    bar.finish_and_clear();
    let mut outcome = outcome.map_err(to_anyhow)?;
    cache.log_stats();
    if let Some(initial) = &initial {
        initial.regauge(&store, &mut outcome.poses, args.anchor.as_deref());
    }
    outcome.poses.write(&args.out)?;
    print_summary(&outcome, &args.out, started.elapsed().as_secs_f64())?;
    Ok(())
}

fn to_anyhow(e: dsmstream::align::AlignError) -> anyhow::Error {
    if e.is_bad_input() {
        anyhow::Error::new(InputError::new(e.to_string()))
    } else {
        anyhow::Error::new(e)
    }
}

/// The summary (stdout) of one shard.
fn print_shard(r: &ShardReport, seconds: f64) -> anyhow::Result<()> {
    emit_line(&format!(
        "shard {}: {} of {} planned pairs ({} from its journal): {} registered, {} below --min-overlap, {} failed, {seconds:.1} s",
        r.shard, r.pairs, r.planned, r.reused, r.registered, r.below_overlap, r.failed
    ))?;
    emit_line(&format!("journal written to {}", r.journal.display()))?;
    Ok(())
}

/// The warnings (stderr) and the summary (stdout) of a finished run.
fn print_summary(
    outcome: &AlignOutcome,
    out: &std::path::Path,
    seconds: f64,
) -> std::io::Result<()> {
    if outcome.reused_pairs > 0 && !quiet() {
        eprintln!(
            "resumed: {} pairs reused from {} (--fresh starts over)",
            outcome.reused_pairs,
            dsmstream::journal::Journal::path_for(out).display()
        );
    }
    if outcome.too_small_pairs > 0 {
        warn_line(&format!(
            "{} overlapping pairs share fewer than --min-overlap-px pixels: not registered",
            outcome.too_small_pairs
        ));
    }
    for f in &outcome.failed_pairs {
        warn_line(&format!(
            "pair {}-{} ({}) gave no edge",
            f.reference, f.moving, f.why
        ));
    }
    if let Some(warning) = outcome.weights_warning() {
        warn_line(&warning);
    }
    if outcome.components.len() > 1 {
        let mut text = format!(
            "the scene graph has {} disconnected components, each solved on its own:",
            outcome.components.len()
        );
        for c in &outcome.components {
            text.push_str(&format!("\n  {}", c.join(", ")));
        }
        warn_line(&text);
    }
    let p = &outcome.poses;
    let c = outcome.counts;
    let kept: Vec<&dsmstream::poses::EdgeEntry> = p.edges.iter().filter(|e| !e.dropped).collect();
    let mean_rmse = kept.iter().map(|e| e.rmse_m).sum::<f64>() / kept.len().max(1) as f64;
    let max_res = kept.iter().map(|e| e.residual_m).fold(0.0, f64::max);
    let (edges, graph, solved) = match c.tree_edges {
        Some(tree) => (
            format!("{tree} tree edges of {} registered pairs", c.edges),
            "mst".to_string(),
            "of the chained poses",
        ),
        None => (
            format!(
                "{} edges ({} dropped, {} down-weighted{})",
                c.edges,
                c.dropped,
                c.downweighted,
                match c.unreliable {
                    0 => String::new(),
                    n => format!(
                        ", {n} not converged or ambiguous at {} % weight",
                        percent(c.unreliable_weight.unwrap_or(0.01))
                    ),
                }
            ),
            format!("full, weights {}", outcome.weights.used.label()),
            "after averaging",
        ),
    };
    emit_line(&format!(
        "aligned {} DSMs: {edges}, {} pairs without edge, graph {graph}, gauge {}, {seconds:.1} s",
        p.poses.len(),
        outcome.failed_pairs.len(),
        p.gauge.label(),
    ))?;
    emit_line(&format!(
        "mean pairwise ICP rmse {mean_rmse:.3} m; largest edge residual {solved} {max_res:.3} m"
    ))?;
    if let Some(r) = outcome.reach.as_ref().filter(|r| r.reach.widened > 0) {
        emit_line(&format!(
            "{} of {} searches widened beyond half an overlap converged farther than {:.1} m (twice the offset {:.0} % of the {} clear pairs lie within): ambiguous",
            r.judged.len(),
            r.reach.widened,
            r.reach.bound_m,
            100.0 * dsmstream::align::reach::QUANTILE,
            r.reach.clear,
        ))?;
    }
    if let Some(f) = c.variance_factor.filter(|_| c.tree_edges.is_none()) {
        emit_line(&if f > 1.0 {
            format!(
                "the pairs disagree {:.1}x more than their sigmas say (variance factor {f:.2}): pose sigmas scaled by {:.2}",
                f.sqrt(),
                f.sqrt()
            )
        } else {
            format!("the pairs agree within their sigmas (variance factor {f:.2})")
        })?;
    }
    if !outcome.unconstrained.is_empty() {
        emit_line(&format!(
            "{} DSMs unconstrained (no reliable edge; poses not learned from the data): {}",
            outcome.unconstrained.len(),
            outcome.unconstrained.join(", ")
        ))?;
    }
    emit_line(&format!("poses written to {}", out.display()))
}

/// A weight factor as a percentage: two significant digits, at least "1".
fn percent(factor: f64) -> String {
    let p = factor * 100.0;
    if p >= 10.0 {
        format!("{p:.0}")
    } else {
        format!("{p:.1}").trim_end_matches(".0").to_string()
    }
}
