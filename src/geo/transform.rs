//! The affine geotransform (GDAL order) that places a raster's pixels in its CRS.
//!
//! Pixel convention: pixel (col, row) covers [col, col+1) x [row, row+1) in pixel
//! space; its centre is at (col + 0.5, row + 0.5). `pixel_to_world(0, 0)` is the
//! outer top-left corner of the raster (GDAL's pixel-is-area convention).

use serde::{Deserialize, Serialize};

use super::Bounds;

/// GDAL-order affine transform: x = gt[0] + col*gt[1] + row*gt[2],
/// y = gt[3] + col*gt[4] + row*gt[5].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GeoTransform(pub [f64; 6]);

impl GeoTransform {
    pub fn north_up(origin_x: f64, origin_y: f64, gsd_x_m: f64, gsd_y_m: f64) -> Self {
        GeoTransform([origin_x, gsd_x_m, 0.0, origin_y, 0.0, -gsd_y_m])
    }

    /// True when there is no rotation or shear term (the only kind we accept).
    pub fn is_north_up(&self) -> bool {
        self.0[2] == 0.0 && self.0[4] == 0.0 && self.0[1] > 0.0 && self.0[5] < 0.0
    }

    /// Pixel width in CRS units (metres for a projected CRS).
    pub fn gsd_x(&self) -> f64 {
        self.0[1]
    }

    /// Pixel height in CRS units, positive.
    pub fn gsd_y(&self) -> f64 {
        -self.0[5]
    }

    /// The coarser of the pixel's width and height (CRS units).
    pub fn pixel_m(&self) -> f64 {
        self.gsd_x().max(self.gsd_y())
    }

    /// World coordinates of a continuous pixel position (0,0 = outer top-left corner).
    pub fn pixel_to_world(&self, col: f64, row: f64) -> (f64, f64) {
        let g = &self.0;
        (
            g[0] + col * g[1] + row * g[2],
            g[3] + col * g[4] + row * g[5],
        )
    }

    /// Continuous pixel position of a world point (north-up transforms only).
    pub fn world_to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        let g = &self.0;
        ((x - g[0]) / g[1], (y - g[3]) / g[5])
    }

    /// The transform of the 2^level overview of this raster.
    pub fn overview(&self, level: u32) -> GeoTransform {
        let f = (1u64 << level) as f64;
        let g = &self.0;
        GeoTransform([g[0], g[1] * f, g[2] * f, g[3], g[4] * f, g[5] * f])
    }

    /// Axis-aligned extent of a width x height raster.
    pub fn extent(&self, width: u64, height: u64) -> Bounds {
        let (x0, y0) = self.pixel_to_world(0.0, 0.0);
        let (x1, y1) = self.pixel_to_world(width as f64, height as f64);
        Bounds::from_corners((x0, y0), (x1, y1))
    }

    /// [`extent`](Self::extent) as `[min_x, min_y, max_x, max_y]`, for callers
    /// that still keep boxes as arrays.
    pub fn bounds(&self, width: u64, height: u64) -> [f64; 4] {
        self.extent(width, height).to_array()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixel_world_round_trip() {
        let gt = GeoTransform::north_up(500_000.0, 4_000_000.0, 0.5, 0.5);
        let (x, y) = gt.pixel_to_world(10.5, 20.5);
        assert_eq!((x, y), (500_005.25, 3_999_989.75));
        let (c, r) = gt.world_to_pixel(x, y);
        assert!((c - 10.5).abs() < 1e-9 && (r - 20.5).abs() < 1e-9);
        assert_eq!(
            gt.bounds(100, 200),
            [500_000.0, 3_999_900.0, 500_050.0, 4_000_000.0]
        );
        assert_eq!(gt.extent(100, 200).width(), 50.0);
        assert_eq!(gt.overview(1).gsd_x(), 1.0);
    }
}
