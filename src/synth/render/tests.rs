//! The point renderings: deterministic per seed and window, and faithful to
//! sub-pixel motions (the reason they exist).

use super::*;
use crate::coarse::cost::{sample_box, score_shift};
use crate::geo::GeoTransform;
use crate::grid::MemGrid;
use crate::synth::objects::ObjectParams;
use crate::synth::surface::SurfaceParams;
use crate::synth::tiles::{render_window, rigid_about, PixelEffects};

const POINT_RENDERINGS: [Rendering; 5] = [
    Rendering::LidarMax,
    Rendering::LidarMean,
    Rendering::Tin,
    Rendering::Idw,
    Rendering::Smooth,
];

fn effects(rendering: Rendering, noise_sigma_m: f64) -> PixelEffects {
    PixelEffects {
        noise_sigma_m,
        outlier_fraction: 0.0,
        void_fraction: 0.0,
        changes: false,
        rendering,
        points_per_px: 0.0,
    }
}

fn spec(gsd_m: f64, size: u64, shift_m: [f64; 3], seed: u64) -> TileSpec {
    let gt = GeoTransform::north_up(500_000.0, 4_800_000.0, gsd_m, gsd_m);
    let mut spec = TileSpec::unperturbed("t", size, size, gt, seed);
    let centre = nalgebra::Vector3::new(500_000.0, 4_800_000.0, 200.0);
    spec.m_world = rigid_about(centre, shift_m, [0.0; 3]);
    spec.shift_m = shift_m;
    spec
}

#[test]
fn point_renderings_are_deterministic_per_seed_and_window() {
    let surface = Surface::new(SurfaceParams {
        seed: 3,
        ..Default::default()
    });
    for rendering in POINT_RENDERINGS {
        let fx = effects(rendering, 0.2);
        let s = spec(0.5, 64, [0.4, -0.3, 1.0], 11);
        let whole = render_window(&surface, &s, &fx, 0, 0, 40, 40);
        let again = render_window(&surface, &s, &fx, 0, 0, 40, 40);
        let part = render_window(&surface, &s, &fx, 10, 5, 20, 20);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&whole), bits(&again), "{rendering:?}");
        for r in 0..20 {
            for c in 0..20 {
                let (a, b) = (whole[(r + 5) * 40 + c + 10], part[r * 20 + c]);
                assert_eq!(a.to_bits(), b.to_bits(), "{rendering:?} at {c},{r}");
            }
        }
        let valid = whole.iter().filter(|v| v.is_finite()).count();
        assert!(valid > 1200, "{rendering:?}: {valid} of 1600 valid");
        let other = render_window(
            &surface,
            &spec(0.5, 64, [0.4, -0.3, 1.0], 12),
            &fx,
            0,
            0,
            40,
            40,
        );
        let differ = whole
            .iter()
            .zip(&other)
            .filter(|(a, b)| a.to_bits() != b.to_bits())
            .count();
        assert!(
            differ > 800,
            "{rendering:?}: another seed, other points ({differ})"
        );
    }
}

/// A shift of (0.3, -0.25) px is found again, to 0.1 px, between two tiles
/// rendered with different random points: the renderings keep sub-pixel motion.
#[test]
fn sub_pixel_shift_survives_every_rendering() {
    let surface = Surface::new(SurfaceParams {
        seed: 8,
        lake_cells: 0.0,
        objects: ObjectParams {
            building_cells: 0.0,
            tree_cells: 0.0,
            changed_cells: 0.0,
        },
        ..Default::default()
    });
    let gsd = 4.0;
    let truth = [0.3 * gsd, -0.25 * gsd];
    for rendering in [Rendering::Centre].into_iter().chain(POINT_RENDERINGS) {
        let fx = effects(rendering, 0.0);
        let n = 96u64;
        let a = spec(gsd, n, [0.0; 3], 1);
        let b = spec(gsd, n, [truth[0], truth[1], 0.0], 2);
        let mut reference = MemGrid::new(
            n as i64,
            n as i64,
            a.geotransform,
            render_window(&surface, &a, &fx, 0, 0, n, n),
        );
        let mut moving = MemGrid::new(
            n as i64,
            n as i64,
            b.geotransform,
            render_window(&surface, &b, &fx, 0, 0, n, n),
        );
        let inner = a.geotransform.bounds(n, n);
        let inner = [
            inner[0] + 20.0,
            inner[1] + 20.0,
            inner[2] - 20.0,
            inner[3] - 20.0,
        ];
        let samples = sample_box(&mut moving, &inner, 100_000);
        let mut scratch = Vec::new();
        let mut best = (f64::INFINITY, [0.0, 0.0]);
        for j in -14..=14 {
            for i in -14..=14 {
                let shift = [i as f64 * 0.05 * gsd, j as f64 * 0.05 * gsd];
                let s = score_shift(&mut reference, &samples, shift, 100, &mut scratch);
                if s.cost_m < best.0 {
                    best = (s.cost_m, shift);
                }
            }
        }
        let err_px = [(best.1[0] - truth[0]) / gsd, (best.1[1] - truth[1]) / gsd];
        assert!(
            err_px[0].abs() <= 0.1 && err_px[1].abs() <= 0.1,
            "{rendering:?}: found {:?} m, truth {truth:?} m",
            best.1
        );
    }
}
