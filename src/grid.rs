//! Pixel access to one DSM level, the seam between storage and the algorithms.
//!
//! The ICP, the nearest-neighbour search, fuse and eval read heights only
//! through [`Grid`]; the store provides an implementation that goes through the
//! shared chunk cache, and [`MemGrid`] holds a small raster in memory for tests
//! and tools. No-data is NaN, and so is any pixel outside the raster.
//! Failures are a [`GridError`]: a level that cannot be opened, or a chunk
//! that could not be read (its pixels read as NaN, the error is kept for
//! [`Grid::take_error`]).

use crate::geo::GeoTransform;
use crate::store::{ChunkReadError, StoreError};

/// Why a level of a DSM could not be opened or some of its pixels not read.
/// The messages are those of the sources: they name the file.
#[derive(Debug, thiserror::Error)]
pub enum GridError {
    /// A chunk is missing or does not decode; its pixels read as NaN.
    #[error(transparent)]
    Chunk(#[from] ChunkReadError),
    /// The store could not open the level's array.
    #[error(transparent)]
    Level(#[from] StoreError),
    /// An in-memory pyramid has no level `level` (it has `levels`).
    #[error("no level {level} (the pyramid has {levels})")]
    NoLevel { level: usize, levels: usize },
}

impl GridError {
    /// A damaged store (a chunk or a level that cannot be read) is bad input;
    /// asking an in-memory pyramid for a level it lacks is a bug.
    pub fn is_bad_input(&self) -> bool {
        match self {
            GridError::Chunk(_) => true,
            GridError::Level(e) => e.is_bad_input(),
            GridError::NoLevel { .. } => false,
        }
    }
}

/// Read access to one level of one DSM. `&mut self` lets an implementation keep
/// a few chunks pinned between calls (each worker owns its own view).
pub trait Grid {
    fn width(&self) -> i64;
    fn height(&self) -> i64;
    /// Geotransform of this level (pixel size doubles at each overview).
    fn geotransform(&self) -> GeoTransform;
    /// Height at pixel (col, row); NaN for no-data or outside the raster.
    fn get(&mut self, col: i64, row: i64) -> f32;
    /// The first read error met since the last call (reads that failed returned NaN).
    fn take_error(&mut self) -> Option<GridError> {
        None
    }
    /// The `w x h` window with top-left pixel (col0, row0), row-major; NaN
    /// outside the raster (as `get` reads it, pixel by pixel unless an
    /// implementation copies whole rows).
    fn read_window(&mut self, col0: i64, row0: i64, w: usize, h: usize) -> Vec<f32> {
        let mut out = Vec::with_capacity(w * h);
        for row in row0..row0 + h as i64 {
            for col in col0..col0 + w as i64 {
                out.push(self.get(col, row));
            }
        }
        out
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
    fn take_error(&mut self) -> Option<GridError> {
        (**self).take_error()
    }
    fn read_window(&mut self, col0: i64, row0: i64, w: usize, h: usize) -> Vec<f32> {
        (**self).read_window(col0, row0, w, h)
    }
}

/// All levels of one DSM (level 0 full resolution, each next level 2x coarser).
/// Each call to `open_level` gives an independent view, so every worker thread
/// can own one.
pub trait Pyramid: Sync {
    type Level<'a>: Grid
    where
        Self: 'a;
    fn num_levels(&self) -> usize;
    fn open_level(&self, level: usize) -> Result<Self::Level<'_>, GridError>;
    /// The ring planes kept for `level` across runs, if this pyramid keeps
    /// them ([`crate::nn::WithPlanes`]).
    fn planes(&self, _level: usize) -> Option<&crate::nn::PlaneTable> {
        None
    }
}

/// A borrowed in-memory level.
pub struct MemView<'a>(pub &'a MemGrid);

impl Grid for MemView<'_> {
    fn width(&self) -> i64 {
        self.0.width
    }
    fn height(&self) -> i64 {
        self.0.height
    }
    fn geotransform(&self) -> GeoTransform {
        self.0.geotransform
    }
    #[inline]
    fn get(&mut self, col: i64, row: i64) -> f32 {
        if col < 0 || row < 0 || col >= self.0.width || row >= self.0.height {
            return f32::NAN;
        }
        self.0.data[(row * self.0.width + col) as usize]
    }
}

/// An in-memory pyramid built with the same no-data-aware 2x2 mean as ingest.
#[derive(Clone, Debug)]
pub struct MemPyramid {
    pub levels: Vec<MemGrid>,
}

impl MemPyramid {
    /// Builds overviews until the long side is at most `min_size_px`.
    pub fn build(level0: MemGrid, min_size_px: i64) -> Self {
        let mut levels = vec![level0];
        loop {
            let last = levels.last().unwrap();
            if last.width.max(last.height) <= min_size_px || last.width < 2 || last.height < 2 {
                break;
            }
            let next = downsample_2x(last);
            levels.push(next);
        }
        MemPyramid { levels }
    }
}

/// No-data-aware 2x2 mean (an output pixel is NaN only when all inputs are).
pub fn downsample_2x(grid: &MemGrid) -> MemGrid {
    let (w, h) = ((grid.width + 1) / 2, (grid.height + 1) / 2);
    let mut src = MemView(grid);
    let mut data = Vec::with_capacity((w * h) as usize);
    for row in 0..h {
        for col in 0..w {
            let (mut sum, mut n) = (0.0f64, 0u32);
            for (dc, dr) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let v = src.get(2 * col + dc, 2 * row + dr);
                if !v.is_nan() {
                    sum += v as f64;
                    n += 1;
                }
            }
            data.push(if n == 0 {
                f32::NAN
            } else {
                (sum / n as f64) as f32
            });
        }
    }
    MemGrid::new(w, h, grid.geotransform.overview(1), data)
}

impl Pyramid for MemPyramid {
    type Level<'a> = MemView<'a>;
    fn num_levels(&self) -> usize {
        self.levels.len()
    }
    fn open_level(&self, level: usize) -> Result<MemView<'_>, GridError> {
        self.levels
            .get(level)
            .map(MemView)
            .ok_or(GridError::NoLevel {
                level,
                levels: self.levels.len(),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(width: i64, height: i64) -> MemGrid {
        let gt = GeoTransform::north_up(0.0, 0.0, 1.0, 1.0);
        MemGrid::from_fn(width, height, gt, |_, _| 1.0)
    }

    #[test]
    fn a_missing_level_is_a_typed_error() {
        let pyramid = MemPyramid::build(flat(8, 8), 4);
        assert_eq!(pyramid.num_levels(), 2);
        assert!(pyramid.open_level(1).is_ok());
        let err = pyramid.open_level(2).err().expect("no level 2");
        assert!(matches!(
            err,
            GridError::NoLevel {
                level: 2,
                levels: 2
            }
        ));
        assert_eq!(err.to_string(), "no level 2 (the pyramid has 2)");
        assert!(!err.is_bad_input());
    }

    #[test]
    fn a_chunk_error_keeps_its_message_and_is_bad_input() {
        let file = std::path::PathBuf::from("s.zarr/a/0/c/1/1");
        let source = ChunkReadError::Missing { file };
        let err = GridError::from(source.clone());
        assert_eq!(err.to_string(), source.to_string());
        assert!(err.is_bad_input());
        let mut grid = flat(2, 2);
        assert!(grid.take_error().is_none());
    }
}
