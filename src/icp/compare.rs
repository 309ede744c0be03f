//! The starts' places compared on the same samples at the same scale.
//!
//! Each start's robust cost is the spread of its own final matches, so a place
//! that slides a narrow overlap half off the reference is judged on the half
//! that still lands, and on a strip of ground noisier at its edges than in
//! its middle that half can fit better than the whole does at the truth:
//! tile_1451 -> tile_1450 of the 50 x 50 grid of 64 m tiles ended 13.3 m east
//! at a spread of 0.40 m on 29 % of the overlap while the start at the
//! georeferenced position reached the truth at 0.53 m on all of it, and the
//! pair reported x to 0.29 m, 55 sigma off. Nor can the places be compared
//! on only the samples all of them land: that can be a corner of the overlap
//! where one DSM has a building the other lacks (tile_310 -> tile_309 of the
//! 20 x 20 grid of 128 m tiles in the lidar-max rendering: a third of the
//! shared corner 4 m off at the truth, and a place 28 m away fitting it better).
//!
//! So before the choice, the results that converged (or held axes) are
//! re-scored as hypotheses are in robust model selection (a truncated
//! quadratic, MSAC): on one lattice of moving samples over every place's
//! overlap, each sample costs its height difference from the place's own
//! median, H_ref(T p) - (T p).z - median, clipped at one common bound (3 x the
//! smallest NMAD of the places), and the bound itself where the place puts it
//! off the reference. The cost is the RMS of that over the samples at least
//! one place lands: a place is paid for what it explains, wherever that is.

use nalgebra::{Point3, Vector3};

use super::start::moved_overlap;
use super::{IcpError, IcpResult};
use crate::coarse::cost::{bilinear, median_in_place, sample_box};
use crate::geo::Bounds;
use crate::grid::{Grid, Pyramid};

/// Moving samples over the places' overlaps (a regular lattice).
const SAMPLES: usize = 4096;
/// A place needs this many samples on the reference for its spread to set
/// the common bound, and the places this many samples in all to be compared.
const MIN_SAMPLES: usize = 64;
/// The box of the places' overlaps is read on the finest level where it spans
/// at most this many pixels a side (bounded reads on huge DSMs).
const MAX_SIDE_PX: f64 = 1024.0;

