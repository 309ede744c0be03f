//! Whether the edges agree with the rest of the graph: each edge's Mahalanobis
//! residual (rotation and translation, in its own sigmas) at the current poses,
//! the round's outliers (cut, or down-weighted where cutting would split the
//! graph), the components the kept edges form, and the a-posteriori variance of
//! unit weight that says whether the sigmas are honest.

use nalgebra::{Matrix3, Matrix6, Vector3};

use super::informed::{EdgeInformation, InformedOptions};
use super::robust::rotation_vector;
use crate::graph::{Edge, PoseGraph, UnionFind};

/// The a-posteriori variance of unit weight of the edges kept at full weight:
/// the sum of their squared Mahalanobis residuals (rotation and translation)
/// over the redundancy 6 (E - N + C) of the graph they form (each edge measures
/// six numbers, each node has six unknowns, one gauge per component). None when
/// the kept edges form a forest (nothing to compare).
pub fn variance_factor(
    graph: &PoseGraph,
    mahalanobis: &[(f64, f64)],
    active: &[f64],
    components: &[Vec<usize>],
) -> Option<f64> {
    let kept: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| active[k] >= 0.999)
        .collect();
    let nodes: usize = components
        .iter()
        .filter(|c| c.len() > 1)
        .map(|c| c.len())
        .sum();
    let linked = components.iter().filter(|c| c.len() > 1).count();
    let redundancy = (kept.len() + linked)
        .checked_sub(nodes)
        .filter(|&r| r > 0)?;
    let sum: f64 = kept
        .iter()
        .map(|&k| mahalanobis[k].0.powi(2) + mahalanobis[k].1.powi(2))
        .sum();
    Some(sum / (6 * redundancy) as f64)
}

/// sqrt(r^T Omega r) of the rotation and translation residuals of every edge
/// (information without the reliability factor's floor effect: as given).
pub(super) fn mahalanobis_residuals(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    rotations: &[Matrix3<f64>],
    translations: &[Vector3<f64>],
) -> Vec<(f64, f64)> {
    graph
        .edges
        .iter()
        .zip(omegas)
        .map(|(e, o)| {
            let pose_i = (&rotations[e.i], &translations[e.i]);
            let pose_j = (&rotations[e.j], &translations[e.j]);
            edge_mahalanobis(e, o, pose_i, pose_j)
        })
        .collect()
}

/// The (rotation, translation) Mahalanobis residual of one edge at the poses
/// (R, t) of its nodes i and j.
pub(super) fn edge_mahalanobis(
    e: &Edge,
    omega: &Matrix6<f64>,
    (r_i, t_i): (&Matrix3<f64>, &Vector3<f64>),
    (r_j, t_j): (&Matrix3<f64>, &Vector3<f64>),
) -> (f64, f64) {
    let rr = rotation_vector(&e.rotation().tr_mul(&r_i.tr_mul(r_j)));
    let rt = r_i.tr_mul(&(r_j * e.centre_j + t_j - t_i)) - e.apply(&e.centre_j);
    let q = |m: Matrix3<f64>, v: Vector3<f64>| (v.transpose() * m * v)[(0, 0)].max(0.0).sqrt();
    (
        q(omega.fixed_view::<3, 3>(0, 0).into_owned(), rr),
        q(omega.fixed_view::<3, 3>(3, 3).into_owned(), rt),
    )
}

pub(super) type Round = (Vec<usize>, Vec<(usize, f64)>);

/// This round's outliers: each edge over the limit that is the worst over the
/// limit at both its nodes (an edge beside a worse one may only be bent by it:
/// it is judged again next round, after the worse one is gone); those that would
/// split a component are down-weighted instead, the least bad first.
pub(super) fn select(
    graph: &PoseGraph,
    active: &[f64],
    residuals: &[(f64, f64)],
    options: &InformedOptions,
) -> Round {
    let live: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| active[k] >= 1e-12)
        .collect();
    let mut values: Vec<f64> = live
        .iter()
        .map(|&k| residuals[k].0.max(residuals[k].1))
        .collect();
    if values.is_empty() {
        return (Vec::new(), Vec::new());
    }
    let mid = values.len() / 2;
    let median = *values.select_nth_unstable_by(mid, f64::total_cmp).1;
    let limit = options.outlier_sigma.max(options.outlier_k * median);
    let bad = |k: usize| residuals[k].0.max(residuals[k].1) / limit;
    let mut outliers: Vec<usize> = live
        .iter()
        .copied()
        .filter(|&k| bad(k) > 1.0 && active[k] >= 0.999)
        .collect();
    let mut worst_at = vec![0.0f64; graph.n];
    for &k in &outliers {
        let e = &graph.edges[k];
        worst_at[e.i] = worst_at[e.i].max(bad(k));
        worst_at[e.j] = worst_at[e.j].max(bad(k));
    }
    outliers.retain(|&k| {
        let e = &graph.edges[k];
        bad(k) >= worst_at[e.i] && bad(k) >= worst_at[e.j]
    });
    outliers.sort_by(|&a, &b| bad(b).total_cmp(&bad(a)).then(a.cmp(&b)));
    let chosen = outliers;
    let mut is_chosen = vec![false; graph.edges.len()];
    chosen.iter().for_each(|&k| is_chosen[k] = true);
    let mut sets = UnionFind::new(graph.n);
    for &k in &live {
        if !is_chosen[k] {
            sets.union(graph.edges[k].i, graph.edges[k].j);
        }
    }
    let (mut dropped, mut downweighted) = (Vec::new(), Vec::new());
    for &k in chosen.iter().rev() {
        if sets.union(graph.edges[k].i, graph.edges[k].j) {
            downweighted.push((k, 1.0 / bad(k)));
        } else {
            dropped.push(k);
        }
    }
    (dropped, downweighted)
}

pub(super) fn active_components(graph: &PoseGraph, active: &[f64]) -> Vec<Vec<usize>> {
    let pairs = graph
        .edges
        .iter()
        .zip(active)
        .filter(|(_, &a)| a > 0.0)
        .map(|(e, _)| (e.i, e.j));
    crate::graph::Components::new(graph.n, pairs).members
}

/// The weight factor of the edges not `reliable` (did not converge, ambiguous):
/// the ratio of the median squared Mahalanobis residual (rotation and
/// translation, at their full information) of the reliable edges to theirs, at
/// the current poses, clamped to [`InformedOptions::unreliable_factor`], 1]. An
/// unconverged pair that stopped 30 cm off where converged ones are 6 cm off
/// gets ~1/25 of its information: the variance-component estimate of its class,
/// robust to the outliers among them (medians). With fewer than 10 edges in
/// either class: the floor.
pub(super) fn unreliable_weight(
    information: &[EdgeInformation],
    mahalanobis: &[(f64, f64)],
    usable: &[f64],
    options: &InformedOptions,
) -> f64 {
    let floor = options.unreliable_factor;
    let class = |reliable: bool, scale: f64| {
        let mut d2: Vec<f64> = (0..information.len())
            .filter(|&k| information[k].reliable == reliable && usable[k] > 0.0)
            .map(|k| (mahalanobis[k].0.powi(2) + mahalanobis[k].1.powi(2)) / scale)
            .filter(|v| v.is_finite())
            .collect();
        if d2.len() < 10 {
            return None;
        }
        let mid = d2.len() / 2;
        Some(*d2.select_nth_unstable_by(mid, f64::total_cmp).1)
    };
    match (class(true, 1.0), class(false, floor)) {
        (Some(good), Some(weak)) if weak > 0.0 => (good / weak).clamp(floor, 1.0),
        _ => floor,
    }
}
