//! The robust cost of one trial shift: heights of the moving DSM's samples
//! against the reference, bilinearly interpolated at the shifted positions.
//!
//! For a trial horizontal shift (dx, dy), every moving sample (x, y, h) gives
//! dh = H_ref(x + dx, y + dy) - h. The vertical offset and relative tilt of
//! that shift are the robust plane through dh ([`super::tilt`]), its cost a
//! robust spread of dh around that plane (RMS of the residuals clipped at 3
//! NMAD, NMAD = 1.4826 median |dh - plane|): it does not depend on the
//! vertical offset or a small tilt at all, and half the overlap may be
//! changed, water or outliers before it breaks.
//!
//! Where the residuals are clipped is a [`Clip`]: at each shift's own spread
//! (the scan's first pass), or at one height common to every shift compared.
//! Only costs at a common clip compare: on noise-free flat ground the own
//! NMAD is about 0 at every shift, and the shift whose spread happens to be
//! smallest wins whatever its fit.

use super::tilt::fit_plane;
pub use super::tilt::Residual;
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
    /// H_ref - h at the samples' centre, from the plane through dh: the
    /// vertical offset at this shift (ref minus moving).
    pub dz_m: f64,
    /// NMAD of dh about that plane: the spread of the inliers.
    pub nmad_m: f64,
    /// The cost: RMS of dh - median(dh), each clipped at the [`Clip`] (a
    /// truncated quadratic: unlike the NMAD alone it grows with the share of
    /// pixels pushed off their surface, such as walls at a one-pixel error).
    /// Infinite when the support is too small.
    pub cost_m: f64,
}

/// Smallest clip height, metres (noise-free data has an NMAD of about 0).
pub const MIN_CLIP_M: f64 = 1e-3;

/// Where a cost clips the residuals |dh - median(dh)|.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Clip {
    /// At 3 NMAD of the shift's own residuals (at least [`MIN_CLIP_M`]):
    /// finds the minima of a scan, but two shifts' costs do not compare.
    OwnSpread,
    /// At this height (metres), the same for every shift compared.
    Common(f64),
}

impl Clip {
    /// The common clip of a set of shifts whose best spread is `nmad_m`:
    /// 3 NMAD of the best-fitting shift, at least [`MIN_CLIP_M`].
    pub fn at_spread(nmad_m: f64) -> Clip {
        Clip::Common((3.0 * nmad_m).max(MIN_CLIP_M))
    }

    /// The clip height for residuals of spread `nmad_m`.
    pub fn height_m(self, nmad_m: f64) -> f64 {
        match self {
            Clip::OwnSpread => (3.0 * nmad_m).max(MIN_CLIP_M),
            Clip::Common(clip_m) => clip_m,
        }
    }
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

/// Buffers reused between the scores of many shifts.
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    pub points: Vec<Residual>,
    pub values: Vec<f64>,
}

/// Scores the shift (dx, dy) in metres at `clip`. Shifts with fewer than
/// `min_support` matched samples cost infinity.
pub fn score_shift<G: Grid + ?Sized>(
    reference: &mut G,
    samples: &[Sample],
    shift_xy_m: [f64; 2],
    min_support: usize,
    clip: Clip,
    scratch: &mut Scratch,
) -> ShiftScore {
    scratch.points.clear();
    for s in samples {
        let h = bilinear(reference, s.x_m + shift_xy_m[0], s.y_m + shift_xy_m[1]);
        if h.is_finite() {
            scratch.points.push(Residual {
                x_m: s.x_m,
                y_m: s.y_m,
                dh_m: h - s.h_m,
            });
        }
    }
    score_residuals(&scratch.points, min_support, clip, &mut scratch.values)
}

/// The score of the height differences H_ref - h in `points` (all finite) at
/// `clip`, about their plane ([`fit_plane`]): infinite cost below
/// `min_support` of them.
pub fn score_residuals(
    points: &[Residual],
    min_support: usize,
    clip: Clip,
    scratch: &mut Vec<f64>,
) -> ShiftScore {
    let support = points.len();
    if support < min_support.max(3) {
        return ShiftScore {
            support,
            ..ShiftScore::EMPTY
        };
    }
    let plane = fit_plane(points, scratch);
    scratch.clear();
    scratch.extend(points.iter().map(|p| plane.detrended(p).abs()));
    let nmad_m = 1.4826 * median_in_place(scratch);
    let clip_m = clip.height_m(nmad_m);
    let sum_sq: f64 = scratch.iter().map(|r| r.min(clip_m).powi(2)).sum();
    ShiftScore {
        support,
        dz_m: plane.offset_m,
        nmad_m,
        cost_m: (sum_sq / support as f64).sqrt(),
    }
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
        let mut scratch = Scratch::default();
        let own = Clip::OwnSpread;
        let at_truth = score_shift(&mut reference, &samples, [-4.0, 2.0], 10, own, &mut scratch);
        assert!(at_truth.cost_m < 1e-3, "{at_truth:?}");
        assert!((at_truth.dz_m - 150.0).abs() < 1e-3, "{at_truth:?}");
        let off = score_shift(&mut reference, &samples, [0.0, 0.0], 10, own, &mut scratch);
        assert!(off.cost_m > 0.2, "{off:?}");
        let starved = score_shift(
            &mut reference,
            &samples,
            [0.0, 0.0],
            100_000,
            own,
            &mut scratch,
        );
        assert_eq!(starved.cost_m, f64::INFINITY);
    }
}
