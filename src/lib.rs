//! dsmstream: out-of-core registration of large collections of overlapping
//! Digital Surface Models (Xu & Qin, ISPRS Annals X-1-2024).
//!
//! Data flow (one module per stage):
//! ```text
//!  GeoTIFFs ──geotiff──► ingest ──► store (Zarr v3: one multiscale array per DSM + catalog)
//!                                     │
//!                         cache (LRU chunk cache, byte budget, shared by all workers)
//!                                     │ grid (pixel access through the cache)
//!  plan (R-tree) ──► pipeline: icp workers (nn + fit) ──► journal ──► averaging ──► poses
//!                                     │
//!  poses ──► fuse (COG mosaic)      eval (rmse_tau report, plots)
//! ```
//! Memory is the cache budget plus a small constant: nothing loads a whole DSM.

pub mod align;
pub mod atomic;
pub mod averaging;
pub mod cache;
pub mod coarse;
pub mod error;
pub mod eval;
pub mod fit;
pub mod fuse;
pub mod geotiff;
pub mod graph;
pub mod grid;
pub mod icp;
pub mod journal;
pub mod nn;
pub mod pipeline;
pub mod plan;
pub mod plots;
pub mod poses;
pub mod raster;
pub mod rng;
pub mod store;
pub mod synth;

pub use error::InputError;
