//! The heights check of a pair: does the overlap hold a second height?
//!
//! Where a building stands in one DSM and not the other (built or pulled down
//! between the epochs) and covers more of a small overlap than the ground
//! does, the fit matches its roof to the ground: tile_299 -> tile_349 of a
//! 50 x 50 grid of 64 m tiles converged 48.9 m off in height with a 3 cm
//! sigma, on 35 % inliers. Both answers are a flat surface fitted to noise,
//! and the pair alone cannot tell which is the ground. So at the answer, the
//! height differences of the moving DSM against the reference are searched
//! for a second cluster beyond ICP's outlier threshold holding at least
//! [`SHARE`] of the overlap ([`second_height`]). When there is one, the pair
//! is `Ambiguous` and the two heights' spread joins its covariance (an equal
//! mixture of the two: the gap squared over two in height), so the graph takes
//! the height from the DSM's other pairs. Well-posed pairs have no such
//! cluster and are left as they were.

use nalgebra::{Matrix6, Point3};

use super::backward::inflate;
use super::start::moved_overlap;
use super::{IcpError, IcpResult, IcpStatus, SecondHeight};
use crate::coarse::cost::{bilinear, median_in_place, sample_box, second_height};
use crate::grid::{Grid, Pyramid};

/// A second height holding at least this share of the overlap makes the pair ambiguous.
pub const SHARE: f64 = 0.2;
/// Moving samples of the overlap the check looks at.
const SAMPLES: usize = 4096;
/// The check's level keeps at least this many pixels across the overlap.
const MIN_SIDE_PX: f64 = 64.0;

/// The answer checked for a second height (module docs): unchanged without
/// one, `Ambiguous` with the spread of the two heights in its covariance with
/// one. `tau_m` is ICP's outlier threshold at full resolution, `pixel_m` the
/// coarser DSM's full-resolution pixel. Only for converged (or held, or
/// already ambiguous) answers with information.
pub(super) fn check_heights<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    mut result: IcpResult,
    tau_m: f64,
    pixel_m: f64,
) -> Result<IcpResult, IcpError> {
    let converged = result.status.is_converged_or_held() || result.status == IcpStatus::Ambiguous;
    if !converged || result.information.is_none() {
        return Ok(result);
    }
    let Some(found) = find(reference, moving, &result, tau_m, pixel_m)? else {
        return Ok(result);
    };
    tracing::debug!(gap_m = found.gap_m, share = found.share, "a second height");
    let mut extra = Matrix6::zeros();
    extra[(2, 2)] = 0.5 * found.gap_m * found.gap_m;
    let info = result.information.as_mut().expect("checked above");
    inflate(info, &extra);
    result.status = IcpStatus::Ambiguous;
    result.second_height = Some(found);
    Ok(result)
}

/// The coarsest level both DSMs have on which an overlap `side_m` across
/// still spans [`MIN_SIDE_PX`] pixels of `moving`: a changed building is as
/// tall there, and a large overlap is read from a few chunks, not from every one.
fn check_level<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    side_m: f64,
) -> Result<usize, IcpError> {
    let levels = reference.num_levels().min(moving.num_levels());
    for level in (1..levels).rev() {
        let gt = moving
            .open_level(level)
            .map_err(IcpError::Read)?
            .geotransform();
        if side_m / gt.pixel_m() >= MIN_SIDE_PX {
            return Ok(level);
        }
    }
    Ok(0)
}

