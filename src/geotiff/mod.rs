//! GeoTIFF in pure Rust: a streaming reader (strips or tiles, one block row at
//! a time) and a tiled, Cloud-Optimized writer. No GDAL dependency.

pub mod epsg_units;
pub mod equivalent;
pub mod gdal_metadata;
pub mod geokeys;
pub mod reader;
pub mod sidecar;
pub mod wkt;
pub mod writer;
