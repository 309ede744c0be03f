//! The edge journal: every finished pair is appended as one JSON line next to
//! the output, flushed in batches, so an interrupted `align` can `--resume`
//! without redoing finished pairs. A torn last line (killed mid-write) is
//! ignored. The header records the settings; resuming with other settings is
//! refused rather than mixing results, and so is a record that names DSMs or
//! pairs this store does not have, or holds a matrix that is not rigid
//! (error naming the journal and the line). Pairs are written and read as
//! [`PairOutcome`]s; [`record`] converts them to and from the file's lines.
//! [`lock`] keeps a second `align` off the same output.

pub mod lock;
pub mod record;

pub use lock::OutputLock;
pub use record::{DsmIds, EdgeRecord};

use std::collections::HashMap;
use std::fs::File;
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

    /// Starts a fresh journal (truncating an old one) for the DSMs `ids`.
    pub fn create(path: &Path, settings: &str, ids: DsmIds) -> Result<Journal, JournalError> {
        let io = |source| JournalError::Io {
            path: path.display().to_string(),
            source,
        };
        let file = File::create(path).map_err(io)?;
        let mut journal = Journal {
            path: path.to_path_buf(),
            ids,
            writer: BufWriter::new(file),
            pending: 0,
            last_flush: Instant::now(),
        };
        let header = Header {
            dsmstream_journal: 1,
            settings: settings.to_string(),
        };
        journal.write_line(&serde_json::to_string(&header).expect("header serialises"))?;
        journal.flush()?;
        Ok(journal)
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
        let mut outcomes: HashMap<PairTask, PairOutcome> = HashMap::new();
        for (line, record) in &records {
            let outcome = ids
                .outcome(record, planned, min_overlap)
                .map_err(|message| JournalError::BadRecord {
                    path: path.display().to_string(),
                    line: *line,
                    message,
                })?;
            outcomes.insert(outcome.pair(), outcome);
        }
        // Rewrite header + good records so a torn line never sits mid-file.
        let mut journal = Journal::create(path, settings, ids)?;
        journal.write_raw(&text)?;
        journal.flush()?;
        Ok((journal, outcomes.into_values().collect()))
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

    fn write_raw(&mut self, text: &str) -> Result<(), JournalError> {
        let path = self.path.display().to_string();
        self.writer
            .write_all(text.as_bytes())
            .map_err(|source| JournalError::Io { path, source })
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

/// The text of a journal's complete records, and each record with its line number.
type Journaled = (String, Vec<(usize, EdgeRecord)>);

/// The complete records of a journal written with `settings`, with their line
/// numbers (1 = header), and their text; None when the file is missing or
/// empty. Reading stops at the first line that does not parse (a torn write:
/// it and everything after it are redone).
fn read_records(
    path: &Path,
    settings: &str,
) -> Result<Option<Journaled>, JournalError> {
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
mod tests {
    use super::*;
    use crate::fit::FitSigma;
    use crate::icp::IcpStatus;
    use crate::pipeline::{Failure, IcpFit};
    use nalgebra::Matrix4;
    use std::fs::OpenOptions;

    fn ids() -> DsmIds {
        DsmIds::new(
            (0..10)
                .map(|k| format!("t{k}"))
                .chain(["z".into()])
                .collect(),
        )
    }

    fn pair(i: usize, j: usize) -> PairTask {
        PairTask {
            reference: i,
            moving: j,
        }
    }

    fn outcome(i: usize) -> PairOutcome {
        PairOutcome::Registered {
            pair: pair(i, i + 1),
            overlap: 0.5,
            fit: IcpFit {
                status: IcpStatus::Converged,
                t_ref_moving_world: Matrix4::new(
                    1.0,
                    0.0,
                    0.0,
                    0.1 * i as f64,
                    0.0,
                    1.0,
                    0.0,
                    1e-17,
                    0.0,
                    0.0,
                    1.0,
                    3.0,
                    0.0,
                    0.0,
                    0.0,
                    1.0,
                ),
                rmse_m: 0.3,
                inliers: 100,
                iterations: 4,
                sigma: Some(FitSigma {
                    rot_deg: [1e-3, 2e-3, 5e-3],
                    trans_m: [0.01, 0.02, 0.003],
                }),
            },
        }
    }

    fn resume(path: &Path, settings: &str) -> Result<(Journal, Vec<PairOutcome>), JournalError> {
        let (journal, mut outcomes) = Journal::resume(path, settings, ids(), &|_| true, 0.1)?;
        outcomes.sort_by_key(|o| (o.pair().reference, o.pair().moving));
        Ok((journal, outcomes))
    }

    #[test]
    fn resume_returns_records_and_ignores_a_torn_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("poses.json.journal");
        let mut j = Journal::create(&path, "s1", ids()).unwrap();
        for i in 0..5 {
            j.append(&outcome(i)).unwrap();
        }
        j.flush().unwrap();
        drop(j);
        // a torn write
        let mut f = OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(b"{\"reference\":\"t9\",\"mov").unwrap();
        drop(f);
        let (mut j, records) = resume(&path, "s1").unwrap();
        assert_eq!(records.len(), 5);
        assert_eq!(records[2], outcome(2)); // f64 round trip is exact
        j.append(&outcome(7)).unwrap();
        j.flush().unwrap();
        drop(j);
        let (_, records) = resume(&path, "s1").unwrap();
        assert_eq!(records.len(), 6);
        assert!(matches!(
            resume(&path, "other"),
            Err(JournalError::Mismatch { .. })
        ));
    }

    #[test]
    fn a_pair_without_edge_survives_resume() {
        // Its rmse is NaN, written as null: reading it must not stop the resume
        // there (every later pair would be redone).
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("poses.json.journal");
        let mut j = Journal::create(&path, "s1", ids()).unwrap();
        let skipped = PairOutcome::BelowOverlap {
            pair: pair(0, 1),
            overlap: 0.05,
        };
        let unreadable = PairOutcome::Failed {
            pair: pair(9, 10),
            overlap: f64::NAN,
            failure: Failure::Error(
                "overlap scoring failed: c.zarr/b/0/c/0/0: unreadable chunk".into(),
            ),
        };
        j.append(&skipped).unwrap();
        j.append(&outcome(1)).unwrap();
        j.append(&unreadable).unwrap();
        j.flush().unwrap();
        drop(j);
        let text = std::fs::read_to_string(&path).unwrap();
        let first: EdgeRecord = serde_json::from_str(text.lines().nth(1).unwrap()).unwrap();
        assert!(first.rmse_m.is_nan() && first.m_world.is_none());
        let (_, records) = resume(&path, "s1").unwrap();
        assert_eq!(records.len(), 3);
        assert_eq!(records[0], skipped);
        assert_eq!(records[1], outcome(1));
        assert!(records[2].overlap().is_nan());
        // below the threshold is skipped by design; unreadable is a failure
        assert!(matches!(records[2], PairOutcome::Failed { .. }));
        assert_eq!(
            records[2].why_no_edge().unwrap(),
            "overlap scoring failed: c.zarr/b/0/c/0/0: unreadable chunk"
        );
    }

    #[test]
    fn records_journaled_without_sigma_still_load() {
        let mut old = serde_json::to_value(ids().record(&outcome(3))).unwrap();
        old.as_object_mut().unwrap().remove("sigma");
        let r: EdgeRecord = serde_json::from_value(old).unwrap();
        assert_eq!(r.sigma, None);
        assert_eq!(r.m_world, ids().record(&outcome(3)).m_world);
        let back = ids().outcome(&r, &|_| true, 0.1).unwrap();
        assert_eq!(back.edge_fit().unwrap().sigma, None);
    }

    /// Writes a journal of `lines` (after the header) and resumes it.
    fn resume_lines(lines: &[String]) -> JournalError {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.json.journal");
        drop(Journal::create(&path, "s1", ids()).unwrap());
        let mut text = std::fs::read_to_string(&path).unwrap();
        for line in lines {
            text.push_str(line);
            text.push('\n');
        }
        std::fs::write(&path, text).unwrap();
        let err = resume(&path, "s1").err().expect("refused");
        assert!(err.is_bad_input());
        assert!(
            err.to_string().starts_with(&path.display().to_string()),
            "{err}"
        );
        err
    }

    #[test]
    fn records_of_another_collection_or_not_rigid_are_refused_by_line() {
        let good = serde_json::to_string(&ids().record(&outcome(0))).unwrap();
        let other = good.replace("\"t1\"", "\"elsewhere\"");
        let err = resume_lines(&[good.clone(), other]);
        assert!(
            matches!(err, JournalError::BadRecord { line: 3, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("no DSM 'elsewhere'"), "{err}");
        let mut scaled = ids().record(&outcome(0));
        scaled.m_world.as_mut().unwrap()[0][0] = 2.0;
        let err = resume_lines(&[serde_json::to_string(&scaled).unwrap()]);
        assert!(
            matches!(err, JournalError::BadRecord { line: 2, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("not a rigid transform"), "{err}");
    }

    #[test]
    fn a_pair_the_store_does_not_plan_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.json.journal");
        let mut j = Journal::create(&path, "s1", ids()).unwrap();
        j.append(&outcome(4)).unwrap();
        j.flush().unwrap();
        drop(j);
        let planned = |p: PairTask| p.reference != 4;
        let err = Journal::resume(&path, "s1", ids(), &planned, 0.1)
            .err()
            .unwrap();
        assert!(
            err.to_string().contains("t4-t5 is not an overlapping pair"),
            "{err}"
        );
    }
}