/// The second height of the overlap at `result`'s transform, if any.
fn find<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    result: &IcpResult,
    tau_m: f64,
    pixel_m: f64,
) -> Result<Option<SecondHeight>, IcpError> {
    // the overlap at the answer's shift (at its centre: rotations are small)
    let centre = Point3::from(nalgebra::Vector3::from(result.centre_m));
    let shift = result.t_ref_moving.transform_point(&centre) - centre;
    let Some(overlap) = moved_overlap(reference, moving, &shift)? else {
        return Ok(None);
    };
    let box_m = [overlap.min_x, overlap.min_y, overlap.max_x, overlap.max_y];
    let level = check_level(reference, moving, overlap.width().min(overlap.height()))?;
    let mut mov = moving.open_level(level).map_err(IcpError::Read)?;
    let pixel_m = pixel_m.max(mov.geotransform().pixel_m());
    let samples = sample_box(&mut mov, &box_m, SAMPLES);
    if let Some(e) = mov.take_error() {
        return Err(IcpError::Read(e));
    }
    let mut refg = reference.open_level(level).map_err(IcpError::Read)?;
    let dh: Vec<f64> = (samples.iter())
        .map(|s| {
            let p = result
                .t_ref_moving
                .transform_point(&Point3::new(s.x_m, s.y_m, s.h_m));
            bilinear(&mut refg, p.x, p.y) - p.z
        })
        .filter(|d| d.is_finite())
        .collect();
    if let Some(e) = refg.take_error() {
        return Err(IcpError::Read(e));
    }
    // the answer's own height is 0: the spread of the differences it explains
    let mut near: Vec<f64> = (dh.iter())
        .filter(|d| d.abs() <= tau_m)
        .map(|d| d.abs())
        .collect();
    if near.len() < 16 {
        return Ok(None);
    }
    let nmad_m = 1.4826 * median_in_place(&mut near);
    let width_m = (3.0 * nmad_m).max(pixel_m);
    Ok(
        second_height(&dh, 0.0, tau_m, width_m, SHARE).map(|(gap_m, count)| SecondHeight {
            gap_m,
            share: count as f64 / dh.len() as f64,
        }),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::GeoTransform;
    use crate::grid::{MemGrid, MemPyramid};
    use nalgebra::{Isometry3, Translation3, Vector3, Vector6};

    /// 150 m of gentle ground at 180-183 m; with `roof`, a flat roof at 220 m
    /// over the west 60 %.
    fn grid(roof: bool) -> MemGrid {
        let gt = GeoTransform::north_up(500_000.0, 4_800_150.0, 0.5, 0.5);
        MemGrid::from_fn(300, 300, gt, |c, r| {
            let ground = 180.0 + 0.01 * c as f32 + 0.3 * (r as f32 / 9.0).sin();
            if roof && c < 180 {
                ground.max(220.0)
            } else {
                ground
            }
        })
    }

    fn tile(roof: bool) -> MemPyramid {
        MemPyramid::build(grid(roof), 16)
    }

    /// A converged answer `dz` metres up with a 1 cm height sigma.
    fn answer(dz: f64) -> IcpResult {
        IcpResult::with_diagonal(
            Isometry3::from_parts(Translation3::new(0.0, 0.0, dz), Default::default()),
            Vector3::new(500_075.0, 4_800_075.0, 180.0),
            Vector6::new(0.05, 0.05, 0.01, 1e-4, 1e-4, 1e-4),
            75.0,
        )
    }

    /// The roof matched to the ground (40 m down) leaves the ground under the
    /// other 40 % a second height: ambiguous, with a height sigma covering it.
    /// Matched ground to ground, the roof is the second height just the same;
    /// without the roof there is none and the answer is untouched.
    #[test]
    fn a_changed_roof_over_most_of_the_overlap_makes_the_height_ambiguous() {
        let (reference, moving) = (tile(false), tile(true));
        let wrong = check_heights(&reference, &moving, answer(-40.0), 10.0, 0.5).unwrap();
        assert_eq!(wrong.status, IcpStatus::Ambiguous);
        let found = wrong.second_height.expect("the ground");
        assert!((found.gap_m - 39.0).abs() < 1.5, "{found:?}");
        assert!((found.share - 0.4).abs() < 0.05, "{found:?}");
        let sigma_z = wrong.information.as_ref().unwrap().sigma[2].unwrap();
        assert!(sigma_z > 40.0 / 3.0, "the truth within 3 sigma: {sigma_z}");

        let right = check_heights(&reference, &moving, answer(0.0), 10.0, 0.5).unwrap();
        assert_eq!(right.status, IcpStatus::Ambiguous);
        assert!((right.second_height.unwrap().gap_m + 39.0).abs() < 1.5);

        // a reference with one level only: the check stays on the levels both have
        let flat = MemPyramid::build(grid(false), 1000);
        assert_eq!(flat.num_levels(), 1);
        let one = check_heights(&flat, &moving, answer(-40.0), 10.0, 0.5).unwrap();
        let gap = one.second_height.expect("the ground, on level 0").gap_m;
        assert!((gap - 39.0).abs() < 1.5, "{gap}");

        let plain = check_heights(&reference, &tile(false), answer(0.0), 10.0, 0.5).unwrap();
        assert_eq!(plain.status, IcpStatus::Converged);
        assert_eq!(plain.second_height, None);
        let before = answer(0.0).information.unwrap().covariance_6x6;
        assert_eq!(plain.information.unwrap().covariance_6x6, before);
    }
}
