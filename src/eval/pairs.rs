//! Pairwise agreement: for every pair of DSMs whose footprints overlap, the
//! height differences dh = z_j - z_i of their corrected surfaces at the same
//! horizontal locations, before (identity) and after the poses.
//!
//! The samples are the level-0 pixels of DSM i (the lower store index), with a
//! stride of 2^k pixels, the smallest that keeps at most `max_samples` in the
//! overlap box. Each pixel is moved by M_i to (X, Y, z_i) and compared with the
//! corrected surface of DSM j at (X, Y), so only DSM j is interpolated (an
//! interpolated DSM i would smear its outliers over neighbouring samples and
//! make the figures depend on where the lattice falls).

use rayon::prelude::*;
use serde::Serialize;

use super::stats::{diff_stats, DiffStats, Thinned};
use super::surfaces::{Placement, Surfaces};
use super::{EvalConfig, EvalError};
use crate::cache::ChunkCache;
use crate::geo::Bounds;
use crate::plan::{candidate_pairs, Footprint};
use crate::store::Store;

/// Samples per pair and set kept for the histograms.
const PLOT_SAMPLES_PER_PAIR: usize = 20_000;

/// One overlapping pair.
#[derive(Clone, Debug, Serialize)]
pub struct PairEval {
    pub i: String,
    pub j: String,
    /// Lattice stride in level-0 pixels of DSM i.
    pub stride_px: u64,
    /// Identity poses.
    pub before: DiffStats,
    /// With the poses (None when evaluating the raw collection).
    pub after: Option<DiffStats>,
}

/// Every pair, and thinned inlier differences for the histograms.
pub struct PairsOutcome {
    pub pairs: Vec<PairEval>,
    pub plot_before: Thinned,
    pub plot_after: Thinned,
}

/// Evaluate every overlapping pair (pairs run in parallel on `pool`).
pub fn eval_pairs(
    store: &Store,
    cache: &ChunkCache,
    before: &Placement,
    after: Option<&Placement>,
    config: &EvalConfig,
    pool: &rayon::ThreadPool,
) -> Result<PairsOutcome, EvalError> {
    // a pair counts when it overlaps before or after correction
    let footprints: Vec<Footprint> = before
        .placed
        .iter()
        .enumerate()
        .map(|(k, p)| Footprint {
            index: k,
            bounds: match after {
                Some(a) => {
                    Bounds::from(p.corrected_bounds).union(&a.placed[k].corrected_bounds.into())
                }
                None => p.corrected_bounds.into(),
            },
        })
        .collect();
    let pairs = candidate_pairs(&footprints);
    config.progress.plan(pairs.len());
    let mut plot_before = Thinned::new(1_000_000);
    let mut plot_after = Thinned::new(1_000_000);
    let mut out = Vec::with_capacity(pairs.len());
    // Batches in pair order: the plot samples of a batch are merged before the
    // next starts, so memory is one batch's (not every pair's) samples, and
    // the thinned plot values are the same as over all pairs at once.
    let batch = PAIRS_PER_THREAD_BATCH * pool.current_num_threads().max(1);
    for chunk in pairs.chunks(batch) {
        let results = pool.install(|| {
            chunk
                .par_iter()
                .map(|&(i, j)| {
                    let region = footprints[i].bounds.clip(&footprints[j].bounds);
                    let result = eval_pair(store, cache, before, after, config, i, j, region);
                    config.progress.tick();
                    result
                })
                .collect::<Result<Vec<_>, _>>()
        })?;
        for (pair, b, a) in results {
            plot_before.extend(&b);
            plot_after.extend(&a);
            out.push(pair);
        }
    }
    Ok(PairsOutcome {
        pairs: out,
        plot_before,
        plot_after,
    })
}

/// Pairs evaluated per thread between merges of their plot samples (each pair
/// holds up to 2 x [`PLOT_SAMPLES_PER_PAIR`] values until merged).
const PAIRS_PER_THREAD_BATCH: usize = 64;

#[allow(clippy::too_many_arguments)]
fn eval_pair(
    store: &Store,
    cache: &ChunkCache,
    before: &Placement,
    after: Option<&Placement>,
    config: &EvalConfig,
    i: usize,
    j: usize,
    region: Bounds,
) -> Result<(PairEval, Vec<f32>, Vec<f32>), EvalError> {
    let meta = &store.dsms()[i];
    let gt = meta.geotransform;
    // level-0 pixel range of DSM i inside the region
    let (c0, r0) = gt.world_to_pixel(region.min_x, region.max_y);
    let (c1, r1) = gt.world_to_pixel(region.max_x, region.min_y);
    let clamp = |v: f64, n: u64| v.max(0.0).min(n as f64);
    let (c0, c1) = (
        clamp(c0.floor(), meta.width) as u64,
        clamp(c1.ceil(), meta.width) as u64,
    );
    let (r0, r1) = (
        clamp(r0.floor(), meta.height) as u64,
        clamp(r1.ceil(), meta.height) as u64,
    );
    let (w, h) = (c1.saturating_sub(c0), r1.saturating_sub(r0));
    let mut stride = 1u64;
    while w.div_ceil(stride) * h.div_ceil(stride) > config.max_samples.max(1) {
        stride *= 2;
    }
    let mut raw = Surfaces::new(store, cache, before);
    let mut corrected = after.map(|a| Surfaces::new(store, cache, a));
    let mut dh_before = Vec::new();
    let mut dh_after = Vec::new();
    for r in (r0..r1).step_by(stride as usize) {
        for c in (c0..c1).step_by(stride as usize) {
            let (x, y) = gt.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            if let Some(d) = pixel_to_surface(&mut raw, i, j, x, y)? {
                dh_before.push(d);
            }
            if let Some(s) = corrected.as_mut() {
                if let Some(d) = pixel_to_surface(s, i, j, x, y)? {
                    dh_after.push(d);
                }
            }
        }
    }
    let errors = raw
        .take_error()
        .or_else(|| corrected.as_mut().and_then(|s| s.take_error()));
    if let Some(e) = errors {
        return Err(e.into());
    }
    let before_stats = diff_stats(&mut dh_before, config.tau_m);
    let after_stats = corrected
        .is_some()
        .then(|| diff_stats(&mut dh_after, config.tau_m));
    let thin = |v: &[f32]| {
        let mut t = Thinned::new(PLOT_SAMPLES_PER_PAIR);
        t.extend(v); // diff_stats left the inliers, sorted: thinning keeps the spread
        t.values
    };
    let pair = PairEval {
        i: meta.id.clone(),
        j: store.dsms()[j].id.clone(),
        stride_px: stride,
        before: before_stats,
        after: after_stats,
    };
    Ok((pair, thin(&dh_before), thin(&dh_after)))
}

/// z_j(X, Y) - Z for the pixel of DSM i at (x, y) moved to (X, Y, Z).
fn pixel_to_surface(
    s: &mut Surfaces,
    i: usize,
    j: usize,
    x: f64,
    y: f64,
) -> Result<Option<f32>, EvalError> {
    let Some([px, py, pz]) = s.moved_point(i, x, y)? else {
        return Ok(None);
    };
    let zj = s.height(j, px, py)?;
    Ok((!zj.is_nan()).then_some((zj - pz) as f32))
}
