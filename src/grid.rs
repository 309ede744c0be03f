//! Pixel access to one DSM level, the seam between storage and the algorithms.
//!
//! The ICP, the nearest-neighbour search, fuse and eval read heights only
//! through [`Grid`]; the store provides an implementation that goes through the
//! shared chunk cache, and [`MemGrid`] holds a small raster in memory for tests
//! and tools. No-data is NaN, and so is any pixel outside the raster.

use crate::raster::GeoTransform;

/// Read access to one level of one DSM. `&mut self` lets an implementation keep
/// a few chunks pinned between calls (each worker owns its own view).
pub trait Grid {
    fn width(&self) -> i64;
    fn height(&self) -> i64;
    /// Geotransform of this level (pixel size doubles at each overview).
    fn geotransform(&self) -> GeoTransform;
    /// Height at pixel (col, row); NaN for no-data or outside the raster.
    fn get(&mut self, col: i64, row: i64) -> f32;
    /// The first I/O error met since the last call (reads that failed returned NaN).
    fn take_error(&mut self) -> Option<String> {
        None
    }
}

/// A raster held in memory, row-major, NaN for no-data.
#[derive(Clone, Debug)]
pub struct MemGrid {
    pub width: i64,
    pub height: i64,
    pub geotransform: GeoTransform,
    pub data: Vec<f32>,
}

impl MemGrid {
    pub fn new(width: i64, height: i64, geotransform: GeoTransform, data: Vec<f32>) -> Self {
        assert_eq!(data.len() as i64, width * height, "MemGrid data size");
        MemGrid {
            width,
            height,
            geotransform,
            data,
        }
    }

    /// Build a grid by evaluating `f(col, row)` at every pixel.
    pub fn from_fn(
        width: i64,
        height: i64,
        geotransform: GeoTransform,
        mut f: impl FnMut(i64, i64) -> f32,
    ) -> Self {
        let mut data = Vec::with_capacity((width * height) as usize);
        for row in 0..height {
            for col in 0..width {
                data.push(f(col, row));
            }
        }
        MemGrid::new(width, height, geotransform, data)
    }
}

impl Grid for MemGrid {
    fn width(&self) -> i64 {
        self.width
    }
    fn height(&self) -> i64 {
        self.height
    }
    fn geotransform(&self) -> GeoTransform {
        self.geotransform
    }
    #[inline]
    fn get(&mut self, col: i64, row: i64) -> f32 {
        if col < 0 || row < 0 || col >= self.width || row >= self.height {
            return f32::NAN;
        }
        self.data[(row * self.width + col) as usize]
    }
}

impl<G: Grid + ?Sized> Grid for &mut G {
    fn width(&self) -> i64 {
        (**self).width()
    }
    fn height(&self) -> i64 {
        (**self).height()
    }
    fn geotransform(&self) -> GeoTransform {
        (**self).geotransform()
    }
    #[inline]
    fn get(&mut self, col: i64, row: i64) -> f32 {
        (**self).get(col, row)
    }
    fn take_error(&mut self) -> Option<String> {
        (**self).take_error()
    }
}
