//! Test pairs shared by the ICP modules' unit tests.

use nalgebra::Vector3;

use crate::geo::GeoTransform;
use crate::grid::{MemGrid, MemPyramid};

/// Two 200 x 200 px DSMs at 0.5 m of `surface`, the reference at x = 500,000
/// and the moving one `moving_east_m` east of it, written so that `shift`
/// registers it (p_ref = p_moving + shift: the moving one sees the ground
/// `shift` away from where its footprint says).
pub(super) fn side_by_side(
    surface: fn(f64, f64) -> f64,
    moving_east_m: f64,
    shift: Vector3<f64>,
) -> (MemPyramid, MemPyramid) {
    let make = |left: f64, t: Vector3<f64>| {
        let gt = GeoTransform::north_up(left, 4_800_100.0, 0.5, 0.5);
        MemGrid::from_fn(200, 200, gt, move |c, r| {
            let (x, y) = gt.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            (surface(x + t.x, y + t.y) - t.z) as f32
        })
    };
    (
        MemPyramid::build(make(500_000.0, Vector3::zeros()), 64),
        MemPyramid::build(make(500_000.0 + moving_east_m, shift), 64),
    )
}
