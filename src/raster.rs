//! The old home of [`GeoTransform`] and [`Crs`], now in [`crate::geo`]; kept as a
//! re-export so callers outside the geo redesign keep compiling (move imports to
//! `crate::geo` when touching them).

pub use crate::geo::{Crs, GeoTransform};
