//! Running statistics of a DSM during ingest: valid pixel count, height
//! min/max/mean/std (blocks merged with Chan's parallel formula, so the
//! variance does not suffer from E[x²]-E[x]² cancellation) and the pixel
//! bounding box of the valid data (for the footprint).

use rayon::prelude::*;

use super::catalog::HeightStats;
use crate::geo::{Bounds, GeoTransform};

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
    ///
    /// Bands of rows are summed in parallel around a shift `k` (the running
    /// mean, or the block's first valid height), so the block variance
    /// `Σ(x-k)² - (Σ(x-k))²/n` does not cancel however high the terrain; blocks
    /// are then merged with Chan's formula.
    pub fn add_rows(&mut self, rows: &mut [f32], width: usize, row0: u64) {
        if width == 0 || rows.is_empty() {
            return;
        }
        let k = if self.count > 0 {
            self.mean
        } else {
            match rows.iter().find(|v| v.is_finite()) {
                Some(&v) => v as f64,
                None => {
                    rows.iter_mut().for_each(|v| *v = f32::NAN);
                    return;
                }
            }
        };
        const BAND_ROWS: usize = 8;
        // bands in parallel, merged in band order: rayon's reduce groups them
        // as its threads happened to split the work, which moves the last
        // bits of the sums from run to run
        let bands: Vec<BlockSums> = rows
            .par_chunks_mut(width * BAND_ROWS)
            .enumerate()
            .map(|(b, band)| BlockSums::of_band(band, width, row0 + (b * BAND_ROWS) as u64, k))
            .collect();
        let block = bands
            .into_iter()
            .fold(BlockSums::default(), BlockSums::merge);
        if block.n == 0 {
            return;
        }
        self.min = self.min.min(block.min);
        self.max = self.max.max(block.max);
        if let Some([c0, r0, c1, r1]) = block.bbox {
            let b = self.bbox.get_or_insert([c0, r0, c1, r1]);
            b[0] = b[0].min(c0);
            b[1] = b[1].min(r0);
            b[2] = b[2].max(c1);
            b[3] = b[3].max(r1);
        }
        let n = block.n as f64;
        let block_mean = k + block.s1 / n;
        let block_m2 = (block.s2 - block.s1 * block.s1 / n).max(0.0);
        let total = self.count + block.n;
        let delta = block_mean - self.mean;
        self.mean += delta * n / total as f64;
        self.m2 += block_m2 + delta * delta * (self.count as f64 * n) / total as f64;
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

    /// World box of the valid pixels (outer pixel edges); the raster's
    /// extent when nothing was valid.
    pub fn footprint(&self, gt: &GeoTransform, width: u64, height: u64) -> Bounds {
        match self.bbox {
            None => gt.extent(width, height),
            Some([c0, r0, c1, r1]) => Bounds::from_corners(
                gt.pixel_to_world(c0 as f64, r0 as f64),
                gt.pixel_to_world(c1 as f64 + 1.0, r1 as f64 + 1.0),
            ),
        }
    }
}

/// Sums of one block (or band) of rows around a shift `k`.
#[derive(Clone, Copy, Debug)]
struct BlockSums {
    n: u64,
    /// Σ (x - k) and Σ (x - k)² over the valid pixels.
    s1: f64,
    s2: f64,
    min: f64,
    max: f64,
    bbox: Option<[u64; 4]>,
}

impl Default for BlockSums {
    fn default() -> Self {
        BlockSums {
            n: 0,
            s1: 0.0,
            s2: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            bbox: None,
        }
    }
}

impl BlockSums {
    /// Canonicalise the non-finite values of `band` (whole rows from `row0`) and sum the rest.
    fn of_band(band: &mut [f32], width: usize, row0: u64, k: f64) -> BlockSums {
        let mut s = BlockSums::default();
        for (r, row) in band.chunks_exact_mut(width).enumerate() {
            let (mut n, mut s1, mut s2) = (0u64, 0.0f64, 0.0f64);
            let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
            for v in row.iter_mut() {
                if v.is_finite() {
                    let d = *v as f64 - k;
                    n += 1;
                    s1 += d;
                    s2 += d * d;
                    lo = lo.min(*v);
                    hi = hi.max(*v);
                } else {
                    *v = f32::NAN;
                }
            }
            if n == 0 {
                continue;
            }
            let first = row.iter().position(|v| !v.is_nan()).unwrap_or(0) as u64;
            let last = row.iter().rposition(|v| !v.is_nan()).unwrap_or(0) as u64;
            let y = row0 + r as u64;
            s = BlockSums::merge(
                s,
                BlockSums {
                    n,
                    s1,
                    s2,
                    min: lo as f64,
                    max: hi as f64,
                    bbox: Some([first, y, last, y]),
                },
            );
        }
        s
    }

