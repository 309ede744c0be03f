//! One journal line ([`EdgeRecord`], the file format: ids, row-major matrix,
//! status, note) and its conversion to and from a [`PairOutcome`] keyed by DSM
//! indices, done once here with [`DsmIds`]. Records read back are checked as
//! strictly as user input: known ids, a planned pair, finite numbers, a rigid
//! matrix.

use std::collections::HashMap;

use nalgebra::Matrix4;
use serde::{Deserialize, Serialize};

use crate::fit::FitSigma;
use crate::icp::{IcpStatus, SearchReach};
use crate::pipeline::{Failure, IcpFit, PairInformation, PairOutcome, PairTask};
use crate::poses::rigid::rigidity;
use crate::poses::RIGIDITY_TOLERANCE;

/// One finished pair (reference i, moving j), as journaled.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EdgeRecord {
    pub reference: String,
    pub moving: String,
    /// s_ij measured on the overviews; NaN (JSON null) when scoring failed.
    #[serde(deserialize_with = "nan_if_null")]
    pub overlap: f64,
    /// None when the pair was skipped or failed.
    pub status: Option<IcpStatus>,
    /// Row-major T_ref_moving in world coordinates: p_reference = T p_moving.
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
    /// The fit's covariance and degenerate axes. None in journals written
    /// before it was reported (the edge then falls back to `sigma`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub information: Option<PairInformation>,
    /// How far the global search looked (absent in journals written before).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub search: Option<SearchReach>,
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
}

/// The DSM ids of the store by index, and back: the one place where a pair
/// changes between indices and ids.
#[derive(Clone, Debug, Default)]
pub struct DsmIds {
    ids: Vec<String>,
    index: HashMap<String, usize>,
}

impl DsmIds {
    pub fn new(ids: Vec<String>) -> Self {
        let index = ids
            .iter()
            .enumerate()
            .map(|(k, id)| (id.clone(), k))
            .collect();
        DsmIds { ids, index }
    }

    pub fn id(&self, k: usize) -> &str {
        &self.ids[k]
    }

    /// The journal line of an outcome.
    pub fn record(&self, outcome: &PairOutcome) -> EdgeRecord {
        let pair = outcome.pair();
        let mut record = EdgeRecord {
            reference: self.ids[pair.reference].clone(),
            moving: self.ids[pair.moving].clone(),
            overlap: outcome.overlap(),
            status: None,
            m_world: None,
            rmse_m: f64::NAN,
            inliers: 0,
            iterations: 0,
            sigma: None,
            information: None,
            search: None,
            note: None,
        };
        let Some(fit) = outcome.fit() else {
            record.note = outcome.why_no_edge();
            return record;
        };
        let m = &fit.t_ref_moving_world;
        record.status = Some(fit.status);
        record.m_world = Some(std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)])));
        record.rmse_m = fit.rmse_m;
        record.inliers = fit.inliers;
        record.iterations = fit.iterations;
        record.sigma = fit.sigma;
        record.information = fit.information.as_deref().cloned();
        record.search = fit.search.as_deref().copied();
        record
    }

    /// The outcome a journal line stands for, checked: its ids are DSMs of this
    /// store, the pair is planned, its numbers finite and its matrix rigid.
    /// `Err` says what is wrong (the caller names the journal and line).
    pub fn outcome(
        &self,
        record: &EdgeRecord,
        planned: &dyn Fn(PairTask) -> bool,
        min_overlap: f64,
    ) -> Result<PairOutcome, String> {
        let index = |id: &str| {
            self.index.get(id).copied().ok_or_else(|| {
                format!("no DSM '{id}' in the store: the journal belongs to another collection")
            })
        };
        let pair = PairTask {
            reference: index(&record.reference)?,
            moving: index(&record.moving)?,
        };
        if !planned(pair) {
            return Err(format!(
                "{}-{} is not an overlapping pair of this store: the journal belongs to another collection",
                record.reference, record.moving
            ));
        }
        let overlap = record.overlap;
        if !(overlap.is_nan() || (0.0..=1.0).contains(&overlap)) {
            return Err(format!("overlap {overlap} is not within [0, 1]"));
        }
        let fit = match (record.status, record.m_world) {
            (Some(status), Some(rows)) => Some(fit_of(record, status, &rows)?),
            (None, None) => None,
            _ => return Err("a status without a matrix, or a matrix without a status".into()),
        };
        Ok(match fit {
            Some(fit) if fit.usable() => PairOutcome::Registered { pair, overlap, fit },
            _ if overlap < min_overlap => PairOutcome::BelowOverlap { pair, overlap },
            Some(fit) => PairOutcome::Failed {
                pair,
                overlap,
                failure: Failure::Ended(fit),
            },
            None => PairOutcome::Failed {
                pair,
                overlap,
                failure: Failure::Error(
                    record
                        .note
                        .clone()
                        .unwrap_or_else(|| "not registered".into()),
                ),
            },
        })
    }
}

/// The ICP result of a record with a status and a matrix, checked.
fn fit_of(record: &EdgeRecord, status: IcpStatus, rows: &[[f64; 4]; 4]) -> Result<IcpFit, String> {
    let m = Matrix4::from_fn(|r, c| rows[r][c]);
    if m.iter().any(|v| !v.is_finite()) {
        return Err("m_world holds a number that is not finite".into());
    }
    let rigid = rigidity(&m);
    if !rigid.is_rigid(RIGIDITY_TOLERANCE)
        || m.row(3) != nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0)
    {
        return Err(format!(
            "m_world is not a rigid transform (|R^T R - I| = {:.3e}, det {:.6}, last row {:?})",
            rigid.orthonormality_error, rigid.det, rows[3]
        ));
    }
    let sigma_ok = record.sigma.is_none_or(|s| {
        s.rot_deg
            .iter()
            .chain(&s.trans_m)
            .all(|v| v.is_finite() && *v >= 0.0)
    });
    if !sigma_ok {
        return Err("sigma holds a negative or non-finite number".into());
    }
    let search_ok = record.search.is_none_or(|s| {
        [s.cut_m, s.reached_m, s.offset_m]
            .iter()
            .all(|v| v.is_finite() && *v >= 0.0)
    });
    if !search_ok {
        return Err("search holds a negative or non-finite number".into());
    }
    if record.information.as_ref().is_some_and(|i| !i.is_valid()) {
        return Err("information holds a non-finite number or is not a covariance".into());
    }
    let fit = IcpFit {
        status,
        t_ref_moving_world: m,
        rmse_m: record.rmse_m,
        inliers: record.inliers,
        iterations: record.iterations,
        sigma: record.sigma,
        information: record.information.clone().map(Box::new),
        search: record.search.map(Box::new),
    };
    // An edge's RMSE feeds the weights; a failed fit's is only reported.
    if fit.usable() && !(fit.rmse_m.is_finite() && fit.rmse_m >= 0.0) {
        return Err(format!("rmse_m {} is not a finite number >= 0", fit.rmse_m));
    }
    Ok(fit)
}
