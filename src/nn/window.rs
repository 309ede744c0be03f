//! A block of queries' share of the reference, copied once: the searches of
//! one block read their pixels from a dense window (an index, no chunk
//! lookup), and fall back to the grid outside it, so the answers are those of
//! the grid itself.

use crate::geo::GeoTransform;
use crate::grid::{Grid, GridError};

/// The largest window copied, pixels (16 MiB of f32): a search radius that
/// covers more reads the grid pixel by pixel.
pub const MAX_WINDOW_PX: usize = 4 << 20;

/// `inner` with the pixels of one rectangle held in memory.
pub struct Window<'g, G: ?Sized> {
    inner: &'g mut G,
    col0: i64,
    row0: i64,
    w: usize,
    h: usize,
    data: Vec<f32>,
}

impl<'g, G: Grid + ?Sized> Window<'g, G> {
    /// No pixel held: every read from `inner`.
    pub fn none(inner: &'g mut G) -> Self {
        Window {
            inner,
            col0: 0,
            row0: 0,
            w: 0,
            h: 0,
            data: Vec::new(),
        }
    }

    /// The pixels of `inner` within `margin_px` of the pixel box [c0, c1] x
    /// [r0, r1] (inclusive), clipped to the raster; no window (every read
    /// from `inner`) when that is empty or larger than [`MAX_WINDOW_PX`].
    pub fn around(
        inner: &'g mut G,
        (c0, r0, c1, r1): (i64, i64, i64, i64),
        margin_px: i64,
    ) -> Self {
        let col0 = c0.saturating_sub(margin_px).max(0);
        let row0 = r0.saturating_sub(margin_px).max(0);
        let col1 = c1.saturating_add(margin_px).min(inner.width() - 1);
        let row1 = r1.saturating_add(margin_px).min(inner.height() - 1);
        let (w, h) = ((col1 - col0 + 1).max(0), (row1 - row0 + 1).max(0));
        let (w, h) = (w as usize, h as usize);
        if w == 0 || h == 0 || w.saturating_mul(h) > MAX_WINDOW_PX {
            return Window::none(inner);
        }
        let data = inner.read_window(col0, row0, w, h);
        Window {
            inner,
            col0,
            row0,
            w,
            h,
            data,
        }
    }
}

impl<G: Grid + ?Sized> Grid for Window<'_, G> {
    fn width(&self) -> i64 {
        self.inner.width()
    }
    fn height(&self) -> i64 {
        self.inner.height()
    }
    fn geotransform(&self) -> GeoTransform {
        self.inner.geotransform()
    }
    #[inline]
    fn get(&mut self, col: i64, row: i64) -> f32 {
        let (dc, dr) = (col.wrapping_sub(self.col0), row.wrapping_sub(self.row0));
        // negatives wrap to huge values
        if (dc as u64) < self.w as u64 && (dr as u64) < self.h as u64 {
            return self.data[dr as usize * self.w + dc as usize];
        }
        self.inner.get(col, row)
    }
    fn take_error(&mut self) -> Option<GridError> {
        self.inner.take_error()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::MemGrid;

    /// Every pixel reads as from the grid, inside the window, outside it and
    /// outside the raster, with and without a window.
    #[test]
    fn a_window_reads_as_its_grid() {
        let gt = GeoTransform::north_up(0.0, 10.0, 1.0, 1.0);
        let mut grid = MemGrid::from_fn(23, 17, gt, |c, r| {
            if (c * 7 + r * 3) % 11 == 0 {
                f32::NAN
            } else {
                (c * 100 + r) as f32
            }
        });
        let mut plain = grid.clone();
        for (bounds, margin) in [
            ((5, 4, 9, 6), 2),
            ((-3, -3, 30, 30), 0),
            ((20, 15, 22, 16), 5),
        ] {
            let mut window = Window::around(&mut grid, bounds, margin);
            for row in -2..20 {
                for col in -2..26 {
                    let (a, b) = (window.get(col, row), plain.get(col, row));
                    assert!(
                        a == b || (a.is_nan() && b.is_nan()),
                        "({col}, {row}): {a} vs {b}"
                    );
                }
            }
        }
        let window = Window::around(&mut grid, (5, 4, 9, 6), 2);
        assert_eq!((window.col0, window.row0, window.w, window.h), (3, 2, 9, 7));
        let huge = Window::around(&mut grid, (0, 0, 1 << 40, 1 << 40), 0);
        assert_eq!(huge.w * huge.h, 23 * 17, "clipped to the raster");
    }
}