    fn merge(a: BlockSums, b: BlockSums) -> BlockSums {
        let bbox = match (a.bbox, b.bbox) {
            (Some(x), Some(y)) => Some([
                x[0].min(y[0]),
                x[1].min(y[1]),
                x[2].max(y[2]),
                x[3].max(y[3]),
            ]),
            (x, None) => x,
            (None, y) => y,
        };
        BlockSums {
            n: a.n + b.n,
            s1: a.s1 + b.s1,
            s2: a.s2 + b.s2,
            min: a.min.min(b.min),
            max: a.max.max(b.max),
            bbox,
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
        assert_eq!(
            acc.footprint(&gt, 3, 4).to_array(),
            [100.0, 192.0, 106.0, 200.0]
        );
    }

    #[test]
    fn high_terrain_keeps_its_small_variance_over_many_blocks() {
        // 3000 m terrain with centimetre variation: E[x²]-E[x]² would cancel.
        let width = 37;
        let mut all = Vec::new();
        let mut acc = HeightAccumulator::default();
        let mut seed = 7u64;
        for block in 0..20u64 {
            let mut rows: Vec<f32> = (0..width * 11)
                .map(|i| {
                    seed = seed
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    if i % 13 == 5 {
                        f32::NEG_INFINITY
                    } else {
                        3000.0 + ((seed >> 40) as f32 / (1u64 << 24) as f32) * 0.05
                    }
                })
                .collect();
            all.extend(
                rows.iter()
                    .copied()
                    .filter(|v| v.is_finite())
                    .map(f64::from),
            );
            acc.add_rows(&mut rows, width, block * 11);
            assert!(rows
                .iter()
                .all(|v| v.is_finite() || v.to_bits() == f32::NAN.to_bits()));
        }
        let n = all.len() as f64;
        let mean = all.iter().sum::<f64>() / n;
        let std = (all.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
        let s = acc.height_stats().unwrap();
        assert_eq!(acc.valid_count(), all.len() as u64);
        assert!((s.mean - mean).abs() < 1e-9, "{} vs {mean}", s.mean);
        assert!(
            (s.std - std).abs() < 1e-9 * std.max(1.0),
            "{} vs {std}",
            s.std
        );
        assert!(std > 0.01, "the data vary");
    }

    /// The statistics are the same bits on any number of threads and in
    /// any run (bands merged in order, not as rayon happened to split them).
    #[test]
    fn statistics_do_not_depend_on_the_threads() {
        let width = 301;
        let rows: Vec<f32> = (0..width * 517)
            .map(|i| 1500.0 + ((i * 7919) % 1013) as f32 * 0.37)
            .collect();
        let stats = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let mut acc = HeightAccumulator::default();
                let mut copy = rows.clone();
                acc.add_rows(&mut copy, width, 0);
                let s = acc.height_stats().unwrap();
                [s.mean.to_bits(), s.std.to_bits()]
            })
        };
        let one = stats(1);
        for threads in [2, 3, 8, 8, 8] {
            assert_eq!(stats(threads), one, "{threads} threads");
        }
    }

    #[test]
    fn all_no_data_has_no_statistics() {
        let mut rows = vec![f32::NAN; 8];
        let mut acc = HeightAccumulator::default();
        acc.add_rows(&mut rows, 4, 0);
        assert!(acc.height_stats().is_none());
        let gt = GeoTransform::north_up(0.0, 0.0, 1.0, 1.0);
        assert_eq!(acc.footprint(&gt, 4, 2).to_array(), [0.0, -2.0, 4.0, 0.0]);
    }
}
