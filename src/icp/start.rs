//! Where ICP starts: the global initial search ([`crate::coarse`]) over
//! ±the search radius, so offsets of hundreds of metres horizontally and
//! vertically need no flag. One start when the search is clear, the best few
//! when it is ambiguous (each is refined by ICP; the pair keeps the best).

use nalgebra::Vector3;

use super::{config, IcpConfig, IcpError};
use crate::coarse::cost::{sample_box, score_shift};
use crate::coarse::{estimate, CoarseConfig, CoarseError, CoarseEstimate};
use crate::geo::Bounds;
use crate::grid::{Grid, Pyramid};

/// Coarse ambiguity above which ICP is run from several candidates.
pub const MULTI_START_AMBIGUITY: f64 = 0.8;
/// Candidates refined by ICP when the search is ambiguous.
pub const MAX_STARTS: usize = 3;
/// The automatic search radius is at least this many pixels.
pub const MIN_AUTO_RADIUS_PX: f64 = 8.0;

/// One starting translation (p_ref = p_moving + shift_m) and the search's
/// residual spread there.
#[derive(Clone, Copy, Debug)]
pub struct Start {
    pub shift_m: Vector3<f64>,
    pub cost_m: f64,
}

/// The outcome of the initial search.
#[derive(Clone, Debug)]
pub struct Starts {
    /// Best first; at least one.
    pub starts: Vec<Start>,
    /// The search's ambiguity (best cost / second cost); None without a search.
    pub ambiguity: Option<f64>,
    /// The search radius used, metres: also the largest motion ICP may make from a start.
    pub radius_m: f64,
    /// The radius the search started with: the automatic one cut to half a
    /// narrow overlap (`radius_m` is larger when the search widened).
    pub cut_m: f64,
    /// Full-resolution pixel (the coarser of the two DSMs), metres.
    pub pixel_m: f64,
}

/// Searches for the moving DSM within the radius (see the module doc). A
/// search that finds no shift with enough overlap falls back to the identity.
pub fn find_starts<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
) -> Result<Starts, IcpError> {
    let g = reference
        .open_level(0)
        .map_err(IcpError::Read)?
        .geotransform();
    let h = moving.open_level(0).map_err(IcpError::Read)?.geotransform();
    let pixel_m = g.pixel_m().max(h.pixel_m());
    // Two DSMs are a pair where their footprints and data meet as georeferenced;
    // the search then looks for the best fit around that.
    let nominal =
        moved_overlap(reference, moving, &Vector3::zeros())?.ok_or(IcpError::NoOverlap)?;
    if !has_common_data(reference, moving, &nominal)? {
        return Err(IcpError::EmptyOverlap);
    }
    // The automatic radius stays within half the overlap: a search over a small
    // overlap's whole width finds chance fits at its edges.
    let full_m = config.search_radius_m(pixel_m);
    let mut radius_m = full_m;
    if !config.max_displacement_m.is_finite() {
        let half_side = 0.5 * nominal.width().min(nominal.height());
        radius_m = radius_m.min(half_side.max(MIN_AUTO_RADIUS_PX * pixel_m));
    }
    let Some(found) = search(reference, moving, radius_m)? else {
        return Ok(Starts {
            starts: vec![Start {
                shift_m: Vector3::zeros(),
                cost_m: f64::NAN,
            }],
            ambiguity: None,
            radius_m,
            cut_m: radius_m,
            pixel_m,
        });
    };
    let mut starts = starts_from(&found, pixel_m);
    tracing::debug!(shift = ?found.shift_m, ambiguity = found.ambiguity, level = found.level, candidates = ?found.candidates, "initial search");
    // Best on the edge of a radius cut to half the overlap: the DSM may lie
    // farther (a 20 m offset across a 19 m strip, where the strip's best
    // place within 9.5 m was 12 m off with 0.1 m sigmas). The radius doubles,
    // up to the automatic one, until the best place lies inside it; the
    // places found on the way join the starts and the usual comparison
    // decides (a near tie makes the pair ambiguous). One jump to the whole
    // radius found chance fits where the strip slid along itself, or, on 64 m
    // tiles, 90 m away where the tiles meet another way (docs/measurements.md,
    // "The search radius beyond half a narrow overlap").
    // In a collection, `align` judges a widened search's far answer by the
    // offsets its clear pairs measured (`crate::align::reach`).
    let ambiguity = found.ambiguity;
    let cut_m = radius_m;
    let mut last = found;
    while radius_m < full_m && on_edge(reference, &last, radius_m)? {
        radius_m = (2.0 * radius_m).min(full_m);
        let Some(wider) = search(reference, moving, radius_m)? else {
            break;
        };
        tracing::debug!(radius_m, shift = ?wider.shift_m, ambiguity = wider.ambiguity, level = wider.level, candidates = ?wider.candidates, "initial search widened");
        for s in starts_from(&wider, pixel_m) {
            let known =
                (starts.iter()).any(|k| (k.shift_m - s.shift_m).xy().norm() <= 3.0 * pixel_m);
            if !known {
                starts.push(s);
            }
        }
        last = wider;
    }
    Ok(Starts {
        starts,
        ambiguity: Some(ambiguity),
        radius_m,
        cut_m,
        pixel_m,
    })
}

