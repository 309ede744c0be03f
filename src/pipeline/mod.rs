//! The streaming pipeline of `align`: planner → N ICP workers → outcome sink,
//! joined by bounded crossbeam channels inside one `std::thread::scope`.
//!
//! The planner feeds candidate pairs; each worker scores the overlap on the
//! overviews, runs DSM-ICP through the one shared chunk cache and sends a
//! [`PairOutcome`] keyed by DSM indices; the sink (the calling thread) appends
//! it to the journal and reports progress. Bounded channels give backpressure,
//! so memory is the cache budget (which also covers the chunks the grids pin:
//! [`memory`]) plus a few messages and each worker's pair in flight (its
//! samples, reference windows and ring-plane table: tens of MiB, whatever
//! the collection's size).
//!
//! Threads live here, in one place: the workers run every pair inside one rayon
//! pool of `threads` threads (`pool.install`), so the data-parallel parts of ICP
//! share those threads and `--threads N` bounds the CPUs used. Outcomes are
//! sorted by pair at the end, and each registration is itself deterministic, so
//! the result does not depend on the thread count.

pub mod memory;
mod outcome;
mod register;

pub use outcome::{below_overlap_note, Failure, IcpFit, PairInformation, PairOutcome, PairTask};
pub use register::register_pair;

use std::collections::HashSet;

use crossbeam::channel::bounded;

use crate::cache::ChunkCache;
use crate::icp::IcpConfig;
use crate::journal::{Journal, JournalError};
use crate::store::Store;
use crate::view::PairInputs;

/// The default `--min-overlap`: pairs whose overlap score s_ij is below it
/// give no edge. 0.05 keeps the corners of a grid of tiles overlapping by 30 %
/// (s_ij about 0.09): on the 20 x 20 grids of 128 m tiles their loops took the
/// worst DSM from 0.26 to 0.17 m (docs/measurements.md, "Corner pairs"); a
/// corner too small to measure anything says so in its own status.
pub const DEFAULT_MIN_OVERLAP: f64 = 0.05;

/// The default `--min-overlap-px`: pairs whose footprints share fewer pixels
/// (of the coarser DSM) are not planned. 50 x 50 pixels: the corners of a
/// grid of 64 m tiles at 0.5 m (38 x 38 px) fitted wrong places at
/// centimetre sigmas often enough to spoil the grid, those of 128 m tiles
/// (76 x 76 px) tie it together (docs/measurements.md, "Corner pairs").
pub const DEFAULT_MIN_OVERLAP_PX: u64 = 2500;

/// Settings of one pipeline run.
#[derive(Clone, Debug)]
pub struct PipelineConfig {
    /// Threads of the whole pipeline (workers and their data-parallel ICP).
    pub threads: usize,
    pub icp: IcpConfig,
    /// Pairs scoring below this s_ij give no edge.
    pub min_overlap: f64,
    /// Pairs whose footprints share fewer pixels of the coarser DSM are not
    /// planned (see [`DEFAULT_MIN_OVERLAP_PX`]).
    pub min_overlap_px: u64,
    /// Stable-terrain mask and initial shifts seen by every pair.
    pub inputs: PairInputs,
}

#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error(transparent)]
    Journal(#[from] JournalError),
    #[error("cannot start {threads} worker threads: {source}")]
    Threads {
        threads: usize,
        source: rayon::ThreadPoolBuildError,
    },
}

/// Runs every task not already in `done`; returns all outcomes (old and new),
/// sorted by the ids of (reference, moving). `progress(done, total)` is called
/// by the sink.
pub fn run(
    store: &Store,
    cache: &ChunkCache,
    tasks: &[PairTask],
    config: &PipelineConfig,
    journal: &mut Journal,
    done: Vec<PairOutcome>,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<Vec<PairOutcome>, PipelineError> {
    let finished: HashSet<PairTask> = done.iter().map(PairOutcome::pair).collect();
    let todo: Vec<PairTask> = tasks
        .iter()
        .copied()
        .filter(|t| !finished.contains(t))
        .collect();
    let total = tasks.len();
    let mut outcomes = done;
    // the total (and the pairs reused from the journal) from the start
    progress(outcomes.len(), total);
    let threads = config.threads.max(1);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .thread_name(|k| format!("icp-{k}"))
        .build()
        .map_err(|source| PipelineError::Threads { threads, source })?;
    let result: Result<(), JournalError> = std::thread::scope(|scope| {
        let (task_tx, task_rx) = bounded::<PairTask>(2 * threads);
        let (outcome_tx, outcome_rx) = bounded::<PairOutcome>(2 * threads);
        scope.spawn(move || {
            for task in todo {
                if task_tx.send(task).is_err() {
                    break;
                }
            }
        });
        for _ in 0..threads {
            let (task_rx, outcome_tx, pool) = (task_rx.clone(), outcome_tx.clone(), &pool);
            scope.spawn(move || {
                for task in task_rx.iter() {
                    let outcome = pool.install(|| register_pair(store, cache, task, config));
                    if outcome_tx.send(outcome).is_err() {
                        break;
                    }
                }
            });
        }
        drop(outcome_tx);
        for outcome in outcome_rx.iter() {
            journal.append(&outcome)?;
            outcomes.push(outcome);
            progress(outcomes.len(), total);
        }
        journal.flush()
    });
    result?;
    sort_by_ids(store, &mut outcomes);
    Ok(outcomes)
}

/// Orders outcomes by the ids of (reference, moving), as poses.json lists its
/// edges: each DSM's rank among the sorted ids is computed once.
pub fn sort_by_ids(store: &Store, outcomes: &mut [PairOutcome]) {
    let dsms = store.dsms();
    let mut by_id: Vec<usize> = (0..dsms.len()).collect();
    by_id.sort_by(|&a, &b| dsms[a].id.cmp(&dsms[b].id));
    let mut rank = vec![0; dsms.len()];
    for (r, &k) in by_id.iter().enumerate() {
        rank[k] = r;
    }
    outcomes.sort_by_key(|o| {
        let p = o.pair();
        (rank[p.reference], rank[p.moving])
    });
}
