//! GeoTIFF reading and writing in pure Rust (in progress).
