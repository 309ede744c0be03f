//! Per-node standard errors from the joint normal equations ([`super`]): the
//! marginal covariance of each node's (rotation, shift at its pivot) in the mean
//! gauge of its component (the six rigid motions projected out: C = P H^+ P).
//! Unlike the decoupled covariance ([`crate::averaging::covariance`]), which gives
//! the shift *given* the rotations, this one carries the rotation uncertainty of
//! a block of tiles into the shifts of its far tiles. Exact: a dense inverse of
//! the 6n x 6n matrix up to `exact_max_nodes / 2` nodes, above that selected
//! inversion of a sparse factor within a fixed budget ([`selected`]); graphs
//! over that budget are sampled as in the decoupled case: x = H^+ J^T
//! Omega^(1/2) xi has covariance H^+ (about 1 / sqrt(2 samples) relative error
//! per sigma).

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Vector3, Vector6};

use super::{linearise, pivots, JointSystem};
use crate::averaging::cg::StepTolerance;
use crate::averaging::covariance::{gauge_free_inverse, CovarianceMethod, NodeSigma};
use crate::averaging::direct::Budget;
use crate::averaging::marginals::{
    dense, gauge_free_marginals, project_out, to_mean_gauge, ComponentMotions,
};
use crate::graph::PoseGraph;
use crate::rng::SplitMix64;

/// Standard errors of every node from the weighted edge information `omegas`
/// (zero for edges left out) at the final poses; infinite for nodes in no edge.
pub(crate) fn joint_node_sigmas(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    rotations: &[Matrix3<f64>],
    translations: &[Vector3<f64>],
    components: &[Vec<usize>],
    method: CovarianceMethod,
) -> Vec<NodeSigma> {
    let active: Vec<f64> = omegas.iter().map(|o| f64::from(o.amax() > 0.0)).collect();
    let pivots = pivots(graph, &active, rotations, translations);
    let system = linearise(graph, omegas, &active, rotations, translations, &pivots);
    let null = null_space(&pivots, components);
    let variances = if graph.n <= method.exact_max_nodes / 2 {
        exact(&system, &null)
    } else if let Some(variances) = selected(&system, &null) {
        variances
    } else {
        sampled(&system, &null, method)
    };
    let mut linked = vec![false; graph.n];
    for members in components.iter().filter(|m| m.len() > 1) {
        members.iter().for_each(|&k| linked[k] = true);
    }
    variances
        .iter()
        .zip(&linked)
        .map(|(v, &linked)| {
            if !linked {
                return NodeSigma {
                    shift_m: [f64::INFINITY; 3],
                    rotation_deg: [f64::INFINITY; 3],
                };
            }
            NodeSigma {
                shift_m: [3, 4, 5].map(|a| v[a].max(0.0).sqrt()),
                rotation_deg: [0, 1, 2].map(|a| v[a].max(0.0).sqrt().to_degrees()),
            }
        })
        .collect()
}

/// The six rigid motions of each component (turns about its mean pivot, shifts),
/// orthonormal over all 6n unknowns; stored per component (a dense 6n vector per
/// component and motion would be quadratic in a graph of many components).
pub(super) fn null_space<'a>(
    pivots: &[Vector3<f64>],
    components: &'a [Vec<usize>],
) -> Vec<ComponentMotions<'a, 6>> {
    let dot = |a: &[Vector6<f64>], b: &[Vector6<f64>]| -> f64 {
        a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
    };
    components
        .iter()
        .map(|members| {
            let centre = members.iter().map(|&k| pivots[k]).sum::<Vector3<f64>>()
                / members.len().max(1) as f64;
            let mut basis: Vec<Vec<Vector6<f64>>> = Vec::new();
            for a in 0..6 {
                let unit = Vector3::ith(a % 3, 1.0);
                let mut v: Vec<Vector6<f64>> = members
                    .iter()
                    .map(|&k| {
                        if a < 3 {
                            let shift = unit.cross(&(pivots[k] - centre));
                            Vector6::new(unit.x, unit.y, unit.z, shift.x, shift.y, shift.z)
                        } else {
                            Vector6::new(0.0, 0.0, 0.0, unit.x, unit.y, unit.z)
                        }
                    })
                    .collect();
                for b in &basis {
                    let c = dot(&v, b);
                    v.iter_mut().zip(b).for_each(|(x, y)| *x -= y * c);
                }
                let norm = dot(&v, &v).sqrt();
                if norm > 1e-12 {
                    v.iter_mut().for_each(|x| *x /= norm);
                    basis.push(v);
                }
            }
            // the mean gauge: mean rotation and mean shift zero
            let conditions = (0..6)
                .map(|a| vec![Vector6::ith(a, 1.0); members.len()])
                .collect();
            ComponentMotions {
                members,
                basis,
                conditions,
            }
        })
        .collect()
}

