//! Sharded `align` for job arrays: `--shard K/N` registers shard K's share of
//! the planned pairs into its own journal `<out>.journal.shard-K-of-N` (no
//! poses), and `--merge` reads every shard journal and solves as a full run.
//!
//! The plan is the full run's (Morton order of the DSM centres, so spatial);
//! shard K takes the contiguous run `[K·P/N, (K+1)·P/N)` of it, which keeps the
//! DSMs a shard reads close together and its cache warm. A shard resumes its
//! journal when the settings match (a re-submitted array task redoes only what
//! is missing) and holds a lock on it, so shards run concurrently while one
//! shard never runs twice. The merge takes the output lock, refuses a shard
//! that is still running, journals written with other settings, and names the
//! shards that are missing or whose journal lacks pairs.

use std::collections::HashSet;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use super::setup::{dsm_ids, journal_settings, AlignPlan};
use super::{AlignConfig, AlignError};
use crate::cache::ChunkCache;
use crate::journal::{Journal, JournalError, OutputLock};
use crate::pipeline::{self, PairOutcome, PairTask};
use crate::store::Store;

/// Largest N of `--shard K/N`.
pub const MAX_SHARDS: usize = 1_000_000;

/// Shard `index` of `count` (`--shard K/N`, K = 0..N-1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

impl FromStr for Shard {
    type Err = String;

