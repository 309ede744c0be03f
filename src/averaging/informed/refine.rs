//! One refinement of the informed averaging ([`super`]): two Gauss-Newton steps
//! on the rotations with their 3x3 information, the linear translation solve at
//! those rotations, then the joint steps over both ([`crate::averaging::joint`]).

use nalgebra::{Matrix3, Matrix6, Vector3};

use super::InformedOptions;
use crate::averaging::block::{BlockEdge, BlockReport, BlockSystem};
use crate::averaging::cg::StepTolerance;
use crate::averaging::joint::{joint_refine, JointSteps};
use crate::averaging::robust::rotation_vector;
use crate::graph::PoseGraph;
use crate::poses::rigid::rotation_from_axis_angle;

/// Block edges of the rotations (at the current rotations) or of the translations.
fn block_edges(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    active: &[f64],
    rotations: &[Matrix3<f64>],
    rotation_part: bool,
) -> Vec<BlockEdge> {
    graph
        .edges
        .iter()
        .zip(omegas)
        .zip(active)
        .filter(|(_, &a)| a > 0.0)
        .map(|((e, o), &a)| {
            let (r_i, r_j) = (rotations[e.i], rotations[e.j]);
            if rotation_part {
                let r_rel = r_i.tr_mul(&r_j);
                let r0 = rotation_vector(&e.rotation().tr_mul(&r_rel));
                let omega = o.fixed_view::<3, 3>(0, 0).into_owned() * a;
                BlockEdge {
                    i: e.i,
                    j: e.j,
                    b: r_rel.transpose(),
                    omega,
                    r0,
                }
            } else {
                let omega = r_i * o.fixed_view::<3, 3>(3, 3).into_owned() * r_i.transpose() * a;
                let r0 = r_j * e.centre_j - r_i * e.apply(&e.centre_j);
                BlockEdge {
                    i: e.i,
                    j: e.j,
                    b: Matrix3::identity(),
                    omega,
                    r0,
                }
            }
        })
        .collect()
}

/// Two Gauss-Newton steps on the rotations, then the translations; CG iterations.
pub(super) fn refine(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    active: &[f64],
    options: &InformedOptions,
    rotations: &mut [Matrix3<f64>],
    translations: &mut [Vector3<f64>],
) -> usize {
    let mut iterations = 0;
    let max_iter = options.base.cg_max_iter;
    let tolerance = StepTolerance::step(max_iter);
    for _ in 0..2 {
        let edges = block_edges(graph, omegas, active, rotations, true);
        let (delta, report) = solve_blocks(graph.n, edges, None, tolerance);
        iterations += report.iterations;
        for (r, d) in rotations.iter_mut().zip(&delta) {
            *r *= rotation_from_axis_angle(d);
        }
    }
    let edges = block_edges(graph, omegas, active, rotations, false);
    // From the current translations: late rounds move them by a fraction of a sigma.
    let (t, report) = solve_blocks(graph.n, edges, Some(&*translations), tolerance);
    iterations += report.iterations;
    translations.copy_from_slice(&t);
    if options.joint_steps > 0 {
        let joint = joint_refine(
            graph,
            omegas,
            active,
            rotations,
            translations,
            JointSteps {
                steps: options.joint_steps,
                tolerance,
                rotation_prior_rad: options.rotation_prior_rad,
            },
        );
        iterations += joint.cg_iterations;
    }
    iterations
}

/// The least-squares solution of the block edges (with a tiny prior), from `start`.
fn solve_blocks(
    n: usize,
    edges: Vec<BlockEdge>,
    start: Option<&[Vector3<f64>]>,
    tolerance: StepTolerance,
) -> (Vec<Vector3<f64>>, BlockReport) {
    let system = BlockSystem {
        n,
        prior: tiny_prior(&edges),
        edges,
    };
    let rhs = system.gather(|_, e| -(e.omega * e.r0));
    system.solve_auto(&rhs, start, tolerance)
}

/// 1e-9 of the mean information: fixes the free motions without biasing the rest.
fn tiny_prior(edges: &[BlockEdge]) -> f64 {
    let mean = edges.iter().map(|e| e.omega.trace() / 3.0).sum::<f64>() / edges.len().max(1) as f64;
    (1e-9 * mean).max(f64::MIN_POSITIVE)
}
