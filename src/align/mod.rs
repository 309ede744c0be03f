//! `align` as a library call, in five steps, each a function of its own file:
//!
//! ```text
//! setup::plan ──► pipeline::run ──► scene::build_graph ──► solve::solve ──► report
//! (checks, pairs,   (workers: PairOutcome   (edges in a local     (motion averaging    (poses.json in
//!  output lock,      per pair, journaled)    frame, weights)       or spanning tree)    world coordinates)
//!  journal)
//! ```
//!
//! Pairs travel by DSM index; ids appear only in the journal and the report.
//! [`shard`] splits the pairwise step over processes (`--shard K/N`, `--merge`).

pub mod reach;
pub mod report;
pub mod scene;
pub mod setup;
pub mod shard;
pub mod solve;

use std::path::PathBuf;

pub use reach::ReachReport;
pub use report::{EdgeCounts, FailedPair};
pub use scene::{SceneGraph, WeightsUsed};
pub use setup::AlignPlan;
pub use shard::{Shard, ShardReport};
pub use solve::PoseSolution;

use crate::cache::ChunkCache;
use crate::graph::Weighting;
use crate::journal::{JournalError, OutputLock};
use crate::pipeline::{self, PipelineConfig, PipelineError};
use crate::poses::{GraphKind, PosesFile};
use crate::store::Store;

/// Everything `align` needs, validated by the CLI.
#[derive(Clone, Debug)]
pub struct AlignConfig {
    pub pipeline: PipelineConfig,
    pub graph: GraphKind,
    /// Edge weights of the averaging (`--weights`).
    pub weights: Weighting,
    /// Id of the DSM that stays fixed; None = mean gauge.
    pub anchor: Option<String>,
    pub resume: bool,
    pub output: PathBuf,
    /// A whole run, one shard of it, or the merge of the shards.
    pub sharding: Sharding,
}

/// How much of the run this process does ([`shard`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Sharding {
    /// Every pair, then the poses.
    #[default]
    Whole,
    /// Only this shard's pairs, into its own journal; no poses ([`align_shard`]).
    Shard(Shard),
    /// No pair registered: the shards' journals, then the poses.
    Merge,
}

#[derive(Debug, thiserror::Error)]
pub enum AlignError {
    /// Bad input: the message says what to change.
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Journal(#[from] JournalError),
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    #[error("motion averaging failed: {0}")]
    Averaging(String),
}

impl AlignError {
    /// The user's input is wrong (exit 2), not the work.
    pub fn is_bad_input(&self) -> bool {
        match self {
            AlignError::Input(_) => true,
            AlignError::Journal(e) | AlignError::Pipeline(PipelineError::Journal(e)) => {
                e.is_bad_input()
            }
            _ => false,
        }
    }
}

/// The result: the poses file, what the user should hear about, and the lock
/// on the output (held until the outcome is dropped, after the poses are written).
#[derive(Debug)]
pub struct AlignOutcome {
    pub poses: PosesFile,
    /// Pairs that should have given an edge and did not.
    pub failed_pairs: Vec<FailedPair>,
    pub components: Vec<Vec<String>>,
    pub weights: WeightsUsed,
    pub counts: EdgeCounts,
    /// Pairs taken from the journal of an earlier run instead of registered.
    pub reused_pairs: usize,
    /// Overlapping pairs not planned: fewer than `--min-overlap-px` shared pixels.
    pub too_small_pairs: usize,
    /// DSMs that no reliable, kept edge constrains: their poses are not learned.
    pub unconstrained: Vec<String>,
    /// The collection's offset bound and the converged pairs beyond it, made
    /// `ambiguous` ([`reach`]); None when the pairs could not teach one.
    pub reach: Option<ReachReport>,
    _lock: OutputLock,
}

impl AlignOutcome {
    /// The warning when the weights used are not the requested ones, once.
    pub fn weights_warning(&self) -> Option<String> {
        report::weights_warning(&self.weights, self.counts.tree_edges.is_some())
    }
}

/// Registers every overlapping pair of `store` and solves the poses; with
/// [`Sharding::Merge`], takes the pairs from the shard journals instead.
/// `progress(done, total)` follows the pairs.
pub fn align(
    store: &Store,
    cache: &ChunkCache,
    config: &AlignConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<AlignOutcome, AlignError> {
    let plan = setup::plan(store, config)?;
    let mut reused_pairs = 0;
    let (lock, mut outcomes, _shard_locks) = match config.sharding {
        Sharding::Whole => {
            let (lock, mut journal, done) = setup::open_journal(store, &plan, config)?;
            reused_pairs = done.len();
            let outcomes = pipeline::run(
                store,
                cache,
                &plan.tasks,
                &config.pipeline,
                &mut journal,
                done,
                progress,
            )?;
            (lock, outcomes, Vec::new())
        }
        Sharding::Merge => {
            let lock = OutputLock::acquire(&config.output)?;
            let (shard_locks, outcomes) = shard::merge_outcomes(store, config, &plan)?;
            progress(outcomes.len(), plan.tasks.len());
            (lock, outcomes, shard_locks)
        }
        Sharding::Shard(s) => {
            return Err(AlignError::Input(format!(
                "--shard {s} writes no poses: run it through align_shard"
            )))
        }
    };
    let reach = reach::judge(&mut outcomes, &config.pipeline.icp);
    let scene = scene::build_graph(store, &outcomes, config)?;
    let prior_deg = config.pipeline.icp.rotation_prior_deg;
    let mut solution = solve::solve(&scene, config.graph, plan.anchor, prior_deg)?;
    if config.pipeline.icp.model == crate::fit::Model::Translation {
        scene::hold_rotations(store, &scene.origin_world, &mut solution.poses_local);
    }
    let parts = report::Parts {
        store,
        config,
        anchor: plan.anchor,
        outcomes: &outcomes,
        scene: &scene,
        solution: &solution,
    };
    Ok(AlignOutcome {
        poses: report::poses_file(&parts),
        failed_pairs: report::failed_pairs(store, &outcomes),
        components: report::component_ids(store, &solution),
        weights: scene.weights.clone(),
        counts: report::edge_counts(&scene, &solution),
        reused_pairs,
        too_small_pairs: plan.too_small,
        unconstrained: report::unconstrained_ids(store, &solution),
        reach,
        _lock: lock,
    })
}

/// Registers one shard's pairs (`--shard K/N`) into its journal; no poses.
pub fn align_shard(
    store: &Store,
    cache: &ChunkCache,
    config: &AlignConfig,
    shard: Shard,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ShardReport, AlignError> {
    let plan = setup::plan(store, config)?;
    shard::run_shard(store, cache, config, &plan, shard, progress)
}