/// Block updates (6 x 6 products) the exact marginals may spend: about a
/// second of factor and selected inversion, whatever the graph's shape (this
/// path serves graphs up to `informed::JOINT_COVARIANCE_MAX_NODES`).
const SELECTED_MAX_UPDATES: usize = 4_000_000;
/// Off-diagonal blocks the factor may keep (the inversion keeps as many again).
const SELECTED_MAX_BLOCKS: usize = 200_000;

/// Exact gauge-free marginals by selected inversion (`marginals`) within a
/// fixed budget; None when over it.
pub(super) fn selected(
    system: &JointSystem,
    motions: &[ComponentMotions<6>],
) -> Option<Vec<Vector6<f64>>> {
    let mut diagonal = vec![Matrix6::zeros(); system.n];
    for e in &system.edges {
        diagonal[e.i] += e.a_i.tr_mul(&(e.omega * e.a_i));
        diagonal[e.j] += e.a_j.tr_mul(&(e.omega * e.a_j));
    }
    let links = system
        .edges
        .iter()
        .map(|e| (e.i, e.j, e.a_i.tr_mul(&(e.omega * e.a_j))));
    let budget = Budget {
        max_blocks: SELECTED_MAX_BLOCKS,
        max_updates: SELECTED_MAX_UPDATES,
    };
    gauge_free_marginals(diagonal, links, motions, budget)
}

pub(super) fn exact(system: &JointSystem, motions: &[ComponentMotions<6>]) -> Vec<Vector6<f64>> {
    let n = system.n;
    let null = dense(n, motions);
    let mut h = DMatrix::<f64>::zeros(6 * n, 6 * n);
    let mut add = |r: usize, c: usize, m: &Matrix6<f64>| {
        let mut view = h.view_mut((6 * r, 6 * c), (6, 6));
        view += m;
    };
    for e in &system.edges {
        let (oi, oj) = (e.omega * e.a_i, e.omega * e.a_j);
        add(e.i, e.i, &e.a_i.tr_mul(&oi));
        add(e.j, e.j, &e.a_j.tr_mul(&oj));
        add(e.i, e.j, &e.a_i.tr_mul(&oj));
        add(e.j, e.i, &e.a_j.tr_mul(&oi));
    }
    let flat: Vec<DVector<f64>> = null
        .iter()
        .map(|v| DVector::from_iterator(6 * n, v.iter().flat_map(|b| b.iter().copied())))
        .collect();
    let Some(mut c) = gauge_free_inverse(h, &flat) else {
        return vec![Vector6::repeat(f64::INFINITY); n];
    };
    // to the mean gauge (marginals' module doc): P C P^T, columns then rows
    for _ in 0..2 {
        for j in 0..6 * n {
            let mut x: Vec<Vector6<f64>> = (0..n)
                .map(|k| c.fixed_view::<6, 1>(6 * k, j).into_owned())
                .collect();
            to_mean_gauge(&mut x, motions);
            for (k, v) in x.iter().enumerate() {
                c.fixed_view_mut::<6, 1>(6 * k, j).copy_from(v);
            }
        }
        c.transpose_mut();
    }
    (0..n)
        .map(|k| Vector6::from_fn(|a, _| c[(6 * k + a, 6 * k + a)]))
        .collect()
}

fn sampled(
    system: &JointSystem,
    null: &[ComponentMotions<6>],
    method: CovarianceMethod,
) -> Vec<Vector6<f64>> {
    let roots: Vec<Matrix6<f64>> = system
        .edges
        .iter()
        .map(|e| {
            e.omega
                .cholesky()
                .map(|c| c.l())
                .unwrap_or_else(Matrix6::zeros)
        })
        .collect();
    let mut rng = SplitMix64::new(method.seed);
    let mut sum = vec![Vector6::zeros(); system.n];
    let samples = method.samples.max(1);
    for _ in 0..samples {
        let mut rhs = vec![Vector6::zeros(); system.n];
        for (e, l) in system.edges.iter().zip(&roots) {
            let w = l * Vector6::from_fn(|_, _| rng.normal());
            rhs[e.i] += e.a_i.tr_mul(&w);
            rhs[e.j] += e.a_j.tr_mul(&w);
        }
        project_out(&mut rhs, null);
        let (mut x, _, _) = system.solve(&rhs, StepTolerance::sample(20_000));
        project_out(&mut x, null);
        to_mean_gauge(&mut x, null);
        sum.iter_mut()
            .zip(&x)
            .for_each(|(s, v)| *s += v.component_mul(v));
    }
    sum.into_iter().map(|s| s / samples as f64).collect()
}
