//! Unit tests of the tile planner, perturbations and rendering windows.
use super::*;
use crate::synth::surface::SurfaceParams;

#[test]
fn chain_layout_overlaps_and_perturbations_are_bounded() {
    let p = TileSetParams::default();
    let tiles = plan_tiles(&p, 200.0);
    assert_eq!(tiles.len(), 4);
    let dx = tiles[1].geotransform.0[0] - tiles[0].geotransform.0[0];
    assert_eq!(dx, 51.0, "256 px * 0.4 = 102 px step at 0.5 m");
    for t in &tiles {
        assert!(t.shift_m[0].abs() <= 3.0 && t.shift_m[2].abs() <= 2.0);
        assert!(t.rot_deg.iter().all(|a| a.abs() <= 0.03));
        let m = &t.m_world;
        let rtr = m.fixed_view::<3, 3>(0, 0).transpose() * m.fixed_view::<3, 3>(0, 0);
        assert!((rtr - nalgebra::Matrix3::identity()).norm() < 1e-12);
        // The tile centre at the pivot height moves by exactly the shift.
        let side = 128.0;
        let (x0, y0) = (t.geotransform.0[0], t.geotransform.0[3]);
        let c = nalgebra::Vector4::new(x0 + side / 2.0, y0 - side / 2.0, 200.0, 1.0);
        let moved = m * c - c;
        for k in 0..3 {
            assert!((moved[k] - t.shift_m[k]).abs() < 1e-9);
        }
    }
    assert_ne!(tiles[0].seed, tiles[1].seed);
    let mut g = p.clone();
    g.layout = Layout::Grid;
    g.rows = 2;
    g.cols = 3;
    let grid = plan_tiles(&g, 200.0);
    assert_eq!(grid.len(), 6);
    assert_eq!(grid[4].geotransform.0[3], 4_800_000.0 - 51.0);
}

/// A noise-free perturbed tile mapped back through m_world lands on the surface.
#[test]
fn written_tile_maps_back_onto_true_surface() {
    let surface = Surface::new(SurfaceParams {
        seed: 21,
        ..Default::default()
    });
    let p = TileSetParams {
        max_rot_deg: 0.05,
        ..Default::default()
    };
    let spec = &plan_tiles(&p, 200.0)[2];
    let n = 96u64;
    let values = render_window(&surface, spec, &PixelEffects::none(), 40, 40, n, n);
    let mut sampler = surface.sampler();
    let (mut checked, mut off, mut moved) = (0, 0, 0);
    for r in 0..n {
        for c in 0..n {
            let hw = values[(r * n + c) as usize] as f64;
            if hw.is_nan() {
                continue;
            }
            let (xw, yw) = spec
                .geotransform
                .pixel_to_world((40 + c) as f64 + 0.5, (40 + r) as f64 + 0.5);
            let p = spec.m_world * nalgebra::Vector4::new(xw, yw, hw, 1.0);
            let truth = sampler.true_height(p[0], p[1]);
            checked += 1;
            if (p[2] - truth).abs() > 1e-3 {
                off += 1;
            }
            if (sampler.true_height(xw, yw) - hw).abs() > 0.05 {
                moved += 1;
            }
        }
    }
    assert!(checked > 8000, "{checked}");
    assert!(off * 200 < checked, "{off} of {checked} off the surface");
    assert!(
        moved * 2 > checked,
        "the perturbation must change the tile ({moved})"
    );
}

#[test]
fn render_is_window_independent_and_noisy() {
    let surface = Surface::new(SurfaceParams::default());
    let p = TileSetParams::default();
    let spec = &plan_tiles(&p, 200.0)[0];
    let fx = PixelEffects::from_params(&p);
    let whole = render_window(&surface, spec, &fx, 0, 0, 64, 64);
    let part = render_window(&surface, spec, &fx, 16, 8, 16, 16);
    for r in 0..16 {
        for c in 0..16 {
            let (a, b) = (
                whole[((r + 8) * 64 + c + 16) as usize],
                part[(r * 16 + c) as usize],
            );
            assert!(a.to_bits() == b.to_bits());
        }
    }
    let clean = render_window(&surface, spec, &PixelEffects::none(), 0, 0, 64, 64);
    let d: Vec<f64> = whole
        .iter()
        .zip(&clean)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (a - b) as f64)
        .filter(|d| d.abs() < 4.0)
        .collect();
    let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
    assert!((rms - 0.3).abs() < 0.03, "noise rms {rms}");
    let edge = render_window(&surface, spec, &fx, 250, 250, 16, 16);
    assert!(edge[10 * 16 + 10].is_nan(), "outside the tile");
}
