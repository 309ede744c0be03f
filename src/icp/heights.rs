//! The heights check of a pair: does the overlap hold a second height?
//!
//! Where a building stands in one DSM and not the other (built or pulled down
//! between the epochs) and covers more of a small overlap than the ground
//! does, the fit matches its roof to the ground: tile_299 -> tile_349 of a
//! 50 x 50 grid of 64 m tiles converged 48.9 m off in height with a 3 cm
//! sigma, on 35 % inliers. Both answers are a flat surface fitted to noise,
//! and the pair alone cannot tell which is the ground. So at the answer, the
//! height differences of the moving DSM against the reference are searched
//! for a second cluster the fit treated as outliers (farther from its height
//! than [`SEPARATION_NMAD`] times the spread of its own, where Tukey's weight
//! is zero) holding at least [`SHARE`] of the overlap ([`second_height`]): a
//! 4.5 m platform over 70 % of a 64 m tile's overlap held tile_327 -> tile_328
//! 3 m off in height at 5 cm. When there is one, the pair is `Ambiguous` and
//! the two heights' spread joins its covariance (an equal mixture of the two:
//! the gap squared over two in height), so the graph takes the height from
//! the DSM's other pairs. Well-posed pairs have no such cluster and are left
//! as they were.
//!
//! A fit on a roof can also slide off the rest of the overlap: tile_2211 ->
//! tile_2261 slid 21 m along its 19 m strip onto the roof and its overlap
//! there was all roof, 36 m off at 16 cm. So an answer that moved the DSM
//! horizontally is also checked where the DSM was georeferenced (the answer's
//! height and rotation, no horizontal shift); when the overlap there holds
//! both the answer's height and a second one, the slide joins the covariance
//! as well (the mixture of the two places).

use nalgebra::{Isometry3, Matrix6, Point3, Translation3, Vector3};

use super::backward::inflate;
use super::start::moved_overlap;
use super::{IcpError, IcpResult, IcpStatus, SecondHeight};
use crate::coarse::cost::{bilinear, median_in_place, sample_box, second_height};
use crate::grid::{Grid, Pyramid};

/// A second height holding at least this share of the overlap makes the pair ambiguous.
pub const SHARE: f64 = 0.2;
/// A second height lies farther than this many NMADs of the answer's own
/// height differences from it (Tukey's cut-off, 4.685 sigma, and the two
/// clusters' half-widths), two pixels and [`MIN_SEPARATION_M`].
pub const SEPARATION_NMAD: f64 = 6.0;
/// A second height lies at least this far from the answer's: on coarse check
/// levels the noise averages out and 6 NMAD can be decimetres, where a fifth
/// of a 1 km overlap a metre higher is change (a field, a surface), not the
/// ground (the 4 x 4 grid of 1 km tiles flagged a right pair 1 m apart).
pub const MIN_SEPARATION_M: f64 = 2.0;
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
    let centre = Point3::from(Vector3::from(result.centre_m));
    let shift = result.t_ref_moving.transform_point(&centre) - centre;
    let slide = Vector3::new(shift.x, shift.y, 0.0);
    let mut found = find(
        reference,
        moving,
        &result.t_ref_moving,
        &centre,
        tau_m,
        pixel_m,
    )?
    .map(|(h, _)| h);
    if found.is_none() && slide.norm() > 2.0 * pixel_m {
        let unslid = Translation3::from(-slide) * result.t_ref_moving;
        found = find(reference, moving, &unslid, &centre, tau_m, pixel_m)?
            .filter(|(_, own)| *own >= SHARE)
            .map(|(h, _)| SecondHeight {
                slide_m: slide.norm(),
                ..h
            });
    }
    let Some(found) = found else {
        return Ok(result);
    };
    tracing::debug!(
        gap_m = found.gap_m,
        share = found.share,
        slide_m = found.slide_m,
        "a second height"
    );
    let mut extra = Matrix6::zeros();
    extra[(2, 2)] = 0.5 * found.gap_m * found.gap_m;
    if found.slide_m > 0.0 {
        let xy = 0.5 * slide.xy() * slide.xy().transpose();
        extra.fixed_view_mut::<2, 2>(0, 0).copy_from(&xy);
    }
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