/// Replaces the costs of the converged or held results in `tried` (two or
/// more, in the order of their own costs) by their truncated-quadratic cost
/// over all their places' samples (module docs), the best of the results
/// within `pixel_m` of each other for each. Leaves them as they are when
/// there are too few samples.
pub(super) fn on_common_samples<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    tried: &mut [(IcpResult, f64)],
    pixel_m: f64,
) -> Result<(), IcpError> {
    let read = IcpError::Read;
    let eligible: Vec<usize> = (0..tried.len())
        .filter(|&k| tried[k].0.status.is_converged_or_held())
        .collect();
    if eligible.len() < 2 {
        return Ok(());
    }
    let mut union: Option<Bounds> = None;
    for &k in &eligible {
        if let Some(landed) = moved_overlap(reference, moving, &shift_at_centre(&tried[k].0))? {
            union = Some(match union {
                None => landed,
                Some(b) => b.union(&landed),
            });
        }
    }
    let Some(union) = union else {
        return Ok(());
    };
    let level = read_level(reference, moving, &union)?;
    let mut mov = moving.open_level(level).map_err(read)?;
    let box_m = [union.min_x, union.min_y, union.max_x, union.max_y];
    let samples = sample_box(&mut mov, &box_m, SAMPLES);
    if let Some(e) = mov.take_error() {
        return Err(read(e));
    }
    let mut refg = reference.open_level(level).map_err(read)?;
    // each place's |dh - median dh| per sample (NaN off the reference) and NMAD
    let mut deviations: Vec<Vec<f64>> = Vec::with_capacity(eligible.len());
    let mut nmads: Vec<f64> = Vec::with_capacity(eligible.len());
    for &k in &eligible {
        let t = &tried[k].0.t_ref_moving;
        let mut dh: Vec<f64> = (samples.iter())
            .map(|s| {
                let p = t.transform_point(&Point3::new(s.x_m, s.y_m, s.h_m));
                bilinear(&mut refg, p.x, p.y) - p.z
            })
            .collect();
        let mut valid: Vec<f64> = dh.iter().copied().filter(|d| d.is_finite()).collect();
        let median = median_in_place(&mut valid);
        dh.iter_mut().for_each(|d| *d = (*d - median).abs());
        let mut valid: Vec<f64> = dh.iter().copied().filter(|d| d.is_finite()).collect();
        if valid.len() >= MIN_SAMPLES {
            nmads.push(1.4826 * median_in_place(&mut valid));
        }
        deviations.push(dh);
    }
    if let Some(e) = refg.take_error() {
        return Err(read(e));
    }
    let landed: Vec<usize> = (0..samples.len())
        .filter(|&i| deviations.iter().any(|dev| dev[i].is_finite()))
        .collect();
    let Some(smallest) = nmads.into_iter().min_by(f64::total_cmp) else {
        return Ok(());
    };
    if landed.len() < MIN_SAMPLES {
        return Ok(());
    }
    let bound = (3.0 * smallest).max(1e-3);
    let costs: Vec<f64> = (deviations.iter())
        .map(|dev| {
            let sum_sq: f64 = (landed.iter())
                .map(|&i| {
                    if dev[i].is_finite() {
                        dev[i].min(bound)
                    } else {
                        bound
                    }
                })
                .map(|r| r * r)
                .sum();
            (sum_sq / landed.len() as f64).sqrt()
        })
        .collect();
    // Results at one place share its best cost: between them the own costs
    // decide (`tried` is ordered by them, and the choice's sort is stable).
    let shifts: Vec<Vector3<f64>> = eligible
        .iter()
        .map(|&k| shift_at_centre(&tried[k].0))
        .collect();
    for (a, &k) in eligible.iter().enumerate() {
        let place = (0..eligible.len())
            .filter(|&b| (shifts[a] - shifts[b]).amax() <= pixel_m)
            .map(|b| costs[b])
            .fold(f64::INFINITY, f64::min);
        tracing::debug!(
            own = tried[k].1,
            common = costs[a],
            place,
            bound,
            samples = landed.len(),
            level,
            "place compared"
        );
        tried[k].1 = place;
    }
    Ok(())
}

/// Where a result moves the centre of its fit, metres (moving -> reference).
fn shift_at_centre(r: &IcpResult) -> Vector3<f64> {
    let c = Point3::from(Vector3::from(r.centre_m));
    r.t_ref_moving.transform_point(&c) - c
}

