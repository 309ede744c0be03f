//! The edge journal: every finished pair is appended as one JSON line next to
//! the output, flushed in batches, so an interrupted `align` can `--resume`
//! without redoing finished pairs. A torn last line (killed mid-write) is
//! ignored. The header records the settings; resuming with other settings is
//! refused rather than mixing results, and so is a record that names DSMs or
//! pairs this store does not have, or holds a matrix that is not rigid
//! (error naming the journal and the line). Pairs are written and read as
//! [`PairOutcome`]s; [`record`] converts them to and from the file's lines.
//! [`lock`] keeps a second `align` off the same output. A journal is started
//! (or rewritten on resume) under a temporary name and renamed into place:
//! a full disk or a kill then leaves the previous journal whole, never an
//! empty or truncated one.

pub mod lock;
pub mod record;

pub use lock::OutputLock;
pub use record::{DsmIds, EdgeRecord};

use std::collections::HashMap;
use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::pipeline::{PairOutcome, PairTask};

#[derive(Serialize, Deserialize, PartialEq, Debug)]
struct Header {
    dsmstream_journal: u32,
    settings: String,
}

#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: the journal was written with other settings ({found}); remove it or run without --resume")]
    Mismatch { path: String, found: String },
    #[error("{path}: not a dsmstream journal")]
    NotAJournal { path: String },
    #[error("{path}, line {line}: {message}; remove the journal or run without --resume")]
    BadRecord {
        path: String,
        line: usize,
        message: String,
    },
    #[error("another dsmstream align is writing {output} (its lock {lock} is held); wait for it to end or choose another --out")]
    Busy { output: String, lock: String },
}

impl JournalError {
    /// The user's journal or command line is wrong (exit 2), not the disk.
    pub fn is_bad_input(&self) -> bool {
        !matches!(self, JournalError::Io { .. })
    }
}

/// Appends edge records; flushes every `BATCH` records or `FLUSH_EVERY`.
pub struct Journal {
    path: PathBuf,
    ids: DsmIds,
    writer: BufWriter<File>,
    pending: usize,
    last_flush: Instant,
}

const BATCH: usize = 32;
const FLUSH_EVERY: Duration = Duration::from_secs(2);

impl Journal {
    /// The journal path for an output file: `<out>.journal`.
    pub fn path_for(output: &Path) -> PathBuf {
        let mut name = output
            .file_name()
            .map(|n| n.to_os_string())
            .unwrap_or_default();
        name.push(".journal");
        output.with_file_name(name)
    }

    /// Starts a fresh journal (replacing an old one) for the DSMs `ids`.
    pub fn create(path: &Path, settings: &str, ids: DsmIds) -> Result<Journal, JournalError> {
        Self::start(path, settings, ids, "")
    }

    /// The header and then `records` (whole lines) written under a temporary
    /// name and renamed over `path` ([`crate::atomic`]), then opened for
    /// appending: until the rename, a reader (or the next run) sees the old
    /// journal.
    fn start(
        path: &Path,
        settings: &str,
        ids: DsmIds,
        records: &str,
    ) -> Result<Journal, JournalError> {
        let io = |source| JournalError::Io {
            path: path.display().to_string(),
            source,
        };
        let header = Header {
            dsmstream_journal: 1,
            settings: settings.to_string(),
        };
        let header = serde_json::to_string(&header).expect("header serialises");
        crate::atomic::remove_stale_temporaries(path);
        crate::atomic::write_atomically(path, |out| {
            out.write_all(header.as_bytes())?;
            out.write_all(b"\n")?;
            out.write_all(records.as_bytes())
        })
        .map_err(io)?;
        let file = OpenOptions::new().append(true).open(path).map_err(io)?;
        Ok(Journal {
            path: path.to_path_buf(),
            ids,
            writer: BufWriter::new(file),
            pending: 0,
            last_flush: Instant::now(),
        })
    }

    /// Reopens a journal for appending, returning the pairs already in it,
    /// each checked ([`DsmIds::outcome`]: known ids, a `planned` pair, a rigid
    /// matrix). A missing journal starts fresh.
    pub fn resume(
        path: &Path,
        settings: &str,
        ids: DsmIds,
        planned: &dyn Fn(PairTask) -> bool,
        min_overlap: f64,
    ) -> Result<(Journal, Vec<PairOutcome>), JournalError> {
        let Some((text, records)) = read_records(path, settings)? else {
            return Ok((Journal::create(path, settings, ids)?, Vec::new()));
        };
        let outcomes = checked_outcomes(path, &records, &ids, planned, min_overlap)?;
        // Rewrite header + good records so a torn line never sits mid-file.
        Ok((Journal::start(path, settings, ids, &text)?, outcomes))
    }

