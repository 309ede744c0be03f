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
    // (a relief along y that no shift within the radius repeats: a plane in y
    // would leave every shift along y as good as the truth)
    let wave = |x: f64, y: f64| {
        let tau = std::f64::consts::TAU;
        (5.0 * (x * tau / 24.0).sin() + 3.0 * (y * tau / 150.0).sin()) as f32
    };
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

/// The cost before issue 11's fix: dh about its median (no tilt), clipped at
/// 3 NMAD of the shift's own residuals (at least 1 mm).
fn self_clipped_cost(
    reference: &mut MemGrid,
    samples: &[cost::Sample],
    shift_xy_m: [f64; 2],
) -> f64 {
    let mut dh: Vec<f64> = samples
        .iter()
        .map(|s| cost::bilinear(reference, s.x_m + shift_xy_m[0], s.y_m + shift_xy_m[1]) - s.h_m)
        .filter(|d| d.is_finite())
        .collect();
    let level = cost::median_in_place(&mut dh);
    for d in dh.iter_mut() {
        *d = (*d - level).abs();
    }
    let clip = (3.0 * 1.4826 * cost::median_in_place(&mut dh)).max(1e-3);
    (dh.iter().map(|d| d.min(clip).powi(2)).sum::<f64>() / dh.len() as f64).sqrt()
}

/// Issue 11: a narrow overlap strip of two noise-free 128 m tiles tilted
/// against each other by 0.06 degrees per axis (twice the generator's largest
/// rotation), started at the truth as with `--initial truth
/// --max-displacement 2`. The old cost (each shift clipped at its own spread,
/// a level offset) starts ICP a metre off; the search now keeps the truth.
#[test]
fn clean_tilted_strip_keeps_the_georeferenced_start() {
    let surface = Surface::new(SurfaceParams {
        seed: 3,
        ..Default::default()
    });
    let (x0, y0) = (500_000.0, 4_800_000.0);
    let (size, gsd) = (256u64, 0.5);
    let make = |corner: (f64, f64), rot_deg: [f64; 3], seed: u64| {
        let gt = GeoTransform::north_up(corner.0, corner.1, gsd, gsd);
        let mut spec = TileSpec::unperturbed("t", size, size, gt, seed);
        let half = 0.5 * size as f64 * gsd;
        let centre = nalgebra::Vector3::new(corner.0 + half, corner.1 - half, 200.0);
        spec.m_world = rigid_about(centre, [0.0; 3], rot_deg);
        let data = render_window(&surface, &spec, &PixelEffects::none(), 0, 0, size, size);
        MemGrid::new(size as i64, size as i64, gt, data)
    };
    let reference = make((x0, y0), [0.03, -0.03, 0.0], 1);
    let moving = make((x0 + 89.5, y0), [-0.03, 0.03, 0.0], 2);
    // the old cost's best whole-pixel shift within +-2 m
    let mut moving_grid = moving.clone();
    let strip = [x0 + 89.5, y0 - 128.0, x0 + 128.0, y0];
    let samples = cost::sample_box(&mut moving_grid, &strip, 4096);
    let mut reference_grid = reference.clone();
    let mut old_best = (f64::INFINITY, [0.0, 0.0]);
    for j in -4..=4 {
        for i in -4..=4 {
            let shift = [i as f64 * gsd, j as f64 * gsd];
            let c = self_clipped_cost(&mut reference_grid, &samples, shift);
            if c < old_best.0 {
                old_best = (c, shift);
            }
        }
    }
    let old_off_m = old_best.1[0].hypot(old_best.1[1]);
    assert!(
        old_off_m >= 0.5,
        "the old cost found the truth here: {old_best:?}"
    );
    let config = CoarseConfig {
        max_displacement_m: 2.0,
        ..Default::default()
    };
    let est = estimate(
        &MemPyramid::build(reference, 32),
        &MemPyramid::build(moving, 32),
        &config,
    )
    .unwrap();
    assert!(
        est.shift_m.xy().norm() < 0.25,
        "old cost {old_off_m} m off; now {est:?}"
    );
}
