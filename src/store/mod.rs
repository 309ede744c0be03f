//! The Zarr v3 collection store (in progress).
