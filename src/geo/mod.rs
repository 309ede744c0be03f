//! Geometry shared by every stage: where a raster sits ([`GeoTransform`], [`Crs`]),
//! axis-aligned boxes ([`Bounds`]), and rigid transforms ([`rigid`]: one place for
//! their parts, inverse, rotation angle, the local <-> world frame change and the
//! row-major 4x4 form written to files, [`rigid::rows`]).
//!
//! Transforms are named by their frames: `t_ref_moving` maps points of the moving
//! DSM into the reference's frame, p_ref = t_ref_moving p_moving.

pub mod bounds;
pub mod crs;
pub mod proj;
pub mod rigid;
pub mod tm;
pub mod transform;

pub use bounds::Bounds;
pub use crs::Crs;
pub use transform::GeoTransform;
