//! Recovery tests of the coarse search on generated pairs with known truth.

use super::*;
use crate::geo::GeoTransform;
use crate::grid::{MemGrid, MemPyramid};
use crate::synth::{render_window, rigid_about, PixelEffects, Surface, SurfaceParams, TileSpec};

/// A size x size tile at `gsd_m` whose top-left corner is `corner`, showing
/// the world moved by M^-1 with M a pure translation `shift_m`
/// (so p_true = p_written + shift_m).
pub fn tile(
    surface: &Surface,
    gsd_m: f64,
    size: u64,
    corner: (f64, f64),
    shift_m: [f64; 3],
    fx: &PixelEffects,
    seed: u64,
) -> MemPyramid {
    let gt = GeoTransform::north_up(corner.0, corner.1, gsd_m, gsd_m);
    let mut spec = TileSpec::unperturbed("t", size, size, gt, seed);
    let centre = nalgebra::Vector3::new(corner.0, corner.1, 0.0);
    spec.m_world = rigid_about(centre, shift_m, [0.0; 3]);
    spec.shift_m = shift_m;
    let data = render_window(surface, &spec, fx, 0, 0, size, size);
    MemPyramid::build(MemGrid::new(size as i64, size as i64, gt, data), 32)
}

fn noisy(sigma_m: f64) -> PixelEffects {
    PixelEffects {
        noise_sigma_m: sigma_m,
        outlier_fraction: 0.02,
        void_fraction: 0.03,
        changes: true,
        rendering: crate::synth::Rendering::Centre,
        points_per_px: 0.0,
    }
}

fn assert_found(est: &CoarseEstimate, truth: [f64; 3], tol_xy_m: f64, tol_z_m: f64) {
    let e = est.shift_m - Vector3::from(truth);
    assert!(
        e.x.abs() < tol_xy_m && e.y.abs() < tol_xy_m && e.z.abs() < tol_z_m,
        "found {:?}, truth {truth:?} ({est:?})",
        est.shift_m
    );
}

/// 30 m DSMs (SRTM / Copernicus-like), 1 km horizontal and 300 m vertical.
#[test]
fn finds_a_kilometre_and_300_m_on_30_m_dsms() {
    let surface = Surface::new(SurfaceParams {
        seed: 4,
        relief_scale: 3.0,
        ..Default::default()
    });
    let (x0, y0) = (500_000.0, 4_800_000.0);
    let reference = tile(&surface, 30.0, 300, (x0, y0), [0.0; 3], &noisy(1.0), 1);
    for truth in [[-709.0, 538.0, 300.0], [800.0, -600.0, -300.0]] {
        let moving = tile(
            &surface,
            30.0,
            300,
            (x0 + 150.0, y0 - 90.0),
            truth,
            &noisy(1.0),
            2,
        );
        let config = CoarseConfig {
            max_displacement_m: 1200.0,
            ..Default::default()
        };
        let est = estimate(&reference, &moving, &config).unwrap();
        assert_found(&est, truth, 10.0, 1.5);
        assert!(est.level >= 2, "searched on a coarse level: {est:?}");
    }
}

/// 0.5 m city DSMs: 50 m horizontal and 150 m vertical, forward and inverse.
#[test]
fn finds_50_m_and_150_m_on_half_metre_dsms() {
    let surface = Surface::new(SurfaceParams {
        seed: 7,
        ..Default::default()
    });
    let (x0, y0) = (500_000.0, 4_800_000.0);
    let truth = [35.3, -35.6, 150.0];
    let a = tile(&surface, 0.5, 384, (x0, y0), [0.0; 3], &noisy(0.3), 1);
    let b = tile(
        &surface,
        0.5,
        384,
        (x0 + 20.0, y0 - 10.0),
        truth,
        &noisy(0.3),
        2,
    );
    let config = CoarseConfig {
        max_displacement_m: 60.0,
        ..Default::default()
    };
    let forward = estimate(&a, &b, &config).unwrap();
    assert_found(&forward, truth, 0.35, 0.3);
    assert_eq!(forward.refined_level, 0);
    assert!(forward.ambiguity < 0.8, "{forward:?}");
    let inverse = estimate(&b, &a, &config).unwrap();
    assert_found(&inverse, truth.map(|v| -v), 0.35, 0.3);
}

/// A scene that repeats itself every 24 m along x is ambiguous, and says so.
/// (Periods finer than the scan level's pixels are invisible to the scan:
/// then a multiple of the period is returned without being flagged.)
#[test]
fn periodic_scene_is_reported_ambiguous() {
    let gt = |x0: f64| GeoTransform::north_up(x0, 1000.0, 0.5, 0.5);
    let wave = |x: f64, y: f64| (5.0 * (x * std::f64::consts::TAU / 24.0).sin() + 0.01 * y) as f32;
    let make = |x0: f64| {
        let g = gt(x0);
        MemPyramid::build(
            MemGrid::from_fn(256, 256, g, |c, r| {
                let (x, y) = g.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
                wave(x, y)
            }),
            32,
        )
    };
    let config = CoarseConfig {
        max_displacement_m: 40.0,
        ..Default::default()
    };
    let est = estimate(&make(0.0), &make(3.0), &config).unwrap();
    let off_period = (est.shift_m.x / 24.0 - (est.shift_m.x / 24.0).round()).abs();
    assert!(off_period < 0.02, "a multiple of the period: {est:?}");
    assert!(est.candidates.len() >= 2, "{est:?}");
    assert!(est.ambiguity > 0.8, "{est:?}");
}

/// Footprints farther apart than the radius: a clear error, not a guess.
#[test]
fn out_of_reach_is_an_error() {
    let surface = Surface::new(SurfaceParams::default());
    let a = tile(
        &surface,
        1.0,
        64,
        (0.0, 1000.0),
        [0.0; 3],
        &PixelEffects::none(),
        1,
    );
    let b = tile(
        &surface,
        1.0,
        64,
        (500.0, 1000.0),
        [0.0; 3],
        &PixelEffects::none(),
        1,
    );
    let err = estimate(&a, &b, &CoarseConfig::default()).unwrap_err();
    assert!(matches!(err, CoarseError::NoOverlap(_)), "{err}");
}
