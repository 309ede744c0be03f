//! The robust cost of one trial shift: heights of the moving DSM's samples
//! against the reference, bilinearly interpolated at the shifted positions.
//!
//! For a trial horizontal shift (dx, dy), every moving sample (x, y, h) gives
//! dh = H_ref(x + dx, y + dy) - h. The vertical offset of that shift is
//! median(dh), its cost a robust spread of dh around that median (RMS of the
//! residuals clipped at 3 NMAD, NMAD = 1.4826 median |dh - median dh|): it
//! does not depend on the vertical offset at all, and half the overlap may be
//! changed, water or outliers before it breaks.

use crate::grid::Grid;

/// A valid pixel of the moving DSM: centre in CRS metres, height in metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub x_m: f64,
    pub y_m: f64,
    pub h_m: f64,
}

/// What one trial shift scores.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShiftScore {
    /// Samples with a valid reference height under the shifted position.
    pub support: usize,
    /// median(H_ref - h): the vertical offset at this shift (ref minus moving).
    pub dz_m: f64,
    /// NMAD of dh: the spread of the inliers.
    pub nmad_m: f64,
    /// The cost: RMS of dh - median(dh), each clipped at 3 NMAD (a truncated
    /// quadratic: unlike the NMAD alone it grows with the share of pixels
    /// pushed off their surface, such as walls at a one-pixel error). Infinite
    /// when the support is too small.
    pub cost_m: f64,
}

impl ShiftScore {
    pub const EMPTY: ShiftScore = ShiftScore {
        support: 0,
        dz_m: f64::NAN,
        nmad_m: f64::INFINITY,
        cost_m: f64::INFINITY,
    };
}

/// Reference height at a CRS point, bilinear between the four surrounding
/// pixel centres; NaN when any of them is no-data or outside the raster.
#[inline]
pub fn bilinear<G: Grid + ?Sized>(grid: &mut G, x_m: f64, y_m: f64) -> f64 {
    let (c, r) = grid.geotransform().world_to_pixel(x_m, y_m);
    let (c, r) = (c - 0.5, r - 0.5);
    let (c0, r0) = (c.floor(), r.floor());
    let (u, v) = (c - c0, r - r0);
    let (c0, r0) = (c0 as i64, r0 as i64);
    let h00 = grid.get(c0, r0) as f64;
    let h10 = grid.get(c0 + 1, r0) as f64;
    let h01 = grid.get(c0, r0 + 1) as f64;
    let h11 = grid.get(c0 + 1, r0 + 1) as f64;
    let top = h00 * (1.0 - u) + h10 * u;
    let bottom = h01 * (1.0 - u) + h11 * u;
    top * (1.0 - v) + bottom * v
}

