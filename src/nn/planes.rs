//! Ring planes shared by every run of one pair on one reference level.
//!
//! The tangent plane under a query ([`super::surface`]) depends only on the
//! reference grid and the pixel, yet each ICP run fits it afresh: the
//! starts' ladders, the restarts pushed a few pixels off and coming back, and
//! the final matches all visit the same pixels (on the 8 x 8 grid of 128 m
//! tiles the fits took a third of `align`'s time). A [`PlaneTable`] keeps the
//! plane of each pixel of a window once it is fitted; the result is the same
//! plane, bit for bit, whichever run or thread fitted it first.
//!
//! [`WithPlanes`] hands a table to the matching through the pyramid it
//! wraps. Memory: [`MAX_TABLE_PIXELS`] entries at most (15 MiB); larger
//! windows get no table and fit as before.

use std::sync::OnceLock;

use super::plane::Plane;
use crate::grid::{GridError, Pyramid};

/// Largest window a table covers, pixels (56 bytes each: 15 MiB).
pub const MAX_TABLE_PIXELS: i64 = 1 << 18;

/// The ring planes of a window of pixels of one reference level, each fitted
/// once (lazily, by whichever thread first needs it).
pub struct PlaneTable {
    col0: i64,
    row0: i64,
    width: i64,
    height: i64,
    cells: Box<[OnceLock<Option<Plane>>]>,
}

impl PlaneTable {
    /// A table over columns `col0..col0 + width` and rows `row0..row0 +
    /// height`; None when empty or larger than [`MAX_TABLE_PIXELS`].
    pub fn new(col0: i64, row0: i64, width: i64, height: i64) -> Option<Self> {
        if width <= 0 || height <= 0 || width.saturating_mul(height) > MAX_TABLE_PIXELS {
            return None;
        }
        let cells = (0..width * height).map(|_| OnceLock::new()).collect();
        Some(PlaneTable {
            col0,
            row0,
            width,
            height,
            cells,
        })
    }

    /// The plane at (col, row): the kept one, or `fit()` (kept when the pixel
    /// lies in the window).
    pub(super) fn plane_or(
        &self,
        col: i64,
        row: i64,
        fit: impl FnOnce() -> Option<Plane>,
    ) -> Option<Plane> {
        let (c, r) = (col - self.col0, row - self.row0);
        if c < 0 || r < 0 || c >= self.width || r >= self.height {
            return fit();
        }
        *self.cells[(r * self.width + c) as usize].get_or_init(fit)
    }
}

/// A pyramid whose level `level` carries a [`PlaneTable`]; reads go to the
/// wrapped pyramid.
pub struct WithPlanes<'a, P> {
    inner: &'a P,
    level: usize,
    table: Option<PlaneTable>,
}

impl<'a, P: Pyramid> WithPlanes<'a, P> {
    pub fn new(inner: &'a P, level: usize, table: Option<PlaneTable>) -> Self {
        WithPlanes {
            inner,
            level,
            table,
        }
    }
}

impl<P: Pyramid> Pyramid for WithPlanes<'_, P> {
    type Level<'b>
        = P::Level<'b>
    where
        Self: 'b;

    fn num_levels(&self) -> usize {
        self.inner.num_levels()
    }

    fn open_level(&self, level: usize) -> Result<Self::Level<'_>, GridError> {
        self.inner.open_level(level)
    }

    fn planes(&self, level: usize) -> Option<&PlaneTable> {
        (level == self.level)
            .then_some(self.table.as_ref())
            .flatten()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(z0: f64) -> Option<Plane> {
        Some(Plane {
            z0,
            a: 0.0,
            b: 0.0,
            rms_m: 0.0,
            slope_var: 0.0,
        })
    }

    #[test]
    fn a_pixel_is_fitted_once_inside_the_window_and_each_time_outside() {
        let table = PlaneTable::new(10, 20, 4, 3).unwrap();
        let mut fits = 0;
        for _ in 0..3 {
            let p = table.plane_or(11, 22, || {
                fits += 1;
                plane(1.0)
            });
            assert_eq!(p.unwrap().z0, 1.0);
        }
        assert_eq!(fits, 1);
        // a pixel without a plane is kept as such
        let mut misses = 0;
        for _ in 0..2 {
            assert!(table
                .plane_or(13, 20, || {
                    misses += 1;
                    None
                })
                .is_none());
        }
        assert_eq!(misses, 1);
        // outside the window (col 14 = col0 + width, row 19): fitted each time
        let mut outside = 0;
        for (c, r) in [(14, 21), (14, 21), (12, 19), (12, 19)] {
            table.plane_or(c, r, || {
                outside += 1;
                plane(2.0)
            });
        }
        assert_eq!(outside, 4);
    }

    #[test]
    fn windows_beyond_the_cap_or_empty_get_no_table() {
        // the memory the module doc states: 56 bytes a pixel, 15 MiB at most
        assert_eq!(std::mem::size_of::<OnceLock<Option<Plane>>>(), 56);
        const { assert!(MAX_TABLE_PIXELS * 56 <= 15 << 20) };
        assert!(PlaneTable::new(0, 0, 512, 512).is_some());
        assert!(PlaneTable::new(0, 0, 513, 512).is_none());
        assert!(PlaneTable::new(0, 0, 0, 5).is_none());
        assert!(PlaneTable::new(0, 0, i64::MAX, i64::MAX).is_none());
    }
}