/// The second height of the overlap with the moving DSM placed by
/// `t_ref_moving` (fitted about `centre`), if any, and the share of the
/// overlap at the transform's own height.
fn find<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    t_ref_moving: &Isometry3<f64>,
    centre: &Point3<f64>,
    tau_m: f64,
    pixel_m: f64,
) -> Result<Option<(SecondHeight, f64)>, IcpError> {
    // the overlap at the transform's shift (at the fit's centre: rotations are small)
    let shift = t_ref_moving.transform_point(centre) - centre;
    let Some(overlap) = moved_overlap(reference, moving, &Vector3::new(shift.x, shift.y, 0.0))?
    else {
        return Ok(None);
    };
    let box_m = [overlap.min_x, overlap.min_y, overlap.max_x, overlap.max_y];
    let level = check_level(reference, moving, overlap.width().min(overlap.height()))?;
    let mut mov = moving.open_level(level).map_err(IcpError::Read)?;
    let level_pixel_m = pixel_m.max(mov.geotransform().pixel_m());
    let samples = sample_box(&mut mov, &box_m, SAMPLES);
    if let Some(e) = mov.take_error() {
        return Err(IcpError::Read(e));
    }
    let mut refg = reference.open_level(level).map_err(IcpError::Read)?;
    let dh: Vec<f64> = (samples.iter())
        .map(|s| {
            let p = t_ref_moving.transform_point(&Point3::new(s.x_m, s.y_m, s.h_m));
            bilinear(&mut refg, p.x, p.y) - p.z
        })
        .filter(|d| d.is_finite())
        .collect();
    if let Some(e) = refg.take_error() {
        return Err(IcpError::Read(e));
    }
    // the transform's own height is 0: the spread of the differences it explains
    let mut near: Vec<f64> = (dh.iter())
        .filter(|d| d.abs() <= tau_m)
        .map(|d| d.abs())
        .collect();
    if near.len() < 16 {
        return Ok(None);
    }
    // a second cluster within tau widens that spread: narrow it to the
    // transform's own cluster (differences within 3 NMAD), twice
    let mut nmad_m = 1.4826 * median_in_place(&mut near);
    for _ in 0..2 {
        near.retain(|d| *d <= 3.0 * nmad_m);
        if near.len() < 16 {
            return Ok(None);
        }
        nmad_m = 1.4826 * median_in_place(&mut near);
    }
    let width_m = (3.0 * nmad_m).max(level_pixel_m);
    let separation_m = (SEPARATION_NMAD * nmad_m)
        .max(2.0 * pixel_m)
        .max(MIN_SEPARATION_M)
        .min(tau_m);
    let own = dh.iter().filter(|d| d.abs() <= width_m).count() as f64 / dh.len() as f64;
    Ok(
        second_height(&dh, 0.0, separation_m, width_m, SHARE).map(|(gap_m, count)| {
            let share = count as f64 / dh.len() as f64;
            (
                SecondHeight {
                    gap_m,
                    share,
                    slide_m: 0.0,
                },
                own,
            )
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
        raised(if roof { 40.0 } else { 0.0 }, 180, 0.0)
    }

    /// The same ground, `top_m` higher over the west `cols` columns, with
    /// `noise_m` of uniform noise (a fixed hash of the pixel).
    fn raised(top_m: f32, cols: i64, noise_m: f32) -> MemGrid {
        let gt = GeoTransform::north_up(500_000.0, 4_800_150.0, 0.5, 0.5);
        MemGrid::from_fn(300, 300, gt, |c, r| {
            let ground = 180.0 + 0.01 * c as f32 + 0.3 * (r as f32 / 9.0).sin();
            let hash = ((c * 7919 + r * 104_729) % 1000) as f32 / 500.0 - 1.0;
            let top = if c < cols { top_m } else { 0.0 };
            ground + top + noise_m * hash
        })
    }

    fn tile(roof: bool) -> MemPyramid {
        MemPyramid::build(grid(roof), 16)
    }

    /// A converged answer `dz` metres up with a 1 cm height sigma.
    fn answer(dz: f64) -> IcpResult {
        answer_at(0.0, dz)
    }

    /// The same, `dx` metres east.
    fn answer_at(dx: f64, dz: f64) -> IcpResult {
        IcpResult::with_diagonal(
            Isometry3::from_parts(Translation3::new(dx, 0.0, dz), Default::default()),
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

    /// A 3 m platform over 70 % of the overlap, well inside ICP's 10 m outlier
    /// threshold but beyond Tukey's cut-off: the fit on the platform leaves
    /// the ground a second height. The same ground without it has none.
    #[test]
    fn a_platform_within_the_outlier_threshold_is_a_second_height() {
        let reference = MemPyramid::build(raised(0.0, 0, 0.3), 16);
        let moving = MemPyramid::build(raised(3.0, 210, 0.3), 16);
        let on_platform = check_heights(&reference, &moving, answer(-3.0), 10.0, 0.5).unwrap();
        assert_eq!(on_platform.status, IcpStatus::Ambiguous);
        let found = on_platform.second_height.expect("the ground");
        assert!((found.gap_m - 3.0).abs() < 0.3, "{found:?}");
        assert!((found.share - 0.3).abs() < 0.05, "{found:?}");
        assert_eq!(found.slide_m, 0.0);
        let sigma_z = on_platform.information.as_ref().unwrap().sigma[2].unwrap();
        assert!(sigma_z > 3.0 / 3.0, "the truth within 3 sigma: {sigma_z}");

        let plain = MemPyramid::build(raised(0.0, 0, 0.3), 16);
        let right = check_heights(&reference, &plain, answer(0.0), 10.0, 0.5).unwrap();
        assert_eq!(right.status, IcpStatus::Converged);
    }

    /// A fit that slid 60 m west onto the roof sees only roof in its overlap;
    /// where the DSM was georeferenced the overlap holds the roof (60 %) and
    /// the ground (40 %): ambiguous, with the slide and the gap in the sigmas.
    /// A slide of a pixel is not checked there, and ground on ground that slid
    /// is not ambiguous.
    #[test]
    fn an_answer_that_slid_onto_a_roof_is_checked_where_it_was_georeferenced() {
        let (reference, moving) = (tile(true), tile(false));
        let slid = check_heights(&reference, &moving, answer_at(-60.0, 40.0), 10.0, 0.5).unwrap();
        assert_eq!(slid.status, IcpStatus::Ambiguous);
        let found = slid.second_height.expect("the ground where it was");
        assert!((found.gap_m + 40.0).abs() < 1.5, "{found:?}");
        assert!((found.slide_m - 60.0).abs() < 1e-6, "{found:?}");
        let sigma = slid.information.as_ref().unwrap().sigma;
        assert!(sigma[0].unwrap() > 60.0 / 3.0, "{sigma:?}");
        assert!(sigma[2].unwrap() > 40.0 / 3.0, "{sigma:?}");
        assert!(sigma[1].unwrap() < 0.1, "y was not in question: {sigma:?}");

        let near = check_heights(&reference, &moving, answer_at(-0.5, 40.0), 10.0, 0.5).unwrap();
        assert_eq!(
            near.second_height.map(|h| h.slide_m),
            Some(0.0),
            "found at the answer"
        );
        let ground =
            check_heights(&tile(false), &moving, answer_at(-30.0, 0.0), 10.0, 0.5).unwrap();
        assert_eq!(ground.status, IcpStatus::Converged);
    }
}
