//! End-to-end tests of [`super::average`] on synthetic graphs with known truth.

use super::synthetic::{
    generate, pose_errors, PoseErrors, SyntheticGraph, SyntheticSpec, Topology,
};
use super::*;
use crate::graph::{chain_poses, mst, Components, Edge};
use crate::poses::rigid::{inverse_rigid, project_to_so3, rotation, translation};

fn errors_of(result: &AveragingResult, synthetic: &SyntheticGraph) -> PoseErrors {
    pose_errors(
        &result.poses,
        &synthetic.truth,
        &synthetic.graph.components(),
    )
}

fn mst_errors(synthetic: &SyntheticGraph) -> PoseErrors {
    let chained = chain_poses(&synthetic.graph, &mst(&synthetic.graph), 0).unwrap();
    pose_errors(&chained, &synthetic.truth, &synthetic.graph.components())
}

#[test]
fn exact_relative_poses_are_recovered_exactly() {
    let topologies = [
        Topology::Chain { reach: 3 },
        Topology::Grid { width: 15 },
        Topology::Random { edges_per_node: 6 },
    ];
    for (seed, topology) in topologies.into_iter().enumerate() {
        let synthetic = generate(&SyntheticSpec::exact(300, topology, seed as u64));
        let result = average(&synthetic.graph, &AveragingOptions::default()).unwrap();
        let errors = errors_of(&result, &synthetic);
        assert!(result.converged, "{topology:?}");
        assert!(
            errors.translation_max_m < 1e-8 && errors.rotation_max_deg < 1e-9,
            "{topology:?}: {errors:?}"
        );
        assert!(result.dropped_edges.is_empty() && result.solves == 1);
        assert!(result.edge_residuals.iter().all(|r| r.translation_m < 1e-8));
        assert_eq!(result.components, vec![(0..300).collect::<Vec<_>>()]);
    }
}

#[test]
fn averaging_beats_spanning_tree_chaining_under_noise() {
    for topology in [
        Topology::Grid { width: 20 },
        Topology::Random { edges_per_node: 6 },
        Topology::Chain { reach: 3 },
    ] {
        let synthetic = generate(&SyntheticSpec::noisy(400, topology, 11, 0.002, 0.02));
        let result = average(&synthetic.graph, &AveragingOptions::default()).unwrap();
        let averaged = errors_of(&result, &synthetic);
        let chained = mst_errors(&synthetic);
        assert!(
            result.dropped_edges.is_empty(),
            "{topology:?}: Gaussian noise is not an outlier"
        );
        assert!(
            averaged.translation_rms_m < 0.5 * chained.translation_rms_m
                && averaged.rotation_rms_deg < 0.5 * chained.rotation_rms_deg,
            "{topology:?}: averaged {averaged:?} vs chained {chained:?}"
        );
        if !matches!(topology, Topology::Chain { .. }) {
            // Noise 0.035 m per edge, ~12 edges per node: about 0.014 m per pose.
            assert!(
                averaged.translation_rms_m < 0.02,
                "{topology:?}: {averaged:?}"
            );
        }
    }
}

#[test]
fn on_a_tree_averaging_equals_chaining() {
    let synthetic = generate(&SyntheticSpec::noisy(
        100,
        Topology::Chain { reach: 1 },
        5,
        0.01,
        0.1,
    ));
    let result = average(
        &synthetic.graph,
        &AveragingOptions {
            gauge: Gauge::Anchor(0),
            ..Default::default()
        },
    )
    .unwrap();
    let chained = chain_poses(&synthetic.graph, &mst(&synthetic.graph), 0).unwrap();
    for (a, c) in result.poses.iter().zip(&chained) {
        assert!((a - c).abs().max() < 1e-9);
    }
    assert!(result
        .edge_residuals
        .iter()
        .all(|r| r.translation_m < 1e-9 && r.rotation_deg < 1e-9));
}

