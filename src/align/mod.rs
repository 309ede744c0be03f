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

pub mod report;
pub mod scene;
pub mod setup;
pub mod solve;

use std::path::PathBuf;

pub use report::{EdgeCounts, FailedPair};
pub use scene::{SceneGraph, WeightsUsed};
pub use setup::AlignPlan;
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
    /// DSMs that no reliable, kept edge constrains: their poses are not learned.
    pub unconstrained: Vec<String>,
    _lock: OutputLock,
}

impl AlignOutcome {
    /// The warning when the weights used are not the requested ones, once.
    pub fn weights_warning(&self) -> Option<String> {
        report::weights_warning(&self.weights, self.counts.tree_edges.is_some())
    }
}

/// Registers every overlapping pair of `store` and solves the poses.
/// `progress(done, total)` follows the pairs.
pub fn align(
    store: &Store,
    cache: &ChunkCache,
    config: &AlignConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<AlignOutcome, AlignError> {
    let plan = setup::plan(store, config)?;
    let (lock, mut journal, done) = setup::open_journal(store, &plan, config)?;
    let outcomes = pipeline::run(
        store,
        cache,
        &plan.tasks,
        &config.pipeline,
        &mut journal,
        done,
        progress,
    )?;
    let scene = scene::build_graph(store, &outcomes, config)?;
    let solution = solve::solve(&scene, config.graph, plan.anchor)?;
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
        unconstrained: report::unconstrained_ids(store, &solution),
        _lock: lock,
    })
}