/// The finest level of both pyramids on which `b` spans at most
/// [`MAX_SIDE_PX`] pixels a side.
fn read_level<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    b: &Bounds,
) -> Result<usize, IcpError> {
    let levels = reference.num_levels().min(moving.num_levels()).max(1);
    let side_m = b.width().max(b.height());
    for l in 0..levels {
        let g = reference
            .open_level(l)
            .map_err(IcpError::Read)?
            .geotransform();
        let h = moving.open_level(l).map_err(IcpError::Read)?.geotransform();
        if side_m / g.pixel_m().max(h.pixel_m()) <= MAX_SIDE_PX {
            return Ok(l);
        }
    }
    Ok(levels - 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coarse::cost::score_shift;
    use crate::geo::GeoTransform;
    use crate::grid::{MemGrid, MemPyramid};
    use crate::icp::IcpStatus;
    use nalgebra::{Isometry3, Translation3};
    use std::f64::consts::PI;

    /// Ground that repeats every 12 m along x, with 0.1 m of noise of its own
    /// in each DSM.
    fn ground(x: f64, y: f64, seed: u64) -> f32 {
        let k = (x * 7.0 + y * 13.0) as u64 ^ seed;
        let noise = 0.1 * ((k.wrapping_mul(2_654_435_761) % 1000) as f64 / 500.0 - 1.0);
        (3.0 * (2.0 * PI * x / 12.0).sin() * (y / 7.1).cos() + noise) as f32
    }

    /// 100 m squares of 1 m pixels, `left` metres east; `building` raises a
    /// box (x0, x1, y0, y1) by 5 m in this DSM only.
    fn tile(left: f64, seed: u64, building: Option<[f64; 4]>) -> MemPyramid {
        let gt = GeoTransform::north_up(left, 100.0, 1.0, 1.0);
        let grid = MemGrid::from_fn(100, 100, gt, |c, r| {
            let (x, y) = (left + c as f64 + 0.5, 100.0 - r as f64 - 0.5);
            let raised = building.is_some_and(|b| x > b[0] && x < b[1] && y > b[2] && y < b[3]);
            ground(x, y, seed) + if raised { 5.0 } else { 0.0 }
        });
        MemPyramid::build(grid, 32)
    }

    fn place(dx: f64, status: IcpStatus, cost: f64) -> (IcpResult, f64) {
        let t = Isometry3::from_parts(Translation3::new(dx, 0.0, 0.0), Default::default());
        let mut r = IcpResult::converged_at(t, [85.0, 50.0, 0.0]);
        r.status = status;
        (r, cost)
    }

    /// The moving tile overlaps the reference in a 30 m strip and belongs
    /// where it is. A place one period (12 m) east keeps 18 m of the strip and
    /// came with the lower own cost. Where both places land, the reference
    /// has a building the moving DSM lacks, so on those samples alone the
    /// other place fits better; over the whole strip the truth explains more.
    /// A result that did not converge keeps its cost; two within a pixel of
    /// each other are one place and share its best cost.
    #[test]
    fn places_are_paid_for_what_they_explain() {
        let reference = tile(0.0, 1, Some([72.0, 84.0, 20.0, 80.0]));
        let moving = tile(70.0, 2, None);
        let mut tried = vec![
            place(0.0, IcpStatus::Converged, 0.5),
            place(12.0, IcpStatus::Converged, 0.3),
            place(5.0, IcpStatus::Diverged, 0.1),
            place(0.4, IcpStatus::Converged, 0.45),
        ];
        // on the samples both places land, the other place fits better
        let mut mov = moving.open_level(0).unwrap();
        let shared = sample_box(&mut mov, &[70.0, 0.0, 88.0, 100.0], 4096);
        let mut refg = reference.open_level(0).unwrap();
        let mut scratch = Vec::new();
        let mut on_shared =
            |dx| score_shift(&mut refg, &shared, [dx, 0.0], 16, &mut scratch).cost_m;
        let (truth, other) = (on_shared(0.0), on_shared(12.0));
        assert!(other < truth, "{truth} {other}");

        on_common_samples(&reference, &moving, &mut tried, 1.0).unwrap();
        let (truth, other) = (tried[0].1, tried[1].1);
        assert!(
            truth < 0.8 * other,
            "the truth explains more: {truth} {other}"
        );
        assert_eq!(tried[2].1, 0.1, "not compared");
        assert_eq!(tried[3].1, truth, "one place, one cost");
    }

    /// A single converged result is not compared.
    #[test]
    fn a_single_place_keeps_its_own_cost() {
        let (reference, moving) = (tile(0.0, 1, None), tile(70.0, 2, None));
        let mut one = vec![
            place(12.0, IcpStatus::Converged, 0.3),
            place(0.0, IcpStatus::MaxIterations, 0.2),
        ];
        on_common_samples(&reference, &moving, &mut one, 1.0).unwrap();
        assert_eq!((one[0].1, one[1].1), (0.3, 0.2));
    }
}
