//! The streaming pipeline of `align`: planner → N ICP workers → edge sink,
//! joined by bounded crossbeam channels inside one `std::thread::scope`.
//!
//! The planner feeds candidate pairs; each worker scores the overlap on the
//! overviews, runs DSM-ICP through the one shared chunk cache and sends an
//! [`EdgeRecord`]; the sink (the calling thread) appends it to the journal and
//! reports progress. Bounded channels give backpressure, so memory is the cache
//! budget plus a few messages. Records are sorted by pair at the end, and each
//! registration is itself deterministic, so the result does not depend on the
//! thread count.

use crossbeam::channel::bounded;

use crate::cache::ChunkCache;
use crate::grid::{Grid, Pyramid};
use crate::icp::{matrix_rows, register, IcpConfig};
use crate::journal::{EdgeRecord, Journal, JournalError};
use crate::plan::{overlap_score, scoring_level};
use crate::store::{Store, StorePyramid};

/// Settings of one pipeline run.
#[derive(Clone, Debug)]
pub struct PipelineConfig {
    pub threads: usize,
    pub icp: IcpConfig,
    /// Pairs scoring below this s_ij give no edge.
    pub min_overlap: f64,
}

/// A candidate pair by DSM index (reference < moving).
#[derive(Clone, Copy, Debug)]
pub struct PairTask {
    pub reference: usize,
    pub moving: usize,
}

/// Runs every task not already in `done`; returns all records (old and new),
/// sorted by (reference, moving) id. `progress(done, total)` is called by the sink.
pub fn run(
    store: &Store,
    cache: &ChunkCache,
    tasks: &[PairTask],
    config: &PipelineConfig,
    journal: &mut Journal,
    done: Vec<EdgeRecord>,
    progress: &mut dyn FnMut(&EdgeRecord, usize, usize),
) -> Result<Vec<EdgeRecord>, JournalError> {
    let ids = |t: &PairTask| {
        (
            store.dsms()[t.reference].id.clone(),
            store.dsms()[t.moving].id.clone(),
        )
    };
    let finished: std::collections::HashSet<(String, String)> =
        done.iter().map(EdgeRecord::key).collect();
    let todo: Vec<PairTask> = tasks
        .iter()
        .copied()
        .filter(|t| !finished.contains(&ids(t)))
        .collect();
    let total = tasks.len();
    let mut records = done;
    let threads = config.threads.max(1);
    let result: Result<(), JournalError> = std::thread::scope(|scope| {
        let (task_tx, task_rx) = bounded::<PairTask>(2 * threads);
        let (edge_tx, edge_rx) = bounded::<EdgeRecord>(2 * threads);
        scope.spawn(move || {
            for task in todo {
                if task_tx.send(task).is_err() {
                    break;
                }
            }
        });
        for _ in 0..threads {
            let (task_rx, edge_tx) = (task_rx.clone(), edge_tx.clone());
            scope.spawn(move || {
                for task in task_rx.iter() {
                    let record = register_pair(store, cache, task, config);
                    if edge_tx.send(record).is_err() {
                        break;
                    }
                }
            });
        }
        drop(edge_tx);
        for record in edge_rx.iter() {
            journal.append(&record)?;
            records.push(record);
            progress(records.last().unwrap(), records.len(), total);
        }
        journal.flush()
    });
    result?;
    records.sort_by_key(EdgeRecord::key);
    Ok(records)
}

/// Scores one pair on the overviews and, if it overlaps enough, registers it.
#[tracing::instrument(level = "debug", skip_all, fields(reference = task.reference, moving = task.moving))]
pub fn register_pair(
    store: &Store,
    cache: &ChunkCache,
    task: PairTask,
    config: &PipelineConfig,
) -> EdgeRecord {
    let dsms = store.dsms();
    let (ri, mi) = (&dsms[task.reference], &dsms[task.moving]);
    let mut record = EdgeRecord {
        reference: ri.id.clone(),
        moving: mi.id.clone(),
        overlap: 0.0,
        status: None,
        m_world: None,
        rmse_m: f64::NAN,
        inliers: 0,
        iterations: 0,
        sigma: None,
        note: None,
    };
    let reference = StorePyramid::new(store, cache, task.reference);
    let moving = StorePyramid::new(store, cache, task.moving);
    match score(&reference, &moving, ri, mi) {
        Ok(s) => record.overlap = s,
        Err(e) => {
            tracing::warn!(reference = %ri.id, moving = %mi.id, error = %e, "pair failed");
            record.overlap = f64::NAN;
            record.note = Some(format!("overlap scoring failed: {e}"));
            return record;
        }
    }
    if record.overlap < config.min_overlap {
        record.note = Some(format!("overlap {:.3} below --min-overlap", record.overlap));
        return record;
    }
    match register(&reference, &moving, &config.icp) {
        Ok(r) => {
            tracing::debug!(reference = %ri.id, moving = %mi.id, rmse_m = r.rmse_m, status = ?r.status, "pair aligned");
            record.status = Some(r.status);
            record.m_world = Some(matrix_rows(&r.t_ref_moving));
            record.rmse_m = r.rmse_m;
            record.inliers = r.inliers;
            record.iterations = r.iterations;
            record.sigma = Some(r.sigma);
        }
        Err(e) => {
            tracing::warn!(reference = %ri.id, moving = %mi.id, error = %e, "pair failed");
            record.note = Some(e.to_string());
        }
    }
    record
}

fn score(
    reference: &StorePyramid<'_>,
    moving: &StorePyramid<'_>,
    ri: &crate::store::DsmMeta,
    mi: &crate::store::DsmMeta,
) -> Result<f64, String> {
    // Score on a common level: the coarser of the two DSMs' scoring levels.
    let sizes = |m: &crate::store::DsmMeta| {
        m.levels
            .iter()
            .map(|l| (l.width, l.height))
            .collect::<Vec<_>>()
    };
    let level = scoring_level(&sizes(ri))
        .max(scoring_level(&sizes(mi)))
        .min(ri.levels.len().min(mi.levels.len()) - 1);
    let mut a = reference.open_level(level)?;
    let mut b = moving.open_level(level)?;
    let s = overlap_score(&mut a, &mut b);
    // A chunk that failed to decode reads as no-data: say so, not "no overlap".
    match a.take_error().or_else(|| b.take_error()) {
        Some(e) => Err(e),
        None => Ok(s),
    }
}
