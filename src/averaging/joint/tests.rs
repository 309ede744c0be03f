use super::*;
use crate::averaging::synthetic::informed::{informed_grid, InformedGridSpec};
use crate::poses::rigid::{rotation, translation};

/// The joint system of a percolated grid (a third of the pairs: nearly tree-like),
/// linearised at the truth with each pose disturbed.
fn percolated_system(width: usize, keep: f64, seed: u64) -> JointSystem {
    let grid = informed_grid(&InformedGridSpec {
        keep_fraction: keep,
        ..InformedGridSpec::new(width, seed)
    });
    let omegas: Vec<Matrix6<f64>> = grid
        .information
        .iter()
        .map(|e| {
            let mut m = Matrix6::zeros();
            m.fixed_view_mut::<3, 3>(0, 0).copy_from(&e.rotation);
            m.fixed_view_mut::<3, 3>(3, 3).copy_from(&e.translation);
            m
        })
        .collect();
    let active = vec![1.0; omegas.len()];
    let rotations: Vec<Matrix3<f64>> = grid
        .truth
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let w = Vector3::new((k as f64).sin(), (k as f64).cos(), 0.5) * 1e-4;
            rotation_from_axis_angle(&w) * rotation(m)
        })
        .collect();
    let translations: Vec<Vector3<f64>> = grid
        .truth
        .iter()
        .enumerate()
        .map(|(k, m)| translation(m) + Vector3::new(0.1, -0.2, (k % 5) as f64 * 0.01))
        .collect();
    let pivots = pivots(&grid.graph, &active, &rotations, &translations);
    linearise(
        &grid.graph,
        &omegas,
        &active,
        &rotations,
        &translations,
        &pivots,
    )
}

#[test]
fn the_direct_step_on_a_nearly_tree_like_graph_is_the_cg_step() {
    let system = percolated_system(24, 0.36, 3);
    let rhs = system.gradient();
    let tight = StepTolerance {
        relative: 1e-12,
        chi2_per_unknown: 0.0,
        max_iter: 50_000,
    };
    let direct = system.solve_direct(&rhs, tight).expect("within the budget");
    let (cg, iterations, converged) = system.solve_cg(&rhs, tight);
    assert!(converged, "{iterations}");
    // Compared in the energy norm (the change of chi^2): the components' free
    // motions, held only by the tiny prior, are far from unique.
    let energy = |x: &[Vector6<f64>]| {
        let mut hx = vec![Vector6::zeros(); x.len()];
        system.apply(x, &mut hx);
        dot(x, &hx)
    };
    let difference: Vec<Vector6<f64>> = direct.iter().zip(&cg).map(|(a, b)| a - b).collect();
    let (gain, apart) = (energy(&cg), energy(&difference));
    assert!(gain > 0.0 && apart <= 1e-10 * gain, "{apart} of {gain}");
    // solve() takes the direct path: no CG iteration.
    let (_, iterations, converged) = system.solve(&rhs, tight);
    assert!(converged);
    assert_eq!(iterations, 0);
}

#[test]
fn a_well_connected_grid_stays_with_cg() {
    let system = percolated_system(40, 1.0, 5);
    let rhs = system.gradient();
    assert!(system
        .solve_direct(&rhs, StepTolerance::step(20_000))
        .is_none());
}
