//! The correspondence step's tests: matches kept between calls, bounds and
//! exact distances, windows.

use super::*;
use crate::geo::GeoTransform;
use crate::grid::{MemGrid, MemPyramid};
use crate::nn::{PlaneTable, WithPlanes};
use crate::rng::SplitMix64;
use nalgebra::{Translation3, UnitQuaternion};

/// A noisy 600 x 600 px surface with walls and voids, and queries over
/// it and beyond its edge (some outliers beyond tau).
fn scene() -> (MemPyramid, Vec<Vector3<f64>>, PixelFrame) {
    let gt = GeoTransform::north_up(1000.0, 2000.0, 0.5, 0.5);
    let mut rng = SplitMix64::new(7);
    let grid = MemGrid::from_fn(600, 600, gt, |c, r| {
        if rng.next_f64() < 0.03 {
            return f32::NAN;
        }
        let wall = if (c / 23 + r / 17) % 4 == 0 {
            12.0
        } else {
            0.0
        };
        (0.02 * c as f64 + 3.0 * (r as f64 / 40.0).sin() + wall + 0.3 * rng.next_f64()) as f32
    });
    let origin = Vector3::new(1150.0, 1850.0, 0.0);
    let frame = PixelFrame::new(&gt, &origin);
    let mut points: Vec<Vector3<f64>> = (0..20_000)
        .map(|_| {
            let (x, y) = (
                rng.next_f64() * 340.0 - 160.0,
                rng.next_f64() * 340.0 - 160.0,
            );
            let z = if rng.next_f64() < 0.05 {
                40.0
            } else {
                rng.next_f64() * 15.0 - 3.0
            };
            Vector3::new(x, y, z)
        })
        .collect();
    block_order(&mut points, &frame, 256);
    (MemPyramid::build(grid, 64), points, frame)
}

/// Point-to-surface matching on level 0 with a tau of 10 m.
fn surface_matcher<P>(reference: &P, frame: PixelFrame, distances: Distances) -> Matcher<'_, P> {
    Matcher {
        reference,
        level: 0,
        frame,
        tau_m: 10.0,
        metric: Metric::PointToSurface,
        distances,
    }
}

/// What a level keeps between calls (each query's ring plane and far
/// mark, and the pair's shared plane table) leaves every match, distance
/// and cell as matching afresh, through small steps (the far marks
/// hold) and jumps (they lapse), bounded and exact.
#[test]
fn what_is_kept_between_calls_matches_as_afresh() {
    let (pyramid, points, frame) = scene();
    let planed = WithPlanes::new(&pyramid, 0, PlaneTable::new(0, 0, 600, 600));
    let steps = [
        (0.7, -0.4, 0.3),
        (0.71, -0.41, 0.31),
        (0.712, -0.405, 0.305),
        (3.0, 2.0, -1.0),
        (3.001, 2.0, -1.002),
    ];
    for distances in [Distances::Bound, Distances::Exact] {
        let mut memo = vec![QueryMemo::default(); points.len()];
        let mut skipped = 0;
        for (x, y, z) in steps {
            let t = Isometry3::from_parts(
                Translation3::new(x, y, z),
                UnitQuaternion::from_euler_angles(0.0, 0.0, 0.002),
            );
            let fresh_matcher = surface_matcher(&pyramid, frame, distances);
            let kept_matcher = surface_matcher(&planed, frame, distances);
            let mut fresh_memo = vec![QueryMemo::default(); points.len()];
            let fresh = associate(&fresh_matcher, &points, &mut fresh_memo, &t).unwrap();
            let kept = associate(&kept_matcher, &points, &mut memo, &t).unwrap();
            assert!(fresh.corrs.len() > 10_000, "{}", fresh.corrs.len());
            assert_eq!(fresh.corrs.len(), kept.corrs.len());
            for k in 0..fresh.corrs.len() {
                let (a, b) = (&fresh.corrs[k], &kept.corrs[k]);
                assert_eq!(
                    (a.moving, a.reference, a.normal, a.normal_var),
                    (b.moving, b.reference, b.normal, b.normal_var)
                );
                assert_eq!(fresh.distances_m[k], kept.distances_m[k]);
                let (c, d) = (&fresh.cells[k], &kept.cells[k]);
                assert_eq!(
                    (c.roughness_m, c.var_m2, c.band_m),
                    (d.roughness_m, d.var_m2, d.band_m)
                );
            }
            skipped += fresh.nn.pixels_visited as i64 - kept.nn.pixels_visited as i64;
        }
        // the far marks saved searches (the queries beyond the raster's
        // edge and the spikes are found again otherwise)
        assert!(skipped > 0, "{distances:?}");
    }
}

/// The outlier rule decided by the pixel below (Bound) keeps exactly the
/// matches of the full search (Exact), with distances at least the
/// nearest neighbour's; both read through windows, so they are also
/// checked against a search without any (one query per call).
#[test]
fn a_bound_keeps_the_matches_of_the_full_search() {
    let (pyramid, points, frame) = scene();
    let t = Isometry3::from_parts(
        Translation3::new(0.7, -0.4, 0.3),
        UnitQuaternion::from_euler_angles(0.0, 0.0, 0.002),
    );
    let matcher = |distances| surface_matcher(&pyramid, frame, distances);
    let memo = || vec![QueryMemo::default(); points.len()];
    let exact = associate(&matcher(Distances::Exact), &points, &mut memo(), &t).unwrap();
    let bound = associate(&matcher(Distances::Bound), &points, &mut memo(), &t).unwrap();
    assert!(exact.corrs.len() > 10_000, "{}", exact.corrs.len());
    assert_eq!(exact.corrs.len(), bound.corrs.len());
    assert_eq!(exact.with_reference_below, bound.with_reference_below);
    for k in 0..exact.corrs.len() {
        let (a, b) = (&exact.corrs[k], &bound.corrs[k]);
        assert_eq!(
            (a.moving, a.reference, a.normal),
            (b.moving, b.reference, b.normal)
        );
        assert!(bound.distances_m[k] >= exact.distances_m[k]);
    }
    let (b, e) = (bound.nn.pixels_visited, exact.nn.pixels_visited);
    assert!(b < e, "pixels visited: bound {b}, exact {e}");
    // one query per call: its window is its own, or none at all
    let mut grid = pyramid.open_level(0).unwrap();
    let m = matcher(Distances::Exact);
    let mut k = 0;
    for p in points.iter().step_by(97) {
        let q = t.transform_point(&Point3::from(*p)).coords;
        let single = match_query(
            &mut grid,
            &m,
            None,
            &q,
            &mut QueryMemo::default(),
            &mut NnStats::default(),
        );
        let batched = exact.corrs.iter().position(|c| c.moving == q);
        match (single, batched) {
            (Some((corr, d, _)), Some(i)) => {
                assert_eq!(
                    (corr.reference, d),
                    (exact.corrs[i].reference, exact.distances_m[i])
                );
                k += 1;
            }
            (None, None) => {}
            (s, b) => panic!(
                "query {q:?}: alone {:?}, in its block {b:?}",
                s.map(|s| s.1)
            ),
        }
    }
    assert!(k > 100, "{k}");
}