    /// `K/N` with 0 <= K < N <= [`MAX_SHARDS`].
    fn from_str(text: &str) -> Result<Shard, String> {
        let bad = || format!("{text:?}: expected K/N with 0 <= K < N, e.g. 0/4");
        let (k, n) = text.split_once('/').ok_or_else(bad)?;
        let (index, count): (usize, usize) = (
            k.trim().parse().map_err(|_| bad())?,
            n.trim().parse().map_err(|_| bad())?,
        );
        if index >= count || count > MAX_SHARDS {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Shard {
    /// This shard's contiguous share of `pairs` planned pairs.
    pub fn range(&self, pairs: usize) -> Range<usize> {
        let cut = |k: usize| (pairs as u128 * k as u128 / self.count as u128) as usize;
        cut(self.index)..cut(self.index + 1)
    }

    /// `<out>.journal.shard-K-of-N`.
    pub fn journal_path(&self, output: &Path) -> PathBuf {
        let mut name = Journal::path_for(output).into_os_string();
        name.push(format!(".shard-{}-of-{}", self.index, self.count));
        PathBuf::from(name)
    }

    /// The shard a journal's file name stands for, beside `output`.
    fn of_journal(output: &Path, file_name: &str) -> Option<Shard> {
        let journal = Journal::path_for(output);
        let stem = journal.file_name()?.to_str()?;
        let rest = file_name.strip_prefix(stem)?.strip_prefix(".shard-")?;
        let (k, n) = rest.split_once("-of-")?;
        let all_digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
        if !all_digits(k) || !all_digits(n) {
            return None;
        }
        Shard::from_str(&format!("{k}/{n}")).ok()
    }
}

/// What one shard did.
#[derive(Clone, Debug, PartialEq)]
pub struct ShardReport {
    pub shard: Shard,
    /// Pairs of the whole plan, and this shard's share.
    pub planned: usize,
    pub pairs: usize,
    /// Pairs found in the shard journal (not registered again).
    pub reused: usize,
    pub registered: usize,
    pub below_overlap: usize,
    pub failed: usize,
    pub journal: PathBuf,
}

/// Registers shard `shard`'s pairs into its journal; `progress(done, total)`
/// follows the shard's pairs.
pub fn run_shard(
    store: &Store,
    cache: &ChunkCache,
    config: &AlignConfig,
    plan: &AlignPlan,
    shard: Shard,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<ShardReport, AlignError> {
    let tasks = &plan.tasks[shard.range(plan.tasks.len())];
    let path = shard.journal_path(&config.output);
    let _lock = OutputLock::acquire(&path)?;
    let (settings, ids) = (journal_settings(config), dsm_ids(store));
    let mine: HashSet<PairTask> = tasks.iter().copied().collect();
    let planned = |p| mine.contains(&p);
    let min_overlap = config.pipeline.min_overlap;
    let (mut journal, done) = match Journal::resume(
        &path,
        &settings,
        ids.clone(),
        &planned,
        min_overlap,
    ) {
        Err(JournalError::Mismatch { .. }) if !config.resume => {
            tracing::warn!(journal = %path.display(), "written with other settings: started afresh");
            (Journal::create(&path, &settings, ids)?, Vec::new())
        }
        other => other?,
    };
    let reused = done.len();
    let outcomes = pipeline::run(
        store,
        cache,
        tasks,
        &config.pipeline,
        &mut journal,
        done,
        progress,
    )?;
    let count = |f: fn(&PairOutcome) -> bool| outcomes.iter().filter(|o| f(o)).count();
    Ok(ShardReport {
        shard,
        planned: plan.tasks.len(),
        pairs: tasks.len(),
        reused,
        registered: count(|o| matches!(o, PairOutcome::Registered { .. })),
        below_overlap: count(|o| matches!(o, PairOutcome::BelowOverlap { .. })),
        failed: count(|o| matches!(o, PairOutcome::Failed { .. })),
        journal: path,
    })
}

/// Every planned pair's outcome, read from the shard journals beside the
/// output (N taken from their names), with the locks that keep the shards
/// from running while they are read. Sorted as a full run sorts them.
pub fn merge_outcomes(
    store: &Store,
    config: &AlignConfig,
    plan: &AlignPlan,
) -> Result<(Vec<OutputLock>, Vec<PairOutcome>), AlignError> {
    let count = shard_count(&config.output)?;
    let (settings, ids) = (journal_settings(config), dsm_ids(store));
    let (mut locks, mut outcomes, mut problems) = (Vec::new(), Vec::new(), Vec::new());
    for index in 0..count {
        let shard = Shard { index, count };
        let path = shard.journal_path(&config.output);
        if !path.exists() {
            problems.push(format!("shard {shard} is missing ({})", path.display()));
            continue;
        }
        locks.push(OutputLock::acquire(&path).map_err(|e| match e {
            JournalError::Busy { .. } => AlignError::Input(format!(
                "shard {shard} is still running (its journal {} is locked); merge after it ends",
                path.display()
            )),
            e => e.into(),
        })?);
        let tasks = &plan.tasks[shard.range(plan.tasks.len())];
        let mine: HashSet<PairTask> = tasks.iter().copied().collect();
        let read = Journal::read(&path, &settings, &ids, &|p| mine.contains(&p), config.pipeline.min_overlap)
            .map_err(|e| match e {
                JournalError::Mismatch { path, found } => AlignError::Input(format!(
                    "{path}: this shard was run with other settings ({found}); give --merge the shards' align flags, or rerun the shard"
                )),
                e => e.into(),
            })?;
        if read.len() < tasks.len() {
            let got: HashSet<PairTask> = read.iter().map(PairOutcome::pair).collect();
            let first = tasks
                .iter()
                .find(|t| !got.contains(t))
                .expect("a pair is missing");
            problems.push(format!(
                "shard {shard} journaled {} of its {} pairs (first missing: {}-{}); rerun --shard {shard}, it resumes",
                read.len(),
                tasks.len(),
                ids.id(first.reference),
                ids.id(first.moving)
            ));
        }
        outcomes.extend(read);
    }
    if !problems.is_empty() {
        return Err(AlignError::Input(format!(
            "{}: cannot merge: {}",
            config.output.display(),
            problems.join("; ")
        )));
    }
    pipeline::sort_by_ids(store, &mut outcomes);
    Ok((locks, outcomes))
}

/// N of the shard journals beside `output`: every one must say the same.
fn shard_count(output: &Path) -> Result<usize, AlignError> {
    let dir = match output.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    let entries = std::fs::read_dir(dir).map_err(|source| {
        AlignError::Journal(JournalError::Io {
            path: dir.display().to_string(),
            source,
        })
    })?;
    let mut counts: Vec<usize> = entries
        .filter_map(|e| e.ok())
        .filter_map(|e| Shard::of_journal(output, e.file_name().to_str()?))
        .map(|s| s.count)
        .collect();
    counts.sort_unstable();
    counts.dedup();
    match counts.as_slice() {
        [n] => Ok(*n),
        [] => Err(AlignError::Input(format!(
            "{}: no shard journal ({}.shard-K-of-N) found; run `align --shard K/N` first",
            output.display(),
            Journal::path_for(output).display()
        ))),
        many => Err(AlignError::Input(format!(
            "{}: shard journals of different shard counts ({}) lie beside it; remove the stale ones",
            output.display(),
            many.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(", ")
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_split_the_plan_into_contiguous_runs() {
        assert_eq!("2/5".parse::<Shard>(), Ok(Shard { index: 2, count: 5 }));
        for bad in ["5/5", "1", "a/3", "-1/3", "0/0", "1/2/3"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
        for (pairs, count) in [(10, 3), (2, 5), (0, 2), (1000, 7)] {
            let mut next = 0;
            for index in 0..count {
                let r = Shard { index, count }.range(pairs);
                assert_eq!(r.start, next, "{pairs} pairs in {count}");
                assert!(r.len() <= pairs / count + 1);
                next = r.end;
            }
            assert_eq!(next, pairs);
        }
    }

    #[test]
    fn journal_names_round_trip_and_others_are_ignored() {
        let out = Path::new("/x/poses.json");
        let s = Shard {
            index: 3,
            count: 12,
        };
        let path = s.journal_path(out);
        assert_eq!(path, Path::new("/x/poses.json.journal.shard-3-of-12"));
        let name = path.file_name().unwrap().to_str().unwrap();
        assert_eq!(Shard::of_journal(out, name), Some(s));
        for other in [
            "poses.json.journal",
            "poses.json.journal.shard-3-of-12.lock",
            "poses.json.journal.shard-12-of-12",
            "other.json.journal.shard-0-of-2",
            "poses.json.journal.shard-+1-of-2",
        ] {
            assert_eq!(Shard::of_journal(out, other), None, "{other}");
        }
    }
}
