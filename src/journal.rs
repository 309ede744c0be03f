//! The edge journal: every finished pair is appended as one JSON line next to
//! the output, flushed in batches, so an interrupted `align` can `--resume`
//! without redoing finished pairs. A torn last line (killed mid-write) is
//! ignored. The header records the settings; resuming with other settings is
//! refused rather than mixing results.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::fit::FitSigma;
use crate::icp::IcpStatus;

/// One finished pair (reference i, moving j), as journaled and reported.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EdgeRecord {
    pub reference: String,
    pub moving: String,
    /// s_ij measured on the overviews; NaN (JSON null) when scoring failed.
    #[serde(deserialize_with = "nan_if_null")]
    pub overlap: f64,
    /// None when the pair was skipped or failed.
    pub status: Option<IcpStatus>,
    /// Row-major T_ij: p_reference = T_ij p_moving (world coordinates).
    pub m_world: Option<[[f64; 4]; 4]>,
    /// NaN when the pair gave no edge (JSON null: serde_json writes NaN so).
    #[serde(deserialize_with = "nan_if_null")]
    pub rmse_m: f64,
    pub inliers: usize,
    pub iterations: usize,
    /// One-sigma standard errors of T_ij from the last ICP fit (local frame at the
    /// overlap). None in journals written before they were reported.
    #[serde(default)]
    pub sigma: Option<FitSigma>,
    /// Why the pair gave no edge (below --min-overlap, read error, no valid overlap...).
    pub note: Option<String>,
}

/// Reads a number, or null as NaN.
fn nan_if_null<'de, D: serde::Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
    Ok(Option::<f64>::deserialize(deserializer)?.unwrap_or(f64::NAN))
}

impl EdgeRecord {
    pub fn key(&self) -> (String, String) {
        (self.reference.clone(), self.moving.clone())
    }

    /// Skipped by design: scored, and below `min_overlap` (false when the
    /// scoring failed, overlap NaN).
    pub fn below_min_overlap(&self, min_overlap: f64) -> bool {
        self.overlap < min_overlap
    }

    /// Registered with a result the graph can use (converged, or still
    /// improving at the last iteration).
    pub fn usable(&self) -> bool {
        self.m_world.is_some()
            && matches!(
                self.status,
                Some(IcpStatus::Converged | IcpStatus::MaxIterations)
            )
    }

    /// A pair that should have given an edge and did not (scoring failed, ICP
    /// failed, or ICP ended diverged, degenerate or with too few inliers).
    pub fn failed(&self, min_overlap: f64) -> bool {
        !self.usable() && !self.below_min_overlap(min_overlap)
    }

    /// Why a pair gave no edge: its note, else its ICP status.
    pub fn why_no_edge(&self) -> String {
        match (&self.note, self.status) {
            (Some(note), _) => note.clone(),
            (None, Some(status)) => format!("ICP ended {status:?}"),
            (None, None) => "not registered".into(),
        }
    }
}

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
}

/// Appends edge records; flushes every `BATCH` records or `FLUSH_EVERY`.
pub struct Journal {
    path: PathBuf,
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

