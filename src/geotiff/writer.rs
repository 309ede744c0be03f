//! Tiled Cloud-Optimized GeoTIFF writer (in progress).
