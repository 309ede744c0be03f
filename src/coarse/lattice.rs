//! The global scan's inner loop: moving samples tied to the pixel lattice of
//! the in-memory reference window, so that a trial shift by whole reference
//! pixels costs four array reads and a few multiply-adds per sample.
//!
//! [`cost::score_shift`](super::cost::score_shift) maps every sample to the
//! reference's pixels through the geotransform (two divisions and two floors
//! per look-up). The scan's shifts are whole multiples of the window's pixel,
//! so the bilinear cell of a sample only moves by whole pixels and its weights
//! (u, v) stay the same: [`LatticeSamples`] computes them once. The scores are
//! those of `score_shift` at the same shifts (up to rounding of the last bit).

use super::cost::{score_residuals, Sample, ShiftScore};
use crate::grid::{Grid, MemGrid};

/// One moving sample on the window's lattice at zero shift.
#[derive(Clone, Copy, Debug)]
struct Cell {
    /// Top-left pixel of the 2x2 bilinear neighbourhood.
    col: i64,
    row: i64,
    /// Bilinear weights of the right column and of the bottom row.
    u: f64,
    v: f64,
    h_m: f64,
}

/// Moving samples prepared for whole-pixel shifts of one reference window.
#[derive(Clone, Debug)]
pub struct LatticeSamples {
    cells: Vec<Cell>,
}

impl LatticeSamples {
    /// Ties `samples` (CRS metres) to the pixels of `window` (north-up).
    pub fn new(window: &MemGrid, samples: &[Sample]) -> LatticeSamples {
        let gt = window.geotransform();
        let cells = samples
            .iter()
            .map(|s| {
                let (c, r) = gt.world_to_pixel(s.x_m, s.y_m);
                let (c, r) = (c - 0.5, r - 0.5);
                let (c0, r0) = (c.floor(), r.floor());
                Cell {
                    col: c0 as i64,
                    row: r0 as i64,
                    u: c - c0,
                    v: r - r0,
                    h_m: s.h_m,
                }
            })
            .collect();
        LatticeSamples { cells }
    }

    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Scores the shift of `shift_px` = (i, j) window pixels, that is
    /// (i gsd_x, j gsd_y) metres east and north (rows grow southwards);
    /// the same score as `score_shift` at that shift.
    pub fn score(
        &self,
        window: &MemGrid,
        shift_px: [i64; 2],
        min_support: usize,
        scratch: &mut Vec<f64>,
    ) -> ShiftScore {
        scratch.clear();
        let (w, h) = (window.width, window.height);
        let data = &window.data;
        for cell in &self.cells {
            let (c, r) = (cell.col + shift_px[0], cell.row - shift_px[1]);
            if c < 0 || r < 0 || c + 1 >= w || r + 1 >= h {
                continue;
            }
            let at = (r * w + c) as usize;
            let (h00, h10) = (data[at] as f64, data[at + 1] as f64);
            let below = at + w as usize;
            let (h01, h11) = (data[below] as f64, data[below + 1] as f64);
            let top = h00 * (1.0 - cell.u) + h10 * cell.u;
            let bottom = h01 * (1.0 - cell.u) + h11 * cell.u;
            let height = top * (1.0 - cell.v) + bottom * cell.v;
            if height.is_finite() {
                scratch.push(height - cell.h_m);
            }
        }
        score_residuals(scratch, min_support)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coarse::cost::score_shift;
    use crate::geo::GeoTransform;

    /// A rough surface with voids, and samples off the window's lattice.
    fn window_and_samples() -> (MemGrid, Vec<Sample>) {
        let gt = GeoTransform::north_up(1000.0, 2000.0, 2.0, 2.0);
        let window = MemGrid::from_fn(60, 50, gt, |c, r| {
            if (c * 7 + r * 3) % 23 == 0 {
                f32::NAN
            } else {
                (0.3 * c as f32 + (r as f32 * 0.7).sin() * 5.0 + ((c * r) % 5) as f32) * 1.1
            }
        });
        let samples = (0..400)
            .map(|k| Sample {
                x_m: 1010.3 + (k % 20) as f64 * 4.1,
                y_m: 1990.7 - (k / 20) as f64 * 3.9,
                h_m: k as f64 * 0.01,
            })
            .collect();
        (window, samples)
    }

    #[test]
    fn scores_equal_the_transformed_look_ups() {
        let (mut window, samples) = window_and_samples();
        let lattice = LatticeSamples::new(&window, &samples);
        assert_eq!(lattice.len(), samples.len());
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for j in -8..=8 {
            for i in -12..=12 {
                let fast = lattice.score(&window, [i, j], 20, &mut a);
                let shift_m = [i as f64 * 2.0, j as f64 * 2.0];
                let slow = score_shift(&mut window, &samples, shift_m, 20, &mut b);
                assert_eq!(fast.support, slow.support, "({i}, {j})");
                if slow.cost_m.is_finite() {
                    assert!((fast.cost_m - slow.cost_m).abs() < 1e-9, "({i}, {j})");
                    assert!((fast.dz_m - slow.dz_m).abs() < 1e-9, "({i}, {j})");
                } else {
                    assert_eq!(fast.cost_m, f64::INFINITY);
                }
            }
        }
    }

    #[test]
    fn samples_shifted_off_the_window_have_no_support() {
        let (window, samples) = window_and_samples();
        let lattice = LatticeSamples::new(&window, &samples);
        let far = lattice.score(&window, [100, 0], 0, &mut Vec::new());
        assert_eq!(far.support, 0);
        assert_eq!(far.cost_m, f64::INFINITY);
    }
}
