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

/// Connected components of the system's edges (isolated nodes alone).
fn components_of(system: &JointSystem) -> Vec<Vec<usize>> {
    let mut parent: Vec<usize> = (0..system.n).collect();
    fn root(parent: &mut [usize], mut k: usize) -> usize {
        while parent[k] != k {
            parent[k] = parent[parent[k]];
            k = parent[k];
        }
        k
    }
    for e in &system.edges {
        let (a, b) = (root(&mut parent, e.i), root(&mut parent, e.j));
        parent[a.max(b)] = a.min(b);
    }
    let mut groups = std::collections::BTreeMap::<usize, Vec<usize>>::new();
    for k in 0..system.n {
        let r = root(&mut parent, k);
        groups.entry(r).or_default().push(k);
    }
    groups.into_values().collect()
}

#[test]
fn selected_inversion_gives_the_dense_joint_marginals() {
    let system = percolated_system(12, 0.3, 5);
    let components = components_of(&system);
    let linked: Vec<&Vec<usize>> = components.iter().filter(|c| c.len() > 1).collect();
    assert!(linked.len() >= 2, "{} components", linked.len());
    let null = covariance::null_space(&system.pivots, &components);
    let dense = covariance::exact(&system, &null);
    let direct = covariance::selected(&system, &null).expect("within budget");
    // per entry: rotations (rad^2, ~1e-8) and shifts (m^2, ~1) make the dense
    // inverse lose about 8 digits
    for &k in linked.iter().flat_map(|c| c.iter()) {
        for a in 0..6 {
            let (d, s) = (direct[k][a], dense[k][a]);
            assert!(s > 0.0 && s.is_finite(), "{k} {a}: {s}");
            assert!((d - s).abs() <= 1e-6 * s, "{k} {a}: {d} vs {s}");
        }
    }
}

/// Two DSMs, one edge whose yaw (0.1 deg) is known to 0.1 deg: free, the
/// joint steps keep the edge's yaw; with each rotation held about the
/// identity to 0.05 deg, the least-squares compromise splits it as
/// (0.1 - 2a)^2 / 0.1^2 + 2 a^2 / 0.05^2, minimal at a = 0.1 / 6 per node.
#[test]
fn the_rotation_prior_holds_each_node_about_the_identity() {
    let yaw = 0.1f64.to_radians();
    let m = crate::poses::rigid::from_parts(
        &rotation_from_axis_angle(&Vector3::new(0.0, 0.0, yaw)),
        &Vector3::new(100.0, 0.0, 0.0),
    );
    let mut graph = PoseGraph::new(2);
    let mut edge = crate::graph::Edge::new(0, 1, m, 0.3, 0.1);
    edge.centre_j = Vector3::new(-50.0, 0.0, 0.0);
    graph.edges.push(edge);
    let omega = isotropic_omega(yaw, 0.01);
    let tight = StepTolerance {
        relative: 1e-12,
        chi2_per_unknown: 0.0,
        max_iter: 1_000,
    };
    let solve = |prior_rad: f64| {
        let mut rotations = vec![Matrix3::identity(); 2];
        let mut translations = vec![Vector3::zeros(), Vector3::new(100.0, 0.0, 0.0)];
        joint_refine(
            &graph,
            &[omega],
            &[1.0],
            &mut rotations,
            &mut translations,
            JointSteps {
                steps: 6,
                tolerance: tight,
                rotation_prior_rad: prior_rad,
            },
        );
        rotations
    };
    let yaw_of = |r: &Matrix3<f64>| rotation_vector(r).z.to_degrees();
    let free = solve(f64::INFINITY);
    let relative = yaw_of(&free[0].tr_mul(&free[1]));
    assert!((relative - 0.1).abs() < 1e-6, "{relative}");
    let held = solve(0.05f64.to_radians());
    let (a, b) = (yaw_of(&held[0]), yaw_of(&held[1]));
    assert!((b - a - 2.0 * 0.1 / 6.0).abs() < 1e-5, "{a} {b}");
    assert!(
        (a + b).abs() < 1e-5,
        "symmetric about the identity: {a} {b}"
    );
}

/// Two DSMs 1 km apart, one edge with rotations known to 1e-5 rad and shifts
/// to 4.5 m (two 90 m SRTM DSMs): in the mean gauge each node carries half of
/// the edge's uncertainty on every axis. (An orthogonal gauge projection over
/// radians and metres gave roll and pitch sigmas of 0.19 deg here.)
#[test]
fn a_loose_shift_does_not_loosen_the_rotations() {
    let m = crate::poses::rigid::from_parts(&Matrix3::identity(), &Vector3::new(1000.0, 0.0, 0.0));
    let mut graph = PoseGraph::new(2);
    let mut edge = crate::graph::Edge::new(0, 1, m, 0.3, 0.1);
    edge.centre_j = Vector3::new(-500.0, 0.0, 0.0);
    graph.edges.push(edge);
    let (sr, st) = (1e-5f64, 4.5f64);
    let omega = isotropic_omega(sr, st);
    let rotations = vec![Matrix3::identity(); 2];
    let translations = vec![Vector3::zeros(), Vector3::new(1000.0, 0.0, 0.0)];
    let components = vec![vec![0, 1]];
    let sigmas = joint_node_sigmas(
        &graph,
        &[omega],
        &rotations,
        &translations,
        &components,
        crate::averaging::covariance::CovarianceMethod::default(),
    );
    for s in &sigmas {
        for a in 0..3 {
            let (r, t) = (s.rotation_deg[a], s.shift_m[a]);
            assert!((r / (sr / 2.0).to_degrees() - 1.0).abs() < 0.01, "{s:?}");
            assert!((t / (st / 2.0) - 1.0).abs() < 0.01, "{s:?}");
        }
    }
    // the selected inversion agrees
    let active = [1.0];
    let pivots = pivots(&graph, &active, &rotations, &translations);
    let system = linearise(
        &graph,
        &[omega],
        &active,
        &rotations,
        &translations,
        &pivots,
    );
    let null = covariance::null_space(&pivots, &components);
    let direct = covariance::selected(&system, &null).expect("within budget");
    for (d, s) in direct.iter().zip(&sigmas) {
        for (v, sr) in d.iter().zip(&s.rotation_deg) {
            let r = v.sqrt().to_degrees();
            assert!((r / sr - 1.0).abs() < 1e-3, "{r} {s:?}");
        }
    }
}

/// A block-diagonal edge information: rotations known to `rotation_rad`,
/// shifts to `shift_m`, on every axis.
fn isotropic_omega(rotation_rad: f64, shift_m: f64) -> Matrix6<f64> {
    let mut omega = Matrix6::zeros();
    omega
        .fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(Matrix3::identity() / rotation_rad.powi(2)));
    omega
        .fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(Matrix3::identity() / shift_m.powi(2)));
    omega
}
