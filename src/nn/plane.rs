//! The robust least-squares plane over a pixel window, shared by the grid
//! normal and the surface-below tangent plane.

use nalgebra::Vector3;

use super::frame::PixelFrame;
use super::surface::NORMAL_RADIUS_PX;
use crate::grid::Grid;
use crate::select;

/// A least-squares plane around a pixel: z = z0 + a dx + b dy, with dx, dy in
/// metres from that pixel's centre (y up).
#[derive(Clone, Copy, Debug)]
pub(super) struct Plane {
    pub z0: f64,
    pub a: f64,
    pub b: f64,
    /// RMS height residual of the pixels kept by the fit (roughness).
    pub rms_m: f64,
    /// Variance of the fitted slopes (mean of a's and b's) that the residual
    /// spread implies: how much of the normal's tilt is noise.
    pub slope_var: f64,
}

impl Plane {
    pub fn normal(&self) -> Vector3<f64> {
        Vector3::new(-self.a, -self.b, 1.0).normalize()
    }

    pub fn height_at(&self, dx: f64, dy: f64) -> f64 {
        self.z0 + self.a * dx + self.b * dy
    }
}

/// Robust plane over the (2r+1)^2 window around (col, row), skipping the inner
/// square of Chebyshev radius < `skip_radius_px` (1 = only the centre): a
/// least-squares fit, then a refit without pixels beyond 3 robust sigmas
/// (spikes, the far side of a wall). None with fewer than 6 valid pixels.
pub(super) fn plane_fit<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    col: i64,
    row: i64,
    skip_radius_px: i64,
) -> Option<Plane> {
    let k = NORMAL_RADIUS_PX;
    let mut pts: [(f64, f64, f64); 49] = [(0.0, 0.0, 0.0); 49];
    let mut n = 0;
    for dr in -k..=k {
        for dc in -k..=k {
            if dr.abs().max(dc.abs()) < skip_radius_px {
                continue;
            }
            let h = grid.get(col + dc, row + dr);
            if h.is_nan() {
                continue;
            }
            pts[n] = (
                dc as f64 * frame.gsd_x_m(),
                -(dr as f64) * frame.gsd_y_m(),
                h as f64,
            );
            n += 1;
        }
    }
    let mut keep = [true; 49];
    let first = fit_plane(&pts[..n], &keep[..n])?;
    let mut abs_res = [0.0f64; 49];
    for (i, &(x, y, z)) in pts[..n].iter().enumerate() {
        abs_res[i] = (z - first.height_at(x, y)).abs();
    }
    let mut keys = [0u64; 49];
    for (k, r) in keys.iter_mut().zip(&abs_res[..n]) {
        *k = select::key(*r);
    }
    let median = select::kth_smallest(&mut keys[..n], n / 2);
    let limit = (3.0 * 1.4826 * median).max(0.05);
    let mut dropped = 0;
    for i in 0..n {
        if abs_res[i] > limit {
            keep[i] = false;
            dropped += 1;
        }
    }
    if dropped == 0 {
        return Some(first);
    }
    fit_plane(&pts[..n], &keep[..n])
}

fn fit_plane(pts: &[(f64, f64, f64)], keep: &[bool]) -> Option<Plane> {
    // One pass of moment sums, heights taken from the first point's (the
    // window spans metres, so the sums stay far from cancellation).
    let z_ref = pts.first()?.2;
    let (mut n, mut sx, mut sy, mut sz) = (0.0, 0.0, 0.0, 0.0);
    let (mut sxx, mut syy, mut sxy, mut sxz, mut syz, mut szz) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (&(x, y, z), _) in pts.iter().zip(keep).filter(|(_, &k)| k) {
        let z = z - z_ref;
        n += 1.0;
        sx += x;
        sy += y;
        sz += z;
        sxx += x * x;
        syy += y * y;
        sxy += x * y;
        sxz += x * z;
        syz += y * z;
        szz += z * z;
    }
    if n < 6.0 {
        return None;
    }
    let (mx, my, mz) = (sx / n, sy / n, sz / n);
    // centred moments
    let (cxx, cyy, cxy) = (sxx - n * mx * mx, syy - n * my * my, sxy - n * mx * my);
    let (cxz, cyz, czz) = (sxz - n * mx * mz, syz - n * my * mz, szz - n * mz * mz);
    let det = cxx * cyy - cxy * cxy;
    if det.abs() < 1e-12 {
        return None;
    }
    let a = (cxz * cyy - cyz * cxy) / det;
    let b = (cyz * cxx - cxz * cxy) / det;
    // residual sum of squares of the least-squares plane
    let sum_sq = (czz - a * cxz - b * cyz).max(0.0);
    Some(Plane {
        z0: mz + z_ref - a * mx - b * my,
        a,
        b,
        rms_m: (sum_sq / n).sqrt(),
        // Var(a) = s^2 cyy / det, Var(b) = s^2 cxx / det, s^2 on n - 3 dof.
        slope_var: sum_sq / (n - 3.0) * 0.5 * (cxx + cyy) / det,
    })
}
