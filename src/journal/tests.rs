//! Tests of the journal: round trips, torn lines, and the records it refuses.

use super::*;
use crate::fit::{Axis, FitSigma};
use crate::icp::IcpStatus;
use crate::pipeline::{Failure, IcpFit, PairInformation};
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
            // Odd pairs carry the fit's information; even ones are as an older
            // version journaled them.
            information: (i % 2 == 1).then(|| {
                Box::new(PairInformation {
                    covariance: std::array::from_fn(|r| {
                        std::array::from_fn(|c| if r == c { 1e-4 * (r + 1) as f64 } else { 0.0 })
                    }),
                    centroid_world: [500_000.25, 4_000_000.5, 101.125],
                    degenerate: vec![Axis::X, Axis::Yaw],
                    gridding: (i % 4 == 1).then(|| {
                        std::array::from_fn(|r| {
                            std::array::from_fn(|c| if r == c && r < 2 { 6.25e-4 } else { 0.0 })
                        })
                    }),
                })
            }),
            // Pairs from 2 on carry their search's reach.
            search: (i >= 2).then_some(Box::new(crate::icp::SearchReach {
                cut_m: 9.5,
                reached_m: 19.0,
                offset_m: 0.1 * i as f64 + 1e-9,
            })),
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
fn a_resume_that_cannot_rewrite_the_journal_leaves_it_whole() {
    // The rewrite goes through a temporary name; here it cannot be created (a
    // directory sits there), as on a full disk: the resume fails, naming the
    // journal, and the pairs already journaled are all still there.
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("poses.json.journal");
    let mut j = Journal::create(&path, "s1", ids()).unwrap();
    for i in 0..3 {
        j.append(&outcome(i)).unwrap();
    }
    j.flush().unwrap();
    drop(j);
    let before = std::fs::read(&path).unwrap();
    let blocker = crate::atomic::temp_path(&path);
    std::fs::create_dir(&blocker).unwrap();
    let err = resume(&path, "s1").err().expect("cannot rewrite");
    assert!(matches!(err, JournalError::Io { .. }), "{err}");
    assert!(err.to_string().starts_with(&path.display().to_string()));
    assert_eq!(std::fs::read(&path).unwrap(), before);
    // nor can a fresh start empty it
    assert!(Journal::create(&path, "s2", ids()).is_err());
    assert_eq!(std::fs::read(&path).unwrap(), before);
    std::fs::remove_dir(&blocker).unwrap();
    let (_, records) = resume(&path, "s1").unwrap();
    assert_eq!(records.len(), 3);
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

#[test]
fn information_round_trips_and_older_records_have_none() {
    let record = ids().record(&outcome(3));
    let text = serde_json::to_string(&record).unwrap();
    assert!(text.contains("\"degenerate\":[\"x\",\"yaw\"]"), "{text}");
    let back: EdgeRecord = serde_json::from_str(&text).unwrap();
    let fit = ids().outcome(&back, &|_| true, 0.1).unwrap();
    assert_eq!(fit.edge_fit(), outcome(3).edge_fit());
    let mut old = serde_json::to_value(&record).unwrap();
    old.as_object_mut().unwrap().remove("information");
    let r: EdgeRecord = serde_json::from_value(old).unwrap();
    let back = ids().outcome(&r, &|_| true, 0.1).unwrap();
    assert_eq!(back.edge_fit().unwrap().information, None);
    assert!(!serde_json::to_string(&ids().record(&outcome(2)))
        .unwrap()
        .contains("information"));
    let mut bad = record;
    bad.information.as_mut().unwrap().covariance[0][0] = -1.0;
    let err = ids().outcome(&bad, &|_| true, 0.1).unwrap_err();
    assert!(err.contains("information"), "{err}");
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
    let mut far = ids().record(&outcome(2));
    far.search.as_mut().unwrap().offset_m = -1.0;
    let err = resume_lines(&[serde_json::to_string(&far).unwrap()]);
    assert!(err.to_string().contains("search holds a negative"), "{err}");
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
