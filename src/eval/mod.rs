//! `eval`: how well the DSMs agree, before and after the poses.
//!
//! - Pairs ([`pairs`]): every pair with overlapping footprints (plan's R-tree),
//!   dh = z_j - z_i of the corrected surfaces at DSM i's pixel centres.
//! - Reference ([`reference`]): the fused surface (median of corrected heights)
//!   against a GeoTIFF DSM or a LAS/LAZ point cloud, dh = fused - reference.
//!
//! Figures per set ([`stats`]): the paper's rmse_tau with N = inliers
//! (|dh| < tau), the inlier fraction, mean, median, NMAD, 16/84 percentiles;
//! and the mean over pairs (the paper's Table 1 figure). Heights are read at
//! level 0 through the chunk cache, with the same corrected-height function as
//! `fuse` ([`crate::fuse::corrected`]).

pub mod las;
pub mod pairs;
pub mod reference;
pub mod report;
pub mod stats;
pub mod surfaces;

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::cache::ChunkCache;
use crate::fuse::{PoseSet, PoseXf};
use crate::geotiff::reader::GeoTiffError;
use crate::store::{Store, StoreError};
pub use pairs::PairEval;
pub use reference::{DiffSample, ReferenceEval};
pub use stats::{diff_stats, mean_over, DiffStats, Thinned};
use surfaces::Placement;

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Bad input (reference in another CRS, not overlapping, bad options): exit 2.
    #[error("{0}")]
    Input(String),
    /// The store could not be read (damaged metadata, missing or bad chunks).
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The reference GeoTIFF could not be read.
    #[error(transparent)]
    Reference(#[from] GeoTiffError),
    /// The reference raster could not be read (a GeoTIFF, VRT or HGT tile).
    #[error(transparent)]
    Source(#[from] crate::store::source::SourceError),
    #[error("thread pool: {0}")]
    ThreadPool(#[from] rayon::ThreadPoolBuildError),
}

impl EvalError {
    /// The user's input (options, reference, the store) is at fault: exit code 2.
    pub fn is_bad_input(&self) -> bool {
        match self {
            EvalError::Input(_) => true,
            EvalError::Store(e) => e.is_bad_input(),
            EvalError::Reference(e) => e.is_bad_input(),
            EvalError::Source(e) => e.bad_input,
            EvalError::ThreadPool(_) => false,
        }
    }
}

/// Evaluation settings.
#[derive(Clone, Debug)]
pub struct EvalConfig {
    /// Inlier threshold of rmse_tau (paper: 10 m).
    pub tau_m: f64,
    /// Most sample locations per pair, and for the reference.
    pub max_samples: u64,
    pub threads: usize,
    /// Use every lidar return (default: first returns only).
    pub all_returns: bool,
    /// Pairs evaluated so far, of how many: read by the caller's progress report.
    pub progress: PairCounter,
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig {
            tau_m: 10.0,
            max_samples: 1_000_000,
            threads: 1,
            all_returns: false,
            progress: PairCounter::default(),
        }
    }
}

/// Pairs done and planned, shared between the workers and a progress reader.
#[derive(Clone, Debug, Default)]
pub struct PairCounter {
    done: std::sync::Arc<std::sync::atomic::AtomicU64>,
    total: std::sync::Arc<std::sync::atomic::AtomicU64>,
}

impl PairCounter {
    /// (pairs done, pairs planned).
    pub fn get(&self) -> (u64, u64) {
        use std::sync::atomic::Ordering::Relaxed;
        (self.done.load(Relaxed), self.total.load(Relaxed))
    }

    fn plan(&self, total: usize) {
        self.total
            .store(total as u64, std::sync::atomic::Ordering::Relaxed);
    }

    fn tick(&self) {
        self.done.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    }
}

/// The whole report (printed as a table or as JSON).
#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    pub store: PathBuf,
    /// The poses file, or "none (identity)".
    pub poses: String,
    pub tau_m: f64,
    /// What N divides in rmse_tau.
    pub rmse_tau_n: String,
    pub pairs: Vec<PairEval>,
    /// Mean over pairs with inliers, identity poses.
    pub mean_before: Option<DiffStats>,
    /// Mean over pairs with inliers, with the poses.
    pub mean_after: Option<DiffStats>,
    pub reference: Option<ReferenceEval>,
    pub seconds: f64,
}

/// Samples kept for the pictures.
pub struct PlotData {
    /// Thinned inlier dh over all pairs, before and after.
    pub pairs_before: Vec<f32>,
    pub pairs_after: Vec<f32>,
    /// Every reference sample (location, dh before and after).
    pub reference: Vec<DiffSample>,
}

/// Evaluate the collection: every pair, and the reference when given.
pub fn evaluate(
    store: &Store,
    cache: &ChunkCache,
    poses: Option<&PoseSet>,
    reference_path: Option<&Path>,
    config: &EvalConfig,
) -> Result<(EvalReport, PlotData), EvalError> {
    if !(config.tau_m.is_finite() && config.tau_m > 0.0) {
        return Err(EvalError::Input(format!(
            "--tau {} must be a positive number of metres",
            config.tau_m
        )));
    }
    let started = std::time::Instant::now();
    let identity = vec![PoseXf::identity(); store.dsms().len()];
    let before = Placement::new(store, &identity);
    let after = poses.map(|p| Placement::new(store, &p.poses));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(config.threads.max(1))
        .build()?;
    // the reference first: its input errors come before the long pair work
    let reference = match reference_path {
        Some(path) => Some(reference::eval_reference(
            store,
            cache,
            &before,
            after.as_ref(),
            config,
            path,
            &pool,
        )?),
        None => None,
    };
    let outcome = pairs::eval_pairs(store, cache, &before, after.as_ref(), config, &pool)?;
    let befores: Vec<DiffStats> = outcome.pairs.iter().map(|p| p.before).collect();
    let afters: Vec<DiffStats> = outcome.pairs.iter().filter_map(|p| p.after).collect();
    let report = EvalReport {
        store: store.root().to_path_buf(),
        poses: poses.map_or_else(|| "none (identity)".to_string(), |p| p.label()),
        tau_m: config.tau_m,
        rmse_tau_n: "inliers (|dh| < tau)".to_string(),
        mean_before: mean_over(&befores),
        mean_after: mean_over(&afters),
        pairs: outcome.pairs,
        reference: reference.as_ref().map(|r| r.eval.clone()),
        seconds: started.elapsed().as_secs_f64(),
    };
    tracing::info!(
        pairs = report.pairs.len(),
        seconds = report.seconds,
        "collection evaluated"
    );
    let plots = PlotData {
        pairs_before: outcome.plot_before.values,
        pairs_after: outcome.plot_after.values,
        reference: reference.map(|r| r.samples).unwrap_or_default(),
    };
    Ok((report, plots))
}

#[cfg(test)]
mod tests;
