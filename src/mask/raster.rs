//! The mask as bits on a north-up lattice ([`BitRaster`], one bit per cell:
//! set = stable), its 2x overviews ([`BitPyramid`]) and the look-up of a DSM
//! level's pixels in it ([`MaskLookup`]).
//!
//! A pixel is stable only when every mask cell it touches is stable: the
//! look-up picks the finest mask overview whose cells are at least as large as
//! the pixel (so a pixel touches at most 2 x 2 of them) and checks those.
//! Cells outside the mask's extent are not stable. An overview cell is stable
//! when at least 3 of its 4 children are: a contiguous excluded area stays
//! excluded at every level, while a scattered mask (1 excluded cell in 4) does
//! not wipe out the coarse levels. Level 0 of the DSMs is looked up exactly.

use crate::geo::{Bounds, GeoTransform};

/// One bit per cell of a north-up lattice; set = stable.
#[derive(Clone)]
pub struct BitRaster {
    pub geotransform: GeoTransform,
    pub width: i64,
    pub height: i64,
    words_per_row: usize,
    bits: Vec<u64>,
}

impl BitRaster {
    /// All cells unset (excluded).
    pub fn new(geotransform: GeoTransform, width: i64, height: i64) -> Self {
        let words_per_row = (width.max(0) as usize).div_ceil(64);
        BitRaster {
            geotransform,
            width,
            height,
            words_per_row,
            bits: vec![0; words_per_row * height.max(0) as usize],
        }
    }

    /// True when (col, row) is inside the raster and stable.
    #[inline]
    pub fn get(&self, col: i64, row: i64) -> bool {
        if col < 0 || row < 0 || col >= self.width || row >= self.height {
            return false;
        }
        let word = self.bits[row as usize * self.words_per_row + col as usize / 64];
        (word >> (col % 64)) & 1 == 1
    }

    /// Marks (col, row) stable (ignored outside the raster).
    pub fn set(&mut self, col: i64, row: i64) {
        if col < 0 || row < 0 || col >= self.width || row >= self.height {
            return;
        }
        self.bits[row as usize * self.words_per_row + col as usize / 64] |= 1 << (col % 64);
    }

    /// Stable cells.
    pub fn count(&self) -> u64 {
        self.bits.iter().map(|w| w.count_ones() as u64).sum()
    }

    /// The raster's extent in CRS units.
    pub fn extent(&self) -> Bounds {
        self.geotransform
            .extent(self.width as u64, self.height as u64)
    }

    /// The 2x overview: a cell is stable when at least 3 of its 4 children are
    /// (children outside the raster count as excluded).
    pub fn overview(&self) -> BitRaster {
        let (w, h) = ((self.width + 1) / 2, (self.height + 1) / 2);
        let mut out = BitRaster::new(self.geotransform.overview(1), w, h);
        for row in 0..h {
            for col in 0..w {
                let stable = [(0, 0), (1, 0), (0, 1), (1, 1)]
                    .iter()
                    .filter(|(dc, dr)| self.get(2 * col + dc, 2 * row + dr))
                    .count();
                if stable >= 3 {
                    out.set(col, row);
                }
            }
        }
        out
    }
}

/// A [`BitRaster`] and its overviews down to a few cells.
#[derive(Clone)]
pub struct BitPyramid {
    /// Level 0 is the mask as read; each next level 2x coarser.
    pub levels: Vec<BitRaster>,
}

impl BitPyramid {
    pub fn build(level0: BitRaster) -> Self {
        let mut levels = vec![level0];
        loop {
            let last = levels.last().expect("level 0");
            if last.width.max(last.height) <= 4 {
                break;
            }
            let next = last.overview();
            levels.push(next);
        }
        BitPyramid { levels }
    }

    /// The look-up of the pixels of a `width` x `height` raster placed by
    /// `pixels` (north-up).
    pub fn lookup(&self, pixels: &GeoTransform, width: i64, height: i64) -> MaskLookup<'_> {
        let fits = |r: &BitRaster| {
            r.geotransform.gsd_x() >= pixels.gsd_x() * (1.0 - 1e-9)
                && r.geotransform.gsd_y() >= pixels.gsd_y() * (1.0 - 1e-9)
        };
        let raster = self
            .levels
            .iter()
            .find(|r| fits(r))
            .unwrap_or_else(|| self.levels.last().expect("level 0"));
        let (m, p) = (&raster.geotransform.0, &pixels.0);
        MaskLookup {
            raster,
            cols: spans((p[0] - m[0]) / m[1], p[1] / m[1], width),
            rows: spans((p[3] - m[3]) / m[5], p[5] / m[5], height),
        }
    }
}

