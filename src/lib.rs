//! dsmstream: out-of-core registration of large collections of overlapping
//! Digital Surface Models (Xu & Qin, ISPRS Annals X-1-2024). The method and the
//! file contracts are in docs/design.md (cited as DESIGN.md in the code); the
//! module picture in docs/architecture.md.
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
//!
//! The modules:
//! - [`geotiff`]: GeoTIFF in pure Rust, a streaming reader (strips or tiles;
//!   georeferencing in side files too: `.aux.xml`, world files, `.prj` as WKT)
//!   and a tiled Cloud-Optimized writer; [`xml`] the XML of GDAL's side
//!   files (VRT, `.aux.xml`); [`geo`] the geometry every stage
//!   shares (geotransform in GDAL order, CRS from geokeys, boxes, rigid transforms).
//! - [`store`]: the collection store, one Zarr v3 multiscale group per DSM with
//!   its catalog entry; `ingest` converts GeoTIFFs into it once.
//! - [`cache`]: decoded chunks shared by every worker under one byte budget;
//!   [`grid`] reads pixel windows of one DSM level through it.
//! - [`plan`]: which DSMs overlap, their overlap scores, and the order in which
//!   pairs are registered so the cache stays warm.
//! - [`icp`], [`nn`], [`fit`]: pairwise DSM-ICP, coarse to fine: the exact grid
//!   nearest-neighbour search of the paper, and the rigid fits
//!   (point-to-surface, point-to-plane, point-to-point) with standard errors.
//! - [`mask`], [`initial`], [`view`]: what a user brings to a registration
//!   (stable-terrain masks, initial poses) and the view of a DSM they give.
//! - [`pipeline`]: planner → N ICP workers → edge sink over bounded channels;
//!   [`journal`] appends every finished pair to disk so `--resume` can skip it.
//! - [`graph`]: the scene graph (edges, weights, components, spanning tree);
//!   [`averaging`] solves one pose per DSM from it (rotations, then
//!   translations, with outlier rounds).
//! - [`align`]: the whole `align` run as one library call, ending in
//!   [`poses`], the poses.json file and its rigid-transform helpers.
//! - [`fuse`]: the registered mosaic (or each corrected DSM) written as COG,
//!   one output tile at a time.
//! - [`eval`]: rmse_tau and robust statistics over every overlapping pair and
//!   against a reference DSM or LAS/LAZ cloud; [`plots`] draws its PNGs.
//! - [`synth`]: DSM collections with a known answer (generated city tiles or
//!   cuts of a real DSM), used by the tests, the demo and `dsmgen`.
//! - [`atomic`]: files written under a temporary name and renamed when
//!   complete; [`rng`]: seeded pseudo-random numbers; [`select`]: the k-th
//!   smallest of many values; [`error`]: the [`InputError`] the binary maps
//!   to exit code 2.

pub mod align;
pub mod atomic;
pub mod averaging;
pub mod cache;
pub mod coarse;
pub mod error;
pub mod eval;
pub mod fit;
pub mod fuse;
pub mod geo;
pub mod geotiff;
pub mod graph;
pub mod grid;
pub mod icp;
pub mod initial;
pub mod journal;
pub mod mask;
pub mod nn;
pub mod pipeline;
pub mod plan;
pub mod plots;
pub mod poses;
pub mod rng;
pub mod select;
pub mod store;
pub mod synth;
pub mod view;
pub mod xml;

pub use error::InputError;