    /// Starts a fresh journal (truncating an old one).
    pub fn create(path: &Path, settings: &str) -> Result<Journal, JournalError> {
        let io = |source| JournalError::Io {
            path: path.display().to_string(),
            source,
        };
        let file = File::create(path).map_err(io)?;
        let mut journal = Journal {
            path: path.to_path_buf(),
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

    /// Reopens a journal for appending, returning the records already in it.
    /// A missing journal starts fresh.
    pub fn resume(path: &Path, settings: &str) -> Result<(Journal, Vec<EdgeRecord>), JournalError> {
        let io = |source| JournalError::Io {
            path: path.display().to_string(),
            source,
        };
        if !path.exists() {
            return Ok((Journal::create(path, settings)?, Vec::new()));
        }
        let reader = BufReader::new(File::open(path).map_err(io)?);
        let mut lines = reader.lines();
        let header: Header = match lines.next() {
            Some(Ok(line)) => {
                serde_json::from_str(&line).map_err(|_| JournalError::NotAJournal {
                    path: path.display().to_string(),
                })?
            }
            _ => return Ok((Journal::create(path, settings)?, Vec::new())),
        };
        if header.settings != settings {
            return Err(JournalError::Mismatch {
                path: path.display().to_string(),
                found: header.settings,
            });
        }
        let mut records: HashMap<(String, String), EdgeRecord> = HashMap::new();
        let mut text = String::new();
        for line in lines {
            let line = line.map_err(io)?;
            match serde_json::from_str::<EdgeRecord>(&line) {
                Ok(r) => {
                    records.insert(r.key(), r);
                    text.push_str(&line);
                    text.push('\n');
                }
                Err(_) => break, // a torn last line: everything after it is redone
            }
        }
        // Rewrite header + good records so a torn line never sits mid-file.
        let mut journal = Journal::create(path, settings)?;
        journal.writer.write_all(text.as_bytes()).map_err(io)?;
        journal.flush()?;
        let mut records: Vec<EdgeRecord> = records.into_values().collect();
        records.sort_by_key(EdgeRecord::key);
        Ok((journal, records))
    }

    pub fn append(&mut self, record: &EdgeRecord) -> Result<(), JournalError> {
        self.write_line(&serde_json::to_string(record).expect("record serialises"))?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs::OpenOptions;

    fn record(i: usize) -> EdgeRecord {
        EdgeRecord {
            reference: format!("t{i}"),
            moving: format!("t{}", i + 1),
            overlap: 0.5,
            status: Some(IcpStatus::Converged),
            m_world: Some([
                [1.0, 0.0, 0.0, 0.1 * i as f64],
                [0.0, 1.0, 0.0, 1e-17],
                [0.0, 0.0, 1.0, 3.0],
                [0.0, 0.0, 0.0, 1.0],
            ]),
            rmse_m: 0.3,
            inliers: 100,
            iterations: 4,
            sigma: Some(FitSigma {
                rot_deg: [1e-3, 2e-3, 5e-3],
                trans_m: [0.01, 0.02, 0.003],
            }),
            note: None,
        }
    }

    #[test]
    fn resume_returns_records_and_ignores_a_torn_line() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("poses.json.journal");
        let mut j = Journal::create(&path, "s1").unwrap();
        for i in 0..5 {
            j.append(&record(i)).unwrap();
        }
        j.flush().unwrap();
        drop(j);
        // a torn write
        let mut f = OpenOptions::new().append(true).open(&path).unwrap();
        f.write_all(b"{\"reference\":\"t9\",\"mov").unwrap();
        drop(f);
        let (mut j, records) = Journal::resume(&path, "s1").unwrap();
        assert_eq!(records.len(), 5);
        assert_eq!(records[2], record(2)); // f64 round trip is exact
        j.append(&record(7)).unwrap();
        j.flush().unwrap();
        drop(j);
        let (_, records) = Journal::resume(&path, "s1").unwrap();
        assert_eq!(records.len(), 6);
        assert!(matches!(
            Journal::resume(&path, "other"),
            Err(JournalError::Mismatch { .. })
        ));
    }

    #[test]
    fn a_pair_without_edge_survives_resume() {
        // Its rmse is NaN, written as null: reading it must not stop the resume
        // there (every later pair would be redone).
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("poses.json.journal");
        let mut j = Journal::create(&path, "s1").unwrap();
        let skipped = EdgeRecord {
            overlap: 0.05,
            status: None,
            m_world: None,
            rmse_m: f64::NAN,
            sigma: None,
            note: Some("overlap 0.050 below --min-overlap".into()),
            ..record(0)
        };
        let unreadable = EdgeRecord {
            overlap: f64::NAN,
            note: Some("overlap scoring failed: c.zarr/b/0/c/0/0: unreadable chunk".into()),
            ..skipped.clone()
        };
        j.append(&skipped).unwrap();
        j.append(&record(1)).unwrap();
        j.append(&EdgeRecord {
            reference: "t9".into(),
            moving: "z".into(),
            ..unreadable
        })
        .unwrap();
        j.flush().unwrap();
        drop(j);
        let (_, records) = Journal::resume(&path, "s1").unwrap();
        assert_eq!(records.len(), 3);
        assert!(records[0].rmse_m.is_nan() && records[0].m_world.is_none());
        assert_eq!(records[1], record(1));
        assert!(records[2].overlap.is_nan());
        // below the threshold is skipped by design; unreadable is a failure
        assert!(!records[0].failed(0.1) && records[2].failed(0.1) && !records[1].failed(0.1));
    }

    #[test]
    fn records_journaled_without_sigma_still_load() {
        let mut old = serde_json::to_value(record(3)).unwrap();
        old.as_object_mut().unwrap().remove("sigma");
        let r: EdgeRecord = serde_json::from_value(old).unwrap();
        assert_eq!(r.sigma, None);
        assert_eq!(r.m_world, record(3).m_world);
    }
}