/// The global search within `radius_m`; None when no shift keeps enough of
/// the overlap (the caller starts from the georeferenced position).
fn search<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    radius_m: f64,
) -> Result<Option<CoarseEstimate>, IcpError> {
    let coarse = CoarseConfig {
        max_displacement_m: radius_m,
        ..CoarseConfig::default()
    };
    match estimate(reference, moving, &coarse) {
        Ok(found) => Ok(Some(found)),
        Err(CoarseError::NoOverlap(_)) => Err(IcpError::NoOverlap),
        Err(CoarseError::EmptyOverlap) => Err(IcpError::EmptyOverlap),
        Err(CoarseError::Read(e)) => Err(IcpError::Read(e)),
        Err(CoarseError::NoMatch(_)) => Ok(None),
    }
}

/// Whether the search's best place lies within two pixels of its scan level
/// from the edge of the searched square.
fn on_edge<R: Pyramid>(
    reference: &R,
    found: &CoarseEstimate,
    radius_m: f64,
) -> Result<bool, IcpError> {
    let scan_pixel_m = (reference.open_level(found.level))
        .map_err(IcpError::Read)?
        .geotransform()
        .pixel_m();
    let reach = found.shift_m.x.abs().max(found.shift_m.y.abs());
    Ok(reach >= radius_m - 2.0 * scan_pixel_m)
}

/// The starts the search's candidates give: the best one when the search is
/// clear, the best [`MAX_STARTS`] when it is ambiguous. Georeferencing is
/// usually right to a few metres: when the search moves the DSM far, or is
/// ambiguous, ICP also starts from where the DSM is (at the search's height
/// offset) unless a start is already there, and the better final fit wins
/// (compared on the samples the places share); two good fits apart make the
/// pair ambiguous. On a narrow strip of noisy ground the search's best
/// minima can all lie where the strip half slides off the reference, a few
/// metres from each other and farther from the truth than the georeferenced
/// position is (tile_1451 -> tile_1450 of the 50 x 50 grid of 64 m tiles).
fn starts_from(found: &CoarseEstimate, pixel_m: f64) -> Vec<Start> {
    let ambiguous = found.ambiguity > MULTI_START_AMBIGUITY;
    let take = if ambiguous { MAX_STARTS } else { 1 };
    let mut starts: Vec<Start> = (found.candidates.iter())
        .take(take)
        .map(|c| Start {
            shift_m: Vector3::from(c.shift_m),
            cost_m: c.cost_m,
        })
        .collect();
    let best = starts[0];
    let far = best.shift_m.xy().norm() > config::PAPER_TAU_M.max(3.0 * pixel_m);
    let at_home = (starts.iter()).any(|s| s.shift_m.xy().norm() <= 3.0 * pixel_m);
    if (far || ambiguous) && !at_home {
        starts.push(Start {
            shift_m: Vector3::new(0.0, 0.0, best.shift_m.z),
            cost_m: best.cost_m,
        });
    }
    starts
}

