//! Height-difference statistics: the paper's rmse_tau and the customary robust
//! figures (pc_align, xDEM) of a set of differences dh.
//!
//! Definitions (all in metres):
//! - samples: horizontal locations where both surfaces have a height;
//! - inliers: samples with |dh| < tau; inlier_fraction = inliers / samples;
//! - rmse_tau = sqrt(1/N sum_{|dh|<tau} dh^2) with **N = inliers** (paper, Xu & Qin 2024);
//! - mean, median, NMAD = 1.4826 median|dh - median|, and the 16/84 percentiles
//!   (linear interpolation between order statistics) are over the inliers too.

use serde::Serialize;

/// Figures of one set of height differences.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct DiffStats {
    pub samples: u64,
    pub inliers: u64,
    pub inlier_fraction: f64,
    pub rmse_tau_m: f64,
    pub mean_m: f64,
    pub median_m: f64,
    pub nmad_m: f64,
    pub p16_m: f64,
    pub p84_m: f64,
}

/// Statistics of `dh` (NaN entries ignored) with threshold `tau_m`; reorders `dh`.
pub fn diff_stats(dh: &mut Vec<f32>, tau_m: f64) -> DiffStats {
    dh.retain(|v| !v.is_nan());
    let samples = dh.len() as u64;
    dh.retain(|&v| (v as f64).abs() < tau_m);
    let n = dh.len();
    if n == 0 {
        return DiffStats {
            samples,
            ..Default::default()
        };
    }
    let sum: f64 = dh.iter().map(|&v| v as f64).sum();
    let sum_sq: f64 = dh.iter().map(|&v| (v as f64).powi(2)).sum();
    dh.sort_unstable_by(f32::total_cmp);
    let median = percentile_sorted(dh, 50.0);
    let mut dev: Vec<f32> = dh
        .iter()
        .map(|&v| (v as f64 - median).abs() as f32)
        .collect();
    dev.sort_unstable_by(f32::total_cmp);
    DiffStats {
        samples,
        inliers: n as u64,
        inlier_fraction: n as f64 / samples as f64,
        rmse_tau_m: (sum_sq / n as f64).sqrt(),
        mean_m: sum / n as f64,
        median_m: median,
        nmad_m: 1.4826 * percentile_sorted(&dev, 50.0),
        p16_m: percentile_sorted(dh, 16.0),
        p84_m: percentile_sorted(dh, 84.0),
    }
}

/// Percentile `q` (0..=100) of sorted values, linear between order statistics.
pub fn percentile_sorted(sorted: &[f32], q: f64) -> f64 {
    match sorted.len() {
        0 => f64::NAN,
        1 => sorted[0] as f64,
        n => {
            let pos = q / 100.0 * (n - 1) as f64;
            let lo = pos.floor() as usize;
            let hi = (lo + 1).min(n - 1);
            let f = pos - lo as f64;
            sorted[lo] as f64 * (1.0 - f) + sorted[hi] as f64 * f
        }
    }
}

/// Mean of each figure over the sets that have inliers (the paper's "mean over
/// pairs"); `samples` and `inliers` are totals. None when no set has inliers.
pub fn mean_over(sets: &[DiffStats]) -> Option<DiffStats> {
    let used: Vec<&DiffStats> = sets.iter().filter(|s| s.inliers > 0).collect();
    if used.is_empty() {
        return None;
    }
    let n = used.len() as f64;
    let avg = |f: fn(&DiffStats) -> f64| used.iter().map(|s| f(s)).sum::<f64>() / n;
    Some(DiffStats {
        samples: sets.iter().map(|s| s.samples).sum(),
        inliers: sets.iter().map(|s| s.inliers).sum(),
        inlier_fraction: avg(|s| s.inlier_fraction),
        rmse_tau_m: avg(|s| s.rmse_tau_m),
        mean_m: avg(|s| s.mean_m),
        median_m: avg(|s| s.median_m),
        nmad_m: avg(|s| s.nmad_m),
        p16_m: avg(|s| s.p16_m),
        p84_m: avg(|s| s.p84_m),
    })
}

/// Keeps a deterministic, evenly thinned subset of a stream (every `stride`-th
/// value, the stride doubling whenever `cap` is passed): bounded samples for plots.
#[derive(Clone, Debug)]
pub struct Thinned {
    pub values: Vec<f32>,
    stride: u64,
    seen: u64,
    cap: usize,
}

impl Thinned {
    pub fn new(cap: usize) -> Thinned {
        Thinned {
            values: Vec::new(),
            stride: 1,
            seen: 0,
            cap: cap.max(2),
        }
    }

    pub fn push(&mut self, v: f32) {
        if self.seen.is_multiple_of(self.stride) {
            self.values.push(v);
            if self.values.len() > self.cap {
                let mut k = 0;
                self.values.retain(|_| {
                    k += 1;
                    k % 2 == 1
                });
                self.stride *= 2;
            }
        }
        self.seen += 1;
    }

    pub fn extend(&mut self, values: &[f32]) {
        for &v in values {
            self.push(v);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_of_a_known_set() {
        // 10 inliers -4.5..4.5 and two outliers beyond tau = 10
        let mut dh: Vec<f32> = (0..10).map(|k| k as f32 - 4.5).collect();
        dh.extend([25.0, -30.0, f32::NAN]);
        let s = diff_stats(&mut dh, 10.0);
        assert_eq!((s.samples, s.inliers), (12, 10));
        assert!((s.inlier_fraction - 10.0 / 12.0).abs() < 1e-12);
        let want_rmse = ((0..10).map(|k| (k as f64 - 4.5).powi(2)).sum::<f64>() / 10.0).sqrt();
        assert!((s.rmse_tau_m - want_rmse).abs() < 1e-9);
        assert_eq!((s.mean_m, s.median_m), (0.0, 0.0));
        // |dh - 0| = 0.5,0.5,1.5,1.5,...,4.5,4.5 -> median 2.5
        assert!((s.nmad_m - 1.4826 * 2.5).abs() < 1e-9);
        assert!((s.p16_m - (-4.5 + 0.16 * 9.0)).abs() < 1e-6);
        assert!((s.p84_m - (-4.5 + 0.84 * 9.0)).abs() < 1e-6);
    }

    #[test]
    fn empty_and_mean_over_sets() {
        let s = diff_stats(&mut vec![f32::NAN, 50.0], 10.0);
        assert_eq!((s.samples, s.inliers), (1, 0));
        let a = diff_stats(&mut vec![1.0, 1.0], 10.0);
        let b = diff_stats(&mut vec![3.0, 3.0], 10.0);
        let m = mean_over(&[a, b, s]).unwrap();
        assert_eq!(m.rmse_tau_m, 2.0);
        assert_eq!(m.samples, 5);
        assert!(mean_over(&[s]).is_none());
    }

    #[test]
    fn thinning_is_bounded_and_even() {
        let mut t = Thinned::new(100);
        for k in 0..10_000 {
            t.push(k as f32);
        }
        assert!(t.values.len() <= 100 && t.values.len() > 50);
        let step = t.values[1] - t.values[0];
        assert!(t.values.windows(2).all(|w| w[1] - w[0] == step));
    }
}
