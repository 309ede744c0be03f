//! The starts' places compared on the samples they share.
//!
//! Each start's robust cost is the spread of its own final matches, so a place
//! that slides a narrow overlap half off the reference is judged on the half
//! that still lands, and on a strip of ground noisier at its edges than in
//! its middle that half can fit better than the whole does at the truth:
//! tile_1451 -> tile_1450 of the 50 x 50 grid of 64 m tiles ended 13.3 m east
//! at a spread of 0.40 m on 29 % of the overlap while the start at the
//! georeferenced position reached the truth at 0.53 m on all of it, and the
//! pair reported x to 0.29 m, 55 sigma off. On the moving samples that land on
//! the reference at both places the truth fits better (0.50 against 0.65 m).
//!
//! So before the choice, the results that converged (or held axes) are
//! re-scored on one lattice of moving samples that land on the reference at
//! every one of their places: the height difference H_ref(T p) - (T p).z,
//! scored as the global search scores a shift ([`score_residuals`]: the RMS
//! about the median, each clipped at 3 NMAD); results within a pixel of each
//! other are one place and share its best score. Too few shared samples
//! (places that overlap little) leave the own costs as they are.
//!
//! Neither score alone is fair: the shared corner can hold a building one DSM
//! lacks (tile_310 -> tile_309 of the 20 x 20 grid of 128 m tiles in the
//! lidar-max rendering: a third of it 4 m off at the truth, and a place 28 m
//! away fitting it better), and counting samples a place puts off the
//! reference as misfits instead rewards places that slide deeper into the
//! reference (tile_2266 -> tile_2265 of the 64 m grid, 9.9 m off). So the
//! choice ranks by the shared score, and a place that the own costs rank
//! nearly as well or better is a rival ([`super::choice`]): where the two
//! disagree the pair is ambiguous, with the places' spread in its covariance.

use nalgebra::{Point3, Vector3};

use super::start::moved_overlap;
use super::{IcpError, IcpResult};
use crate::coarse::cost::{bilinear, sample_box, score_residuals};
use crate::geo::Bounds;
use crate::grid::{Grid, Pyramid};

/// Moving samples of the shared box (a regular lattice).
const SHARED_SAMPLES: usize = 4096;
/// Below this many shared samples the places are not compared.
const MIN_SHARED: usize = 256;
/// The shared box is read on the finest level where it spans at most this
/// many pixels a side (bounded reads on huge DSMs).
const MAX_SIDE_PX: f64 = 1024.0;

/// Sets the choice costs of the converged or held results in `tried` (two
/// or more; result, choice cost, own cost) to their robust spread on the
/// samples all their places share, the best of the results within `pixel_m`
/// of each other for each (module docs). Leaves them as they are when the
/// places share too little.
pub(super) fn on_shared_samples<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    tried: &mut [(IcpResult, f64, f64)],
    pixel_m: f64,
) -> Result<(), IcpError> {
    let eligible: Vec<usize> = (0..tried.len())
        .filter(|&k| tried[k].0.status.is_converged_or_held())
        .collect();
    if eligible.len() < 2 {
        return Ok(());
    }
    let places: Vec<&IcpResult> = eligible.iter().map(|&k| &tried[k].0).collect();
    let Some(shared) = scores(reference, moving, &places)? else {
        return Ok(());
    };
    let shifts: Vec<Vector3<f64>> = places.iter().map(|r| shift_at_centre(r)).collect();
    for (a, &k) in eligible.iter().enumerate() {
        let place = (0..eligible.len())
            .filter(|&b| (shifts[a] - shifts[b]).amax() <= pixel_m)
            .map(|b| shared.scores[b])
            .fold(f64::INFINITY, f64::min);
        tracing::debug!(
            own = tried[k].2,
            shared = shared.scores[a],
            place,
            samples = shared.samples,
            level = shared.level,
            "place compared"
        );
        tried[k].1 = place;
    }
    Ok(())
}

/// How nearly `other` fits as well as `best` on the samples their two
/// places share (best's score over other's, at most 1); None when they
/// share too few to say.
pub(super) fn closeness<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    best: &IcpResult,
    other: &IcpResult,
) -> Result<Option<f64>, IcpError> {
    let Some(shared) = scores(reference, moving, &[best, other])? else {
        return Ok(None);
    };
    let [b, o] = [shared.scores[0], shared.scores[1]];
    tracing::debug!(
        best = b,
        other = o,
        samples = shared.samples,
        "slid place compared"
    );
    Ok(Some(if o > 0.0 { (b / o).min(1.0) } else { 1.0 }))
}

/// The places' scores on the samples all of them share.
struct Shared {
    scores: Vec<f64>,
    samples: usize,
    level: usize,
}