/// Whether valid moving pixels of `overlap` land on valid reference pixels as
/// georeferenced, judged on the coarsest level where the overlap still spans
/// 16 pixels a side.
fn has_common_data<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    overlap: &Bounds,
) -> Result<bool, IcpError> {
    let levels = reference.num_levels().min(moving.num_levels()).max(1);
    let side_m = overlap.width().min(overlap.height());
    let mut level = 0;
    for l in (0..levels).rev() {
        let gt = moving.open_level(l).map_err(IcpError::Read)?.geotransform();
        if side_m / gt.pixel_m() >= 16.0 {
            level = l;
            break;
        }
    }
    let mut mov = moving.open_level(level).map_err(IcpError::Read)?;
    let box_m = [overlap.min_x, overlap.min_y, overlap.max_x, overlap.max_y];
    let samples = sample_box(&mut mov, &box_m, 1024);
    if let Some(e) = mov.take_error() {
        return Err(IcpError::Read(e));
    }
    let mut refg = reference.open_level(level).map_err(IcpError::Read)?;
    let score = score_shift(&mut refg, &samples, [0.0, 0.0], 0, &mut Vec::new());
    if let Some(e) = refg.take_error() {
        return Err(IcpError::Read(e));
    }
    Ok(score.support >= 3)
}

