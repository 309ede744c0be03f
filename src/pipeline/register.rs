//! One pair through the worker: score the overlap on the overviews and, if it
//! is large enough, register it with DSM-ICP through the shared chunk cache.
//! Both DSMs are seen through [`crate::view`] (moved by their initial shifts,
//! masked for the registration, not for the score); the result is returned
//! in the DSMs' own coordinates.

use super::outcome::{Failure, IcpFit, PairInformation, PairOutcome, PairTask};
use super::PipelineConfig;
use crate::cache::ChunkCache;
use crate::grid::{Grid, GridError, Pyramid};
use crate::icp::{register, IcpError};
use crate::plan::{overlap_score, scoring_level};
use crate::store::{DsmMeta, Store, StorePyramid};
use crate::view::to_raw_frames;

/// Scores one pair on the overviews and, if it overlaps enough, registers it.
#[tracing::instrument(level = "debug", skip_all, fields(reference = pair.reference, moving = pair.moving))]
pub fn register_pair(
    store: &Store,
    cache: &ChunkCache,
    pair: PairTask,
    config: &PipelineConfig,
) -> PairOutcome {
    let dsms = store.dsms();
    let (ri, mi) = (&dsms[pair.reference], &dsms[pair.moving]);
    let inputs = &config.inputs;
    let store_dsm = |k| StorePyramid::new(store, cache, k);
    let reference = inputs.view(store_dsm(pair.reference), pair.reference);
    let moving = inputs.view(store_dsm(pair.moving), pair.moving);
    let scored = score(
        &inputs.moved(store_dsm(pair.reference), pair.reference),
        &inputs.moved(store_dsm(pair.moving), pair.moving),
        ri,
        mi,
    );
    let overlap = match scored {
        Ok(s) => s,
        Err(e) => {
            tracing::warn!(reference = %ri.id, moving = %mi.id, error = %e, "pair failed");
            return PairOutcome::Failed {
                pair,
                overlap: f64::NAN,
                failure: Failure::Error(format!("overlap scoring failed: {e}")),
            };
        }
    };
    if overlap < config.min_overlap {
        return PairOutcome::BelowOverlap { pair, overlap };
    }
    let registered = register(&reference, &moving, &config.icp)
        .map(|r| to_raw_frames(r, &reference.shift_m, &moving.shift_m));
    match registered {
        Ok(r) => {
            tracing::debug!(reference = %ri.id, moving = %mi.id, rmse_m = r.rmse_m, status = ?r.status, "pair aligned");
            let fit = IcpFit {
                status: r.status,
                t_ref_moving_world: r.t_ref_moving.to_homogeneous(),
                rmse_m: r.rmse_m,
                inliers: r.inliers,
                iterations: r.iterations,
                sigma: Some(r.sigma),
                information: r
                    .information
                    .as_ref()
                    .map(|i| Box::new(PairInformation::from_fit(i))),
                search: r.search.map(Box::new),
            };
            if fit.usable() {
                PairOutcome::Registered { pair, overlap, fit }
            } else {
                let failure = Failure::Ended(fit);
                PairOutcome::Failed {
                    pair,
                    overlap,
                    failure,
                }
            }
        }
        Err(e) => {
            tracing::warn!(reference = %ri.id, moving = %mi.id, error = %e, "pair failed");
            let masked = matches!(e, IcpError::EmptyOverlap) && inputs.mask.is_some();
            let within = if masked {
                " on the mask's stable cells"
            } else {
                ""
            };
            PairOutcome::Failed {
                pair,
                overlap,
                failure: Failure::Error(format!("{e}{within}")),
            }
        }
    }
}

/// s_ij on a common level: the coarser of the two DSMs' scoring levels.
fn score<P: Pyramid>(
    reference: &P,
    moving: &P,
    ri: &DsmMeta,
    mi: &DsmMeta,
) -> Result<f64, GridError> {
    let sizes = |m: &DsmMeta| {
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