#[test]
fn anchor_gauge_keeps_the_anchor_fixed() {
    let synthetic = generate(&SyntheticSpec::noisy(
        200,
        Topology::Grid { width: 10 },
        2,
        0.002,
        0.02,
    ));
    let result = average(
        &synthetic.graph,
        &AveragingOptions {
            gauge: Gauge::Anchor(37),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(result.poses[37], Matrix4::identity());
    let mean = average(&synthetic.graph, &AveragingOptions::default()).unwrap();
    // Same solution up to the gauge: relative poses agree.
    let shift = mean.poses[37];
    for (a, m) in result.poses.iter().zip(&mean.poses) {
        assert!((shift * a - m).abs().max() < 1e-7);
    }
}

#[test]
fn mean_gauge_averages_to_identity() {
    let synthetic = generate(&SyntheticSpec::noisy(
        150,
        Topology::Random { edges_per_node: 6 },
        3,
        0.002,
        0.02,
    ));
    let result = average(&synthetic.graph, &AveragingOptions::default()).unwrap();
    let rotation_sum: Matrix3<f64> = result.poses.iter().map(rotation).sum();
    assert!(
        (project_to_so3(&rotation_sum) - Matrix3::identity())
            .abs()
            .max()
            < 1e-12
    );
    let translation_sum: Vector3<f64> = result.poses.iter().map(translation).sum();
    assert!(translation_sum.norm() < 1e-9, "{translation_sum}");
}

#[test]
fn disconnected_components_are_solved_separately() {
    let a = generate(&SyntheticSpec::noisy(
        60,
        Topology::Grid { width: 6 },
        7,
        0.002,
        0.02,
    ));
    let b = generate(&SyntheticSpec::noisy(
        40,
        Topology::Random { edges_per_node: 5 },
        8,
        0.002,
        0.02,
    ));
    // Nodes of b go after a's, plus one isolated node at the end.
    let mut graph = PoseGraph::new(101);
    graph.edges = a.graph.edges.clone();
    graph.edges.extend(b.graph.edges.iter().map(|e| Edge {
        i: e.i + 60,
        j: e.j + 60,
        ..e.clone()
    }));
    let truth: Vec<_> = a
        .truth
        .iter()
        .chain(&b.truth)
        .copied()
        .chain([Matrix4::identity()])
        .collect();
    let options = AveragingOptions {
        gauge: Gauge::Anchor(70),
        ..Default::default()
    };
    let result = average(&graph, &options).unwrap();
    assert_eq!(
        result.components,
        vec![(0..60).collect(), (60..100).collect(), vec![100]]
    );
    assert_eq!(result.poses[70], Matrix4::identity());
    assert_eq!(result.poses[100], Matrix4::identity());
    let mean_t: Vector3<f64> = (0..60).map(|k| translation(&result.poses[k])).sum();
    assert!(
        mean_t.norm() < 1e-9,
        "component without the anchor uses the mean gauge"
    );
    let errors = pose_errors(&result.poses, &truth, &graph.components());
    let alone_a = errors_of(
        &average(&a.graph, &AveragingOptions::default()).unwrap(),
        &a,
    );
    assert!(errors.translation_rms_m < 0.02, "{errors:?}");
    assert!(errors.translation_max_m >= alone_a.translation_max_m - 1e-9);
}

/// Adds 5 m to the x translation of edge `k`.
fn corrupt(synthetic: &mut SyntheticGraph, k: usize) {
    synthetic.graph.edges[k].t_ij.x += 5.0;
}

#[test]
fn an_outlier_edge_is_dropped_and_the_result_stays_accurate() {
    for topology in [
        Topology::Grid { width: 15 },
        Topology::Random { edges_per_node: 6 },
        Topology::Chain { reach: 3 },
    ] {
        let clean = generate(&SyntheticSpec::noisy(300, topology, 21, 0.002, 0.01));
        let clean_errors = errors_of(
            &average(&clean.graph, &AveragingOptions::default()).unwrap(),
            &clean,
        );
        let mut bad = clean.clone();
        corrupt(&mut bad, 123);
        let result = average(&bad.graph, &AveragingOptions::default()).unwrap();
        assert_eq!(result.dropped_edges, vec![123], "{topology:?}");
        assert!(result.downweighted_edges.is_empty());
        assert!(result.edge_residuals[123].translation_m > 4.0);
        let errors = errors_of(&result, &bad);
        assert!(
            errors.translation_rms_m < 1.2 * clean_errors.translation_rms_m,
            "{topology:?}: {errors:?} vs {clean_errors:?}"
        );
        // Without the robust step the 5 m error leaks into the poses.
        let plain = average(
            &bad.graph,
            &AveragingOptions {
                robust: false,
                ..Default::default()
            },
        )
        .unwrap();
        assert!(plain.dropped_edges.is_empty());
        assert!(
            errors_of(&plain, &bad).translation_max_m > 5.0 * errors.translation_max_m,
            "{topology:?}"
        );
    }
}

#[test]
fn several_outliers_are_all_dropped() {
    let mut synthetic = generate(&SyntheticSpec::noisy(
        400,
        Topology::Grid { width: 20 },
        4,
        0.002,
        0.01,
    ));
    let bad = [10, 400, 401, 1500];
    for &k in &bad {
        corrupt(&mut synthetic, k);
    }
    synthetic.graph.edges[401].t_ij.z -= 30.0;
    let result = average(&synthetic.graph, &AveragingOptions::default()).unwrap();
    assert_eq!(result.dropped_edges, bad.to_vec());
    assert!(errors_of(&result, &synthetic).translation_max_m < 0.05);
}

#[test]
fn bad_input_is_refused() {
    let synthetic = generate(&SyntheticSpec::exact(10, Topology::Chain { reach: 2 }, 1));
    let options = AveragingOptions {
        gauge: Gauge::Anchor(10),
        ..Default::default()
    };
    assert_eq!(
        average(&synthetic.graph, &options),
        Err(AveragingError::AnchorOutOfRange { anchor: 10, n: 10 })
    );
    let mut graph = synthetic.graph.clone();
    graph.edges[2].j = 12;
    let err = average(&graph, &AveragingOptions::default()).unwrap_err();
    assert_eq!(
        err.to_string(),
        "pose graph: edge 2: node 12 out of range (graph has 10 nodes)"
    );
    let options = AveragingOptions {
        cg_tol: 0.0,
        ..Default::default()
    };
    assert!(matches!(
        average(&synthetic.graph, &options),
        Err(AveragingError::InvalidOptions(_))
    ));
}

#[test]
fn components_helper_matches_the_result() {
    let synthetic = generate(&SyntheticSpec::exact(20, Topology::Chain { reach: 1 }, 1));
    let mut graph = synthetic.graph.clone();
    graph.edges[9].weight = 0.0; // splits the chain (both parts: weight 0 ignores the edge)
    let result = average(&graph, &AveragingOptions::default()).unwrap();
    let expected = Components::new(
        20,
        graph
            .edges
            .iter()
            .filter(|e| e.weight > 0.0)
            .map(|e| (e.i, e.j)),
    );
    assert_eq!(result.components, expected.members);
    assert_eq!(result.components.len(), 2);
    // The zero-weight edge still gets a residual, against poses it did not shape.
    let m = inverse_rigid(&result.poses[9]) * result.poses[10];
    assert!((translation(&m) - graph.edges[9].t_ij).norm() > 1e-6);
}

#[test]
fn multigrid_and_jacobi_agree_on_a_large_grid() {
    let exact = generate(&SyntheticSpec::exact(2500, Topology::Grid { width: 50 }, 6));
    let result = average(&exact.graph, &AveragingOptions::default()).unwrap();
    let errors = errors_of(&result, &exact);
    assert!(
        errors.translation_max_m < 1e-8 && errors.rotation_max_deg < 1e-9,
        "{errors:?}"
    );
    let noisy = generate(&SyntheticSpec::noisy(
        2500,
        Topology::Grid { width: 50 },
        6,
        0.002,
        0.02,
    ));
    let multigrid = average(&noisy.graph, &AveragingOptions::default()).unwrap();
    let jacobi_options = AveragingOptions {
        preconditioner: Preconditioner::Jacobi,
        ..Default::default()
    };
    let jacobi = average(&noisy.graph, &jacobi_options).unwrap();
    assert!(multigrid.converged && jacobi.converged);
    assert!(
        multigrid.cg_iterations * 3 < jacobi.cg_iterations,
        "{} vs {}",
        multigrid.cg_iterations,
        jacobi.cg_iterations
    );
    for (a, b) in multigrid.poses.iter().zip(&jacobi.poses) {
        assert!((a - b).abs().max() < 1e-8);
    }
}

#[test]
fn the_summary_counts_what_happened() {
    let mut synthetic = generate(&SyntheticSpec::noisy(
        300,
        Topology::Random { edges_per_node: 6 },
        9,
        0.002,
        0.01,
    ));
    corrupt(&mut synthetic, 50);
    let result = average(&synthetic.graph, &AveragingOptions::default()).unwrap();
    let summary = crate::poses::PosesSummary::from_result(&result);
    assert_eq!(
        (
            summary.nodes,
            summary.edges,
            summary.edges_dropped,
            summary.components
        ),
        (300, synthetic.graph.edges.len(), 1, 1)
    );
    // The dropped edge's 5 m residual is left out of the statistics.
    assert!(
        summary.max_residual_m < 0.2 && summary.median_residual_m > 0.0,
        "{summary:?}"
    );
    assert_eq!(summary.cg_iterations, result.cg_iterations);
}

/// Noise whose size differs by up to 5x either way between edges.
fn heteroscedastic(topology: Topology, seed: u64) -> SyntheticGraph {
    generate(&SyntheticSpec {
        noise_scale_spread: 5.0,
        ..SyntheticSpec::noisy(400, topology, seed, 0.002, 0.02)
    })
}

#[test]
fn information_weights_beat_the_papers_when_pairs_differ_in_quality() {
    for (seed, topology) in [
        Topology::Grid { width: 20 },
        Topology::Random { edges_per_node: 6 },
        Topology::Chain { reach: 3 },
    ]
    .into_iter()
    .enumerate()
    {
        let paper = heteroscedastic(topology, seed as u64);
        let mut information = paper.clone();
        crate::graph::information_weights(&mut information.graph.edges).unwrap();
        let options = AveragingOptions::default();
        let with_paper = errors_of(&average(&paper.graph, &options).unwrap(), &paper);
        let result = average(&information.graph, &options).unwrap();
        let with_information = errors_of(&result, &information);
        // Gaussian noise of the stated sigma is no outlier, however large.
        assert!(result.dropped_edges.is_empty(), "{topology:?}");
        assert!(
            with_information.rotation_rms_deg < 0.8 * with_paper.rotation_rms_deg
                && with_information.translation_rms_m < 0.8 * with_paper.translation_rms_m,
            "{topology:?}: information {with_information:?} paper {with_paper:?}"
        );
    }
}

#[test]
fn separate_translation_weights_still_give_the_exact_solution() {
    // Exact edges, translation weights unrelated to the rotation weights: the
    // translation solve runs on its own Laplacian and is still exact.
    let mut synthetic = generate(&SyntheticSpec::exact(
        300,
        Topology::Random { edges_per_node: 6 },
        12,
    ));
    let mut rng = crate::rng::SplitMix64::new(3);
    for e in &mut synthetic.graph.edges {
        e.translation_weight = 0.01 + rng.next_f64();
    }
    let result = average(&synthetic.graph, &AveragingOptions::default()).unwrap();
    let errors = errors_of(&result, &synthetic);
    assert!(result.converged);
    assert!(
        errors.translation_max_m < 1e-8 && errors.rotation_max_deg < 1e-9,
        "{errors:?}"
    );
    let mut graph = synthetic.graph.clone();
    graph.edges[7].translation_weight = 0.0;
    assert_eq!(
        average(&graph, &AveragingOptions::default()),
        Err(AveragingError::Graph(
            crate::graph::GraphError::ZeroTranslationWeight { edge: 7 }
        ))
    );
}

#[test]
fn translations_measured_at_the_overlap_do_not_inherit_rotation_errors() {
    // Tiles 100 m apart on a 20 x 20 grid (up to 1.3 km from the origin), each pair
    // measured at its midpoint with rotation noise 0.01 deg about it (17 cm at 1 km)
    // and 5 mm of translation noise. Constraints at the midpoints see the 5 mm; at
    // the origin they see the lever arm as well. What remains at the midpoints is
    // mostly the averaged rotations' error over the ~100 m between a node and its
    // pairs' midpoints: measured 0.0106 m against 0.0139 m (seeds 1-3: 0.72-0.75x).
    let spec = SyntheticSpec {
        spacing_m: 100.0,
        ..SyntheticSpec::noisy(400, Topology::Grid { width: 20 }, 5, 0.01, 0.005)
    };
    let synthetic = generate(&spec);
    let positions = super::synthetic::node_positions(&spec);
    // RMS over the edges of the relative pose error at the pair's midpoint (where
    // the two DSMs must meet).
    let error_m = |poses: &[Matrix4<f64>]| {
        let sum: f64 = synthetic
            .graph
            .edges
            .iter()
            .map(|e| {
                let truth = inverse_rigid(&synthetic.truth[e.i]) * synthetic.truth[e.j];
                let d = inverse_rigid(&truth) * inverse_rigid(&poses[e.i]) * poses[e.j];
                let p = (positions[e.i] + positions[e.j]) / 2.0;
                (crate::poses::rigid::apply(&d, &p) - p).norm_squared()
            })
            .sum();
        (sum / synthetic.graph.edges.len() as f64).sqrt()
    };
    let options = AveragingOptions::default();
    let result = average(&synthetic.graph, &options).unwrap();
    assert!(result.dropped_edges.is_empty());
    let at_centre = error_m(&result.poses);
    let mut at_origin = synthetic.graph.clone();
    at_origin
        .edges
        .iter_mut()
        .for_each(|e| e.centre_j = Vector3::zeros());
    let options = AveragingOptions {
        robust: false,
        ..options
    };
    let at_origin = error_m(&average(&at_origin, &options).unwrap().poses);
    assert!(
        at_centre < 0.85 * at_origin,
        "centre {at_centre} m, origin {at_origin} m"
    );
}