/// The part of the moving DSM that lands on the reference when moved by
/// `shift_m` (moving CRS coordinates); None when nothing does.
pub fn moved_overlap<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    shift_m: &Vector3<f64>,
) -> Result<Option<Bounds>, IcpError> {
    let extent = |g: &dyn Grid| g.geotransform().extent(g.width() as u64, g.height() as u64);
    let ref0 = extent(&reference.open_level(0).map_err(IcpError::Read)?);
    let mov0 = extent(&moving.open_level(0).map_err(IcpError::Read)?);
    let back = Bounds::from_corners(
        (ref0.min_x - shift_m.x, ref0.min_y - shift_m.y),
        (ref0.max_x - shift_m.x, ref0.max_y - shift_m.y),
    );
    Ok(mov0.intersection(&back))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::coarse::Candidate;
    use crate::geo::GeoTransform;
    use crate::grid::{MemGrid, MemPyramid};

    fn search(ambiguity: f64, places: &[[f64; 2]]) -> CoarseEstimate {
        let candidates: Vec<Candidate> = (places.iter().enumerate())
            .map(|(k, p)| Candidate {
                shift_m: [p[0], p[1], -0.5],
                cost_m: 0.7 + 0.01 * k as f64,
                support: 1000,
            })
            .collect();
        CoarseEstimate {
            shift_m: Vector3::from(candidates[0].shift_m),
            candidates,
            ambiguity,
            level: 0,
            refined_level: 0,
            trials: 1,
        }
    }

    fn places(starts: &[Start]) -> Vec<[f64; 2]> {
        starts.iter().map(|s| [s.shift_m.x, s.shift_m.y]).collect()
    }

    /// A clear search near home gives its best place; an ambiguous one its
    /// best three and home (at the search's height offset), unless one of
    /// them is home already; a clear one far away gives its best and home.
    #[test]
    fn ambiguous_or_far_searches_also_start_at_home() {
        let near = [[2.5, -1.0], [9.0, 0.0], [9.0, -1.0], [-7.0, 3.0]];
        let clear = starts_from(&search(0.5, &near), 0.5);
        assert_eq!(places(&clear), vec![[2.5, -1.0]]);
        let edge = [[8.5, -4.0], [9.0, 0.0], [9.0, -1.0], [-7.0, 3.0]];
        let ambiguous = starts_from(&search(0.95, &edge), 0.5);
        assert_eq!(
            places(&ambiguous),
            vec![[8.5, -4.0], [9.0, 0.0], [9.0, -1.0], [0.0, 0.0]]
        );
        assert_eq!(ambiguous[3].shift_m.z, -0.5);
        let home = [[8.5, -4.0], [0.5, 1.0], [9.0, -1.0]];
        assert_eq!(starts_from(&search(0.95, &home), 0.5).len(), 3);
        let far = starts_from(&search(0.5, &[[300.0, -200.0]]), 30.0);
        assert_eq!(places(&far), vec![[300.0, -200.0], [0.0, 0.0]]);
    }

    #[test]
    fn the_moved_overlap_follows_the_shift() {
        let tile = |left: f64| {
            let gt = GeoTransform::north_up(left, 100.0, 1.0, 1.0);
            MemPyramid::build(MemGrid::from_fn(100, 100, gt, |_, _| 1.0), 64)
        };
        let (r, m) = (tile(0.0), tile(50.0));
        let none = moved_overlap(&r, &m, &Vector3::zeros()).unwrap().unwrap();
        assert_eq!((none.min_x, none.max_x), (50.0, 100.0));
        // moved 30 m east, the moving tile lands 30 m further from the reference
        let moved = moved_overlap(&r, &m, &Vector3::new(30.0, 0.0, 7.0))
            .unwrap()
            .unwrap();
        assert_eq!((moved.min_x, moved.max_x), (50.0, 70.0));
        assert!(moved_overlap(&r, &m, &Vector3::new(60.0, 0.0, 0.0))
            .unwrap()
            .is_none());
    }

    /// Smooth bumps of varied height, one per 12 m cell at a place of its
    /// own: no repeating pattern for a chance fit to lock onto.
    fn bumps(x: f64, y: f64) -> f64 {
        let (cx, cy) = ((x / 12.0).floor(), (y / 12.0).floor());
        let mut h = 0.02 * x - 0.01 * y;
        for i in -1..=1 {
            for j in -1..=1 {
                let (u, v) = (cx + i as f64, cy + j as f64);
                let hash = |a: f64, b: f64| ((u * a + v * b).sin() * 43758.5453).fract().abs();
                let (px, py) = (12.0 * (u + hash(12.9, 78.2)), 12.0 * (v + hash(39.3, 11.1)));
                let d2 = (x - px).powi(2) + (y - py).powi(2);
                h += (1.0 + 8.0 * hash(26.7, 4.9)) * (-d2 / 18.0).exp();
            }
        }
        h
    }

    /// Two 200 x 200 px DSMs at 0.5 m whose footprints share a 20 m strip
    /// (the automatic radius is cut to 10 m) and whose content needs `shift`
    /// (p_ref = p_moving + shift): the moving one sees the reference's ground
    /// `shift.x` metres west of where its footprint says.
    fn strip_pair(shift: Vector3<f64>) -> (MemPyramid, MemPyramid) {
        crate::icp::testing::side_by_side(bumps, 80.0, shift)
    }

    /// An offset beyond half a narrow strip is found when the best place
    /// within the cut radius lies on its edge (14 m: the radius doubles);
    /// within the cut radius nothing changes (4 m).
    #[test]
    fn offsets_beyond_half_a_narrow_overlap_are_found() {
        for dx in [-4.0, -14.0] {
            let truth = Vector3::new(dx, 3.0, 0.4);
            let (reference, moving) = strip_pair(truth);
            let found = find_starts(&reference, &moving, &IcpConfig::default()).unwrap();
            let near = (found.starts.iter()).any(|s| (s.shift_m - truth).xy().norm() < 1.5);
            assert!(near, "{dx}: {:?}", places(&found.starts));
            let widened = found.radius_m > found.cut_m;
            assert_eq!(
                widened,
                dx < -10.0,
                "{dx}: {} {}",
                found.cut_m,
                found.radius_m
            );
            let config = IcpConfig {
                model: crate::fit::Model::Translation,
                ..IcpConfig::default()
            };
            let result = crate::icp::register(&reference, &moving, &config).unwrap();
            let at = nalgebra::Point3::from(result.information.as_ref().unwrap().centroid);
            let shift = result.t_ref_moving.transform_point(&at) - at;
            assert!(
                (shift - truth).norm() < 0.1 && result.status.is_converged_or_held(),
                "{dx}: {shift:?} {:?}",
                result.status
            );
        }
    }
}