/// Median of a slice (reordered in place); NaN when empty.
pub fn median_in_place(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// Scores the shift (dx, dy) in metres; `scratch` is reused between calls.
/// Shifts with fewer than `min_support` matched samples cost infinity.
pub fn score_shift<G: Grid + ?Sized>(
    reference: &mut G,
    samples: &[Sample],
    shift_xy_m: [f64; 2],
    min_support: usize,
    scratch: &mut Vec<f64>,
) -> ShiftScore {
    scratch.clear();
    for s in samples {
        let h = bilinear(reference, s.x_m + shift_xy_m[0], s.y_m + shift_xy_m[1]);
        if h.is_finite() {
            scratch.push(h - s.h_m);
        }
    }
    score_residuals(scratch, min_support)
}

/// The score of the height differences H_ref - h in `residuals` (reordered
/// and overwritten): infinite cost below `min_support` of them.
pub fn score_residuals(residuals: &mut [f64], min_support: usize) -> ShiftScore {
    let support = residuals.len();
    if support < min_support.max(3) {
        return ShiftScore {
            support,
            ..ShiftScore::EMPTY
        };
    }
    let dz_m = median_in_place(residuals);
    for d in residuals.iter_mut() {
        *d = (*d - dz_m).abs();
    }
    let nmad_m = 1.4826 * median_in_place(residuals);
    let clip_m = (3.0 * nmad_m).max(1e-3);
    let sum_sq: f64 = residuals.iter().map(|r| r.min(clip_m).powi(2)).sum();
    ShiftScore {
        support,
        dz_m,
        nmad_m,
        cost_m: (sum_sq / support as f64).sqrt(),
    }
}

/// A second height the overlap agrees on: the densest cluster of the height
/// differences `dh` (H_ref - h, any order) farther than `separation_m` from
/// `dz_m` (a fit's own height), when it holds at least `min_share` of them. Each
/// cluster is a window of `2 width_m`; the answer is the median of the best
/// and how many differences it holds.
///
/// A changed building covering more of a small overlap than the ground is
/// the median's height; the ground is then this second one (`icp::heights`).
pub fn second_height(
    dh: &[f64],
    dz_m: f64,
    separation_m: f64,
    width_m: f64,
    min_share: f64,
) -> Option<(f64, usize)> {
    let mut far: Vec<f64> = (dh.iter().copied())
        .filter(|d| d.is_finite() && (d - dz_m).abs() > separation_m)
        .collect();
    far.sort_by(f64::total_cmp);
    let mut best: Option<(usize, usize)> = None;
    let mut start = 0;
    for end in 0..far.len() {
        while far[end] - far[start] > 2.0 * width_m {
            start += 1;
        }
        if best.is_none_or(|(s, e)| end - start > e - s) {
            best = Some((start, end));
        }
    }
    let (s, e) = best?;
    let count = e - s + 1;
    let support = dh.iter().filter(|d| d.is_finite()).count();
    (count as f64 >= min_share * support as f64).then(|| (far[s + count / 2], count))
}

/// Valid pixel centres of `grid` inside `box_m` ([min_x, min_y, max_x, max_y]),
/// on a regular stride chosen so that about `target` samples are taken.
pub fn sample_box<G: Grid + ?Sized>(grid: &mut G, box_m: &[f64; 4], target: usize) -> Vec<Sample> {
    let gt = grid.geotransform();
    let (ca, ra) = gt.world_to_pixel(box_m[0], box_m[3]);
    let (cb, rb) = gt.world_to_pixel(box_m[2], box_m[1]);
    let c0 = ca.min(cb).floor().max(0.0) as i64;
    let c1 = (ca.max(cb).ceil() as i64).min(grid.width());
    let r0 = ra.min(rb).floor().max(0.0) as i64;
    let r1 = (ra.max(rb).ceil() as i64).min(grid.height());
    if c1 <= c0 || r1 <= r0 {
        return Vec::new();
    }
    let area = ((c1 - c0) * (r1 - r0)) as f64;
    let stride = ((area / target.max(1) as f64).sqrt().floor() as i64).max(1);
    let mut out = Vec::new();
    // Start half a stride in, so the lattice is centred in the box.
    let mut row = r0 + stride / 2;
    while row < r1 {
        let mut col = c0 + stride / 2;
        while col < c1 {
            let h = grid.get(col, row);
            if h.is_finite() {
                let (x, y) = gt.pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
                out.push(Sample {
                    x_m: x,
                    y_m: y,
                    h_m: h as f64,
                });
            }
            col += stride;
        }
        row += stride;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::GeoTransform;
    use crate::grid::MemGrid;

    fn plane_grid(offset_m: f32) -> MemGrid {
        let gt = GeoTransform::north_up(1000.0, 2000.0, 2.0, 2.0);
        MemGrid::from_fn(50, 40, gt, |c, r| {
            0.3 * c as f32 + 0.1 * (r * r) as f32 + offset_m
        })
    }

    #[test]
    fn bilinear_is_exact_on_a_plane_and_nan_outside() {
        let gt = GeoTransform::north_up(0.0, 100.0, 1.0, 1.0);
        let mut g = MemGrid::from_fn(10, 10, gt, |c, r| (2 * c + 3 * r) as f32);
        // Pixel centre (c + 0.5, r + 0.5) holds 2c + 3r.
        let h = bilinear(&mut g, 3.75, 100.0 - 4.25);
        assert!((h - (2.0 * 3.25 + 3.0 * 3.75)).abs() < 1e-9, "{h}");
        assert!(bilinear(&mut g, -3.0, 50.0).is_nan());
    }

    /// A roof over 55 % of the overlap takes the median; the ground under the
    /// other 45 % is the second height. A spread of outliers is none, nor is
    /// a cluster below the share or within the separation.
    #[test]
    fn a_second_cluster_of_height_differences_is_a_second_height() {
        let noise = |i: usize| 0.1 * ((i * 7919 % 13) as f64 - 6.0) / 6.0;
        let mut dh: Vec<f64> = (0..550).map(|i| -48.5 + noise(i)).collect();
        dh.extend((0..450).map(|i| 0.3 + noise(i)));
        let dz = -48.5;
        let (second, count) = second_height(&dh, dz, 10.0, 0.5, 0.2).expect("the ground");
        assert!((second - 0.3).abs() < 0.11, "{second}");
        assert_eq!(count, 450);
        assert_eq!(second_height(&dh, dz, 60.0, 0.5, 0.2), None);
        assert_eq!(second_height(&dh, dz, 10.0, 0.5, 0.5), None);
        // the same share spread over 40 m is no height
        let mut spread: Vec<f64> = (0..550).map(noise).collect();
        spread.extend((0..450).map(|i| 15.0 + 40.0 * i as f64 / 450.0));
        assert_eq!(second_height(&spread, 0.0, 10.0, 0.5, 0.2), None);
    }

    /// The true shift costs nothing whatever the vertical offset; another costs more.
    #[test]
    fn true_shift_scores_zero_spread_and_the_offset() {
        let mut reference = plane_grid(0.0);
        let mut moving = plane_grid(-150.0);
        // The moving grid is the reference moved by (+4 m, -2 m): shift it back.
        moving.geotransform.0[0] += 4.0;
        moving.geotransform.0[3] -= 2.0;
        let b = [1010.0, 1930.0, 1080.0, 1990.0];
        let samples = sample_box(&mut moving, &b, 400);
        assert!(samples.len() > 300, "{}", samples.len());
        let mut scratch = Vec::new();
        let at_truth = score_shift(&mut reference, &samples, [-4.0, 2.0], 10, &mut scratch);
        assert!(at_truth.cost_m < 1e-3, "{at_truth:?}");
        assert!((at_truth.dz_m - 150.0).abs() < 1e-3, "{at_truth:?}");
        let off = score_shift(&mut reference, &samples, [0.0, 0.0], 10, &mut scratch);
        assert!(off.cost_m > 0.2, "{off:?}");
        let starved = score_shift(&mut reference, &samples, [0.0, 0.0], 100_000, &mut scratch);
        assert_eq!(starved.cost_m, f64::INFINITY);
    }
}
