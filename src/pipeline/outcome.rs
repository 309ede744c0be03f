//! What a worker sends for one pair: [`PairOutcome`], keyed by DSM indices.
//! Ids appear only where outcomes are journaled (crate::journal).

use nalgebra::Matrix4;

use crate::fit::FitSigma;
use crate::icp::IcpStatus;

/// A candidate pair by DSM index (reference < moving).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PairTask {
    pub reference: usize,
    pub moving: usize,
}

/// What DSM-ICP returned for a pair (usable or not).
#[derive(Clone, Debug, PartialEq)]
pub struct IcpFit {
    pub status: IcpStatus,
    /// T_ref_moving in world coordinates: p_reference = T p_moving.
    pub t_ref_moving_world: Matrix4<f64>,
    /// RMSE of the final iteration, metres.
    pub rmse_m: f64,
    pub inliers: usize,
    pub iterations: usize,
    /// One-sigma standard errors of the last fit (local frame at the overlap);
    /// None for pairs journaled before they were reported.
    pub sigma: Option<FitSigma>,
}

impl IcpFit {
    /// Converged, or still improving at the last iteration: the graph can use it.
    pub fn usable(&self) -> bool {
        matches!(self.status, IcpStatus::Converged | IcpStatus::MaxIterations)
    }
}

/// Why a pair that should have given an edge did not.
#[derive(Clone, Debug, PartialEq)]
pub enum Failure {
    /// Reading or scoring failed, or ICP returned an error: the message.
    Error(String),
    /// ICP ran and ended diverged, degenerate or with too few inliers.
    Ended(IcpFit),
}

/// The outcome of one pair.
#[derive(Clone, Debug, PartialEq)]
pub enum PairOutcome {
    /// Registered with a usable fit: an edge of the graph.
    Registered {
        pair: PairTask,
        /// s_ij measured on the overviews.
        overlap: f64,
        fit: IcpFit,
    },
    /// Scored below `--min-overlap`: no edge, by design.
    BelowOverlap { pair: PairTask, overlap: f64 },
    /// Should have given an edge and did not.
    Failed {
        pair: PairTask,
        /// NaN when the scoring itself failed.
        overlap: f64,
        failure: Failure,
    },
}

impl PairOutcome {
    pub fn pair(&self) -> PairTask {
        match self {
            PairOutcome::Registered { pair, .. }
            | PairOutcome::BelowOverlap { pair, .. }
            | PairOutcome::Failed { pair, .. } => *pair,
        }
    }

    pub fn overlap(&self) -> f64 {
        match self {
            PairOutcome::Registered { overlap, .. }
            | PairOutcome::BelowOverlap { overlap, .. }
            | PairOutcome::Failed { overlap, .. } => *overlap,
        }
    }

    /// The fit the graph can use, if any.
    pub fn edge_fit(&self) -> Option<&IcpFit> {
        match self {
            PairOutcome::Registered { fit, .. } => Some(fit),
            _ => None,
        }
    }

    /// Why the pair gave no edge; None for a registered pair.
    pub fn why_no_edge(&self) -> Option<String> {
        match self {
            PairOutcome::Registered { .. } => None,
            PairOutcome::BelowOverlap { overlap, .. } => Some(below_overlap_note(*overlap)),
            PairOutcome::Failed { failure, .. } => Some(match failure {
                Failure::Error(message) => message.clone(),
                Failure::Ended(fit) => format!("ICP ended {:?}", fit.status),
            }),
        }
    }
}

/// The note of a pair scored below `--min-overlap` (as journaled).
pub fn below_overlap_note(overlap: f64) -> String {
    format!("overlap {overlap:.3} below --min-overlap")
}
