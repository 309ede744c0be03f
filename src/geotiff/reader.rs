//! Streaming GeoTIFF reader (in progress).