    /// The pairs of a journal written with `settings`, checked as by
    /// [`Journal::resume`], without opening it for writing (the merge of
    /// sharded runs). A missing or empty journal holds no pair.
    pub fn read(
        path: &Path,
        settings: &str,
        ids: &DsmIds,
        planned: &dyn Fn(PairTask) -> bool,
        min_overlap: f64,
    ) -> Result<Vec<PairOutcome>, JournalError> {
        match read_records(path, settings)? {
            Some((_, records)) => checked_outcomes(path, &records, ids, planned, min_overlap),
            None => Ok(Vec::new()),
        }
    }

    /// Appends one pair's outcome.
    pub fn append(&mut self, outcome: &PairOutcome) -> Result<(), JournalError> {
        let record = self.ids.record(outcome);
        self.write_line(&serde_json::to_string(&record).expect("record serialises"))?;
        self.pending += 1;
        if self.pending >= BATCH || self.last_flush.elapsed() >= FLUSH_EVERY {
            self.flush()?;
        }
        Ok(())
    }

    fn write_line(&mut self, line: &str) -> Result<(), JournalError> {
        let io = |source| JournalError::Io {
            path: self.path.display().to_string(),
            source,
        };
        self.writer.write_all(line.as_bytes()).map_err(io)?;
        self.writer.write_all(b"\n").map_err(io)
    }

    pub fn flush(&mut self) -> Result<(), JournalError> {
        let path = self.path.display().to_string();
        self.writer.flush().map_err(|source| JournalError::Io {
            path: path.clone(),
            source,
        })?;
        self.writer
            .get_ref()
            .sync_data()
            .map_err(|source| JournalError::Io { path, source })?;
        self.pending = 0;
        self.last_flush = Instant::now();
        Ok(())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Each record as a checked outcome (the last one of a pair journaled twice
/// wins); the first bad record is an error naming the journal and its line.
fn checked_outcomes(
    path: &Path,
    records: &[(usize, EdgeRecord)],
    ids: &DsmIds,
    planned: &dyn Fn(PairTask) -> bool,
    min_overlap: f64,
) -> Result<Vec<PairOutcome>, JournalError> {
    let mut outcomes: HashMap<PairTask, PairOutcome> = HashMap::new();
    for (line, record) in records {
        let outcome = ids
            .outcome(record, planned, min_overlap)
            .map_err(|message| JournalError::BadRecord {
                path: path.display().to_string(),
                line: *line,
                message,
            })?;
        outcomes.insert(outcome.pair(), outcome);
    }
    Ok(outcomes.into_values().collect())
}

/// The text of a journal's complete records, and each record with its line number.
type Journaled = (String, Vec<(usize, EdgeRecord)>);

/// The complete records of a journal written with `settings`, with their line
/// numbers (1 = header), and their text; None when the file is missing or
/// empty. Reading stops at the first line that does not parse (a torn write:
/// it and everything after it are redone).
fn read_records(path: &Path, settings: &str) -> Result<Option<Journaled>, JournalError> {
    let io = |source| JournalError::Io {
        path: path.display().to_string(),
        source,
    };
    if !path.exists() {
        return Ok(None);
    }
    let reader = BufReader::new(File::open(path).map_err(io)?);
    let mut lines = reader.lines();
    let header: Header = match lines.next() {
        Some(Ok(line)) => serde_json::from_str(&line).map_err(|_| JournalError::NotAJournal {
            path: path.display().to_string(),
        })?,
        _ => return Ok(None),
    };
    if header.settings != settings {
        return Err(JournalError::Mismatch {
            path: path.display().to_string(),
            found: header.settings,
        });
    }
    let (mut text, mut records) = (String::new(), Vec::new());
    for (k, line) in lines.enumerate() {
        let line = line.map_err(io)?;
        match serde_json::from_str::<EdgeRecord>(&line) {
            Ok(r) => {
                records.push((k + 2, r));
                text.push_str(&line);
                text.push('\n');
            }
            Err(_) => break,
        }
    }
    Ok(Some((text, records)))
}

#[cfg(test)]
mod tests;
