//! Running statistics of a DSM during ingest: valid pixel count, height
//! min/max/mean/std (blocks merged with Chan's parallel formula, so the
//! variance does not suffer from E[x²]-E[x]² cancellation) and the pixel
//! bounding box of the valid data (for the footprint).

use super::catalog::HeightStats;
use crate::raster::GeoTransform;

#[derive(Clone, Debug)]
pub struct HeightAccumulator {
    count: u64,
    mean: f64,
    m2: f64,
    min: f64,
    max: f64,
    /// Valid pixel box: min col, min row, max col, max row (inclusive).
    bbox: Option<[u64; 4]>,
}

impl Default for HeightAccumulator {
    fn default() -> Self {
        HeightAccumulator {
            count: 0,
            mean: 0.0,
            m2: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            bbox: None,
        }
    }
}

impl HeightAccumulator {
    /// Replace non-finite values by the canonical NaN (so all-no-data chunks
    /// equal the fill value byte for byte) and add the rest to the statistics.
    /// `rows` holds whole rows of `width` pixels starting at `row0`.
    pub fn add_rows(&mut self, rows: &mut [f32], width: usize, row0: u64) {
        let (mut n, mut sum) = (0u64, 0.0f64);
        for (r, row) in rows.chunks_exact_mut(width).enumerate() {
            let mut first: Option<usize> = None;
            let mut last = 0usize;
            for (c, v) in row.iter_mut().enumerate() {
                if !v.is_finite() {
                    *v = f32::NAN;
                    continue;
                }
                let x = *v as f64;
                n += 1;
                sum += x;
                self.min = self.min.min(x);
                self.max = self.max.max(x);
                first.get_or_insert(c);
                last = c;
            }
            if let Some(first) = first {
                let row = row0 + r as u64;
                let b = self
                    .bbox
                    .get_or_insert([first as u64, row, last as u64, row]);
                b[0] = b[0].min(first as u64);
                b[2] = b[2].max(last as u64);
                b[3] = row;
            }
        }
        if n == 0 {
            return;
        }
        let block_mean = sum / n as f64;
        let block_m2: f64 = rows
            .iter()
            .filter(|v| !v.is_nan())
            .map(|&v| (v as f64 - block_mean).powi(2))
            .sum();
        let total = self.count + n;
        let delta = block_mean - self.mean;
        self.mean += delta * n as f64 / total as f64;
        self.m2 += block_m2 + delta * delta * (self.count as f64 * n as f64) / total as f64;
        self.count = total;
    }

    pub fn valid_count(&self) -> u64 {
        self.count
    }

    /// Population statistics (None when no pixel was valid).
    pub fn height_stats(&self) -> Option<HeightStats> {
        (self.count > 0).then(|| HeightStats {
            min: self.min,
            max: self.max,
            mean: self.mean,
            std: (self.m2 / self.count as f64).sqrt(),
        })
    }

    /// World bounds [min_x, min_y, max_x, max_y] of the valid pixels (outer
    /// pixel edges); the raster bounds when nothing was valid.
    pub fn footprint(&self, gt: &GeoTransform, width: u64, height: u64) -> [f64; 4] {
        match self.bbox {
            None => gt.bounds(width, height),
            Some([c0, r0, c1, r1]) => {
                let (xa, ya) = gt.pixel_to_world(c0 as f64, r0 as f64);
                let (xb, yb) = gt.pixel_to_world(c1 as f64 + 1.0, r1 as f64 + 1.0);
                [xa.min(xb), ya.min(yb), xa.max(xb), ya.max(yb)]
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_merge_to_the_direct_statistics() {
        let nan = f32::NAN;
        let mut a = vec![nan, 10.0, 12.0, nan, f32::INFINITY, 11.0];
        let mut b = vec![nan, nan, nan, 1000.5, 13.0, nan];
        let mut acc = HeightAccumulator::default();
        acc.add_rows(&mut a, 3, 0);
        acc.add_rows(&mut b, 3, 2);
        assert!(a[4].is_nan() && a[4].to_bits() == f32::NAN.to_bits());
        let vals = [10.0, 12.0, 11.0, 1000.5, 13.0f64];
        let mean = vals.iter().sum::<f64>() / 5.0;
        let std = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / 5.0).sqrt();
        let s = acc.height_stats().unwrap();
        assert_eq!(acc.valid_count(), 5);
        assert_eq!((s.min, s.max), (10.0, 1000.5));
        assert!((s.mean - mean).abs() < 1e-9 && (s.std - std).abs() < 1e-9);
        let gt = GeoTransform::north_up(100.0, 200.0, 2.0, 2.0);
        // valid cols 0..=2, rows 0..=3
        assert_eq!(acc.footprint(&gt, 3, 4), [100.0, 192.0, 106.0, 200.0]);
    }

    #[test]
    fn all_no_data_has_no_statistics() {
        let mut rows = vec![f32::NAN; 8];
        let mut acc = HeightAccumulator::default();
        acc.add_rows(&mut rows, 4, 0);
        assert!(acc.height_stats().is_none());
        let gt = GeoTransform::north_up(0.0, 0.0, 1.0, 1.0);
        assert_eq!(acc.footprint(&gt, 4, 2), [0.0, -2.0, 4.0, 0.0]);
    }
}
