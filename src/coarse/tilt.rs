//! The plane through one shift's height differences: the vertical offset and
//! the relative tilt of the two DSMs, removed before the spread is measured.
//!
//! Two DSMs differ by a rotation of hundredths of a degree as well as by a
//! translation. Over a strip 128 m long, 0.03 degrees is a ramp of +-3 cm in
//! dh; a translation-only cost would absorb it by shifting the DSM along a
//! slope, and on noise-free data that wrong shift fits better than the truth
//! (0.5-2 m off on the 20 x 20 grid). Fitting dh = offset + tilt . (p - centre)
//! at every shift lets the shift be judged by the relief alone.

use super::cost::median_in_place;

/// Largest relative tilt fitted, metres per metre (0.1 degrees): DSMs are
/// rotated by hundredths of a degree, and a free plane would also absorb the
/// difference a shift makes on curved terrain (a shift turns a quadratic
/// surface into a plane).
pub const MAX_TILT: f64 = 1.745e-3;

/// One sample's height difference at a trial shift: H_ref - h at the sample's
/// position (x, y in CRS metres of the moving DSM).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Residual {
    pub x_m: f64,
    pub y_m: f64,
    pub dh_m: f64,
}

/// dh = offset_m + slope . ((x, y) - centre_m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Plane {
    pub centre_m: [f64; 2],
    /// dh at the centre: the vertical offset (ref minus moving), metres.
    pub offset_m: f64,
    /// d(dh)/dx and d(dh)/dy, metres per metre.
    pub slope: [f64; 2],
}

impl Plane {
    pub fn at(&self, x_m: f64, y_m: f64) -> f64 {
        self.offset_m
            + self.slope[0] * (x_m - self.centre_m[0])
            + self.slope[1] * (y_m - self.centre_m[1])
    }

    /// dh minus the plane at the residual's position.
    pub fn detrended(&self, r: &Residual) -> f64 {
        r.dh_m - self.at(r.x_m, r.y_m)
    }
}

/// The plane of `points` (all finite): the median level, a least-squares plane
/// through the points within 3 NMAD of it (at least 1 mm) with its tilt
/// shortened to at most [`MAX_TILT`], then the offset that leaves a median of
/// zero. Level (no tilt) when the inliers do not span a plane. `scratch` is
/// reused between calls.
pub fn fit_plane(points: &[Residual], scratch: &mut Vec<f64>) -> Plane {
    let n = points.len().max(1) as f64;
    let centre_m = [
        points.iter().map(|p| p.x_m).sum::<f64>() / n,
        points.iter().map(|p| p.y_m).sum::<f64>() / n,
    ];
    scratch.clear();
    scratch.extend(points.iter().map(|p| p.dh_m));
    let level_m = median_in_place(scratch);
    if !super::switch::get().plane {
        return Plane {
            centre_m,
            offset_m: level_m,
            slope: [0.0, 0.0],
        };
    }
    for d in scratch.iter_mut() {
        *d = (*d - level_m).abs();
    }
    let gate_m = (3.0 * 1.4826 * median_in_place(scratch)).max(1e-3);
    // normal equations of (1, x, y) -> dh - level over the inliers
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut b = nalgebra::Vector3::<f64>::zeros();
    for p in points {
        let d = p.dh_m - level_m;
        if d.abs() <= gate_m {
            let row = nalgebra::Vector3::new(1.0, p.x_m - centre_m[0], p.y_m - centre_m[1]);
            a += row * row.transpose();
            b += row * d;
        }
    }
    let mut plane = Plane {
        centre_m,
        offset_m: level_m,
        slope: [0.0, 0.0],
    };
    if let Some(c) = a.cholesky() {
        let c = c.solve(&b);
        let norm = c[1].hypot(c[2]);
        if norm.is_finite() && norm > 0.0 {
            let shorten = (MAX_TILT / norm).min(1.0);
            plane.slope = [c[1] * shorten, c[2] * shorten];
        }
    }
    scratch.clear();
    scratch.extend(points.iter().map(|p| plane.detrended(p)));
    plane.offset_m += median_in_place(scratch);
    plane
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_tilted_offset_despite_outliers_and_bounds_the_tilt() {
        let truth = Plane {
            centre_m: [0.0, 0.0],
            offset_m: 1.5,
            slope: [4e-4, -2e-4],
        };
        let points: Vec<Residual> = (0..400)
            .map(|k| {
                let (x, y) = (
                    500_000.0 + (k % 20) as f64 * 3.0,
                    4_800_000.0 + (k / 20) as f64 * 3.0,
                );
                let spike = if k % 17 == 0 { 25.0 } else { 0.0 };
                Residual {
                    x_m: x,
                    y_m: y,
                    dh_m: truth.at(x - 500_028.5, y - 4_800_028.5) + spike,
                }
            })
            .collect();
        let plane = fit_plane(&points, &mut Vec::new());
        assert!((plane.slope[0] - 4e-4).abs() < 1e-9, "{plane:?}");
        assert!((plane.slope[1] + 2e-4).abs() < 1e-9, "{plane:?}");
        assert!((plane.offset_m - 1.5).abs() < 1e-6, "{plane:?}");
        let clean = points.iter().filter(|p| p.dh_m < 20.0);
        assert!(clean.map(|p| plane.detrended(p).abs()).all(|r| r < 1e-6));
        // a steep plane (a shift over curved ground) keeps most of its ramp
        let steep: Vec<Residual> = points
            .iter()
            .map(|p| Residual {
                dh_m: 0.05 * (p.x_m - 500_000.0),
                ..*p
            })
            .collect();
        let plane = fit_plane(&steep, &mut Vec::new());
        assert!((plane.slope[0] - MAX_TILT).abs() < 1e-9, "{plane:?}");
        assert!(plane.slope[1].abs() < 1e-9, "{plane:?}");
    }

    #[test]
    fn points_on_a_line_give_a_level_plane() {
        let points: Vec<Residual> = (0..50)
            .map(|k| Residual {
                x_m: k as f64,
                y_m: 0.0,
                dh_m: 2.0,
            })
            .collect();
        let plane = fit_plane(&points, &mut Vec::new());
        assert_eq!(plane.slope, [0.0, 0.0]);
        assert!((plane.offset_m - 2.0).abs() < 1e-12);
    }
}