/// Each place's robust spread of height differences on one lattice of
/// moving samples that land on the reference at every place (module docs);
/// None when the places share too little.
fn scores<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    places: &[&IcpResult],
) -> Result<Option<Shared>, IcpError> {
    let read = IcpError::Read;
    let mut shared: Option<Bounds> = None;
    for place in places {
        let Some(landed) = moved_overlap(reference, moving, &shift_at_centre(place))? else {
            return Ok(None);
        };
        shared = match shared {
            None => Some(landed),
            Some(b) => match b.intersection(&landed) {
                Some(common) => Some(common),
                None => return Ok(None),
            },
        };
    }
    let Some(shared) = shared else {
        return Ok(None);
    };
    let level = read_level(reference, moving, &shared)?;
    let mut mov = moving.open_level(level).map_err(read)?;
    let box_m = [shared.min_x, shared.min_y, shared.max_x, shared.max_y];
    let samples = sample_box(&mut mov, &box_m, SHARED_SAMPLES);
    if let Some(e) = mov.take_error() {
        return Err(read(e));
    }
    let mut refg = reference.open_level(level).map_err(read)?;
    let heights: Vec<Vec<f64>> = (places.iter())
        .map(|place| {
            let t = &place.t_ref_moving;
            (samples.iter())
                .map(|s| {
                    let p = t.transform_point(&Point3::new(s.x_m, s.y_m, s.h_m));
                    bilinear(&mut refg, p.x, p.y) - p.z
                })
                .collect()
        })
        .collect();
    if let Some(e) = refg.take_error() {
        return Err(read(e));
    }
    let everywhere: Vec<usize> = (0..samples.len())
        .filter(|&i| heights.iter().all(|dh| dh[i].is_finite()))
        .collect();
    if everywhere.len() < MIN_SHARED {
        return Ok(None);
    }
    let scores = (heights.iter())
        .map(|dh| {
            let mut residuals: Vec<f64> = everywhere.iter().map(|&i| dh[i]).collect();
            score_residuals(&mut residuals, MIN_SHARED).cost_m
        })
        .collect();
    Ok(Some(Shared {
        scores,
        samples: everywhere.len(),
        level,
    }))
}

/// Where a result moves the centre of its fit, metres (moving -> reference).
pub(super) fn shift_at_centre(r: &IcpResult) -> Vector3<f64> {
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

    fn place(dx: f64, status: IcpStatus, cost: f64) -> (IcpResult, f64, f64) {
        let t = Isometry3::from_parts(Translation3::new(dx, 0.0, 0.0), Default::default());
        let mut r = IcpResult::converged_at(t, [85.0, 50.0, 0.0]);
        r.status = status;
        (r, cost, cost)
    }

    /// The moving tile overlaps the reference in a 30 m strip and belongs
    /// where it is. A place 5 m east keeps 25 m of the strip and came with
    /// the lower own cost; on the samples both places land the truth fits and
    /// the other does not. A result that did not converge keeps its cost; two
    /// within a pixel of each other are one place and share its best score;
    /// the own costs stay.
    #[test]
    fn places_are_ranked_on_the_samples_they_share() {
        let (reference, moving) = (tile(0.0, 1, None), tile(70.0, 2, None));
        let mut tried = vec![
            place(0.0, IcpStatus::Converged, 0.5),
            place(5.0, IcpStatus::Converged, 0.3),
            place(9.0, IcpStatus::Diverged, 0.1),
            place(0.4, IcpStatus::Converged, 0.45),
        ];
        on_shared_samples(&reference, &moving, &mut tried, 1.0).unwrap();
        let (truth, other) = (tried[0].1, tried[1].1);
        assert!(truth < 0.2 && other > 1.0, "{truth} {other}");
        assert_eq!(tried[2].1, 0.1, "not compared");
        assert_eq!(tried[3].1, truth, "one place, one score");
        assert_eq!((tried[0].2, tried[1].2), (0.5, 0.3), "own costs kept");
    }

    /// Where both places land, the reference has a building the moving DSM
    /// lacks: on those samples a place one period (12 m) east fits better
    /// than the truth (the choice's own-cost rival rule is what catches it).
    /// A place that keeps a 1 m sliver of the strip shares too few samples to
    /// be compared, and a single converged result is not compared either.
    #[test]
    fn what_the_shared_samples_can_and_cannot_tell() {
        let reference = tile(0.0, 1, Some([72.0, 84.0, 20.0, 80.0]));
        let moving = tile(70.0, 2, None);
        let mut tried = vec![
            place(0.0, IcpStatus::Converged, 0.3),
            place(12.0, IcpStatus::Converged, 0.35),
        ];
        on_shared_samples(&reference, &moving, &mut tried, 1.0).unwrap();
        assert!(tried[1].1 < tried[0].1, "{} {}", tried[0].1, tried[1].1);

        let mut sliver = vec![
            place(0.0, IcpStatus::Converged, 0.5),
            place(29.0, IcpStatus::Converged, 0.3),
        ];
        on_shared_samples(&reference, &moving, &mut sliver, 1.0).unwrap();
        assert_eq!((sliver[0].1, sliver[1].1), (0.5, 0.3));
        let mut one = vec![
            place(12.0, IcpStatus::Converged, 0.3),
            place(0.0, IcpStatus::MaxIterations, 0.2),
        ];
        on_shared_samples(&reference, &moving, &mut one, 1.0).unwrap();
        assert_eq!((one[0].1, one[1].1), (0.3, 0.2));
    }
}