/// A pixel's edge is pulled in by this fraction, so that a pixel whose edge
/// lies on a cell edge (the same lattice) does not touch the next cell.
const EDGE_EPS: f64 = 1e-6;

/// Per pixel k of `count`, the first and last mask cell it covers: pixel k
/// spans [origin + k * per_pixel, origin + (k + 1) * per_pixel) in cells.
fn spans(origin: f64, per_pixel: f64, count: i64) -> Vec<(i64, i64)> {
    (0..count.max(0))
        .map(|k| {
            let a = origin + (k as f64 + EDGE_EPS) * per_pixel;
            let b = origin + (k as f64 + 1.0 - EDGE_EPS) * per_pixel;
            (a.min(b).floor() as i64, a.max(b).floor() as i64)
        })
        .collect()
}

/// Whether the pixels of one raster are stable: the mask cells each column
/// and each row covers, computed once.
#[derive(Clone)]
pub struct MaskLookup<'a> {
    raster: &'a BitRaster,
    cols: Vec<(i64, i64)>,
    rows: Vec<(i64, i64)>,
}

impl MaskLookup<'_> {
    /// True when every mask cell under the pixel is stable (false outside
    /// the raster the look-up was made for).
    #[inline]
    pub fn is_stable(&self, col: i64, row: i64) -> bool {
        let (Some(&(c0, c1)), Some(&(r0, r1))) = (
            usize::try_from(col).ok().and_then(|c| self.cols.get(c)),
            usize::try_from(row).ok().and_then(|r| self.rows.get(r)),
        ) else {
            return false;
        };
        if c0 == c1 && r0 == r1 {
            return self.raster.get(c0, r0);
        }
        (r0..=r1).all(|r| (c0..=c1).all(|c| self.raster.get(c, r)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 8 x 8 cells of 1 m, all stable but the block [4, 8) x [0, 4).
    fn block_mask() -> BitRaster {
        let mut m = BitRaster::new(GeoTransform::north_up(100.0, 208.0, 1.0, 1.0), 8, 8);
        for r in 0..8 {
            for c in 0..8 {
                if !(c >= 4 && r < 4) {
                    m.set(c, r);
                }
            }
        }
        m
    }

    #[test]
    fn bits_are_set_read_and_counted() {
        let m = block_mask();
        assert!(m.get(0, 0) && !m.get(4, 0) && m.get(4, 4));
        assert!(!m.get(-1, 0) && !m.get(8, 0));
        assert_eq!(m.count(), 48);
        assert_eq!(m.extent().to_array(), [100.0, 200.0, 108.0, 208.0]);
    }

    #[test]
    fn an_overview_keeps_a_block_and_forgives_one_cell_in_four() {
        let mut m = block_mask();
        m.set(4, 0); // 1 of the 4 children of overview cell (2, 0): still excluded
        let o = m.overview();
        assert_eq!((o.width, o.height), (4, 4));
        assert!(o.get(0, 0) && o.get(3, 3));
        assert!(!o.get(2, 0) && !o.get(3, 0) && !o.get(2, 1));
        // all stable but cell (0, 0): its overview cell has 3 of 4 stable children
        let mut one = BitRaster::new(m.geotransform, 8, 8);
        (0..64)
            .filter(|k| *k != 0)
            .for_each(|k| one.set(k % 8, k / 8));
        assert_eq!(one.overview().count(), 16);
    }

    #[test]
    fn a_pixel_is_stable_only_when_every_cell_under_it_is() {
        let pyramid = BitPyramid::build(block_mask());
        // the same lattice: exact per pixel
        let same = pyramid.lookup(&GeoTransform::north_up(100.0, 208.0, 1.0, 1.0), 8, 8);
        assert!(same.is_stable(3, 0) && !same.is_stable(4, 0) && same.is_stable(4, 4));
        assert!(!same.is_stable(-1, 5) && !same.is_stable(8, 5), "outside");
        let wide = pyramid.lookup(&GeoTransform::north_up(100.0, 208.0, 1.0, 1.0), 9, 8);
        assert!(!wide.is_stable(8, 5), "outside the mask");
        // half-pixel offset 2 m pixels: pixel 1 covers cells 3..5 and touches the block
        let offset = pyramid.lookup(&GeoTransform::north_up(101.0, 208.0, 2.0, 2.0), 4, 4);
        assert!(offset.is_stable(0, 0) && !offset.is_stable(1, 0));
        assert!(offset.is_stable(1, 2));
        // finer pixels than the mask
        let fine = pyramid.lookup(&GeoTransform::north_up(100.0, 208.0, 0.25, 0.25), 32, 32);
        assert!(fine.is_stable(15, 0) && !fine.is_stable(16, 0) && fine.is_stable(16, 16));
    }
}
