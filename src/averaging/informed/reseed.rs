//! Node re-seeding between the reweighted rounds of the informed averaging
//! ([`super`]): a node whose incident edges are half outliers can sit in the
//! basin of a bad edge, where the Cauchy rounds keep it (they only descend).
//! Each edge of a node proposes a pose for it (its neighbour's pose composed with
//! the edge); the node moves to the proposal with the least robust cost
//! sum_f a_f ln(1 + (d_f / s)^2) over its incident edges f (d_f the larger
//! Mahalanobis residual, a_f the edge's weight) when that beats its current cost
//! by [`MARGIN`]. The other nodes are held, so a move lowers the graph's robust
//! cost by the same amount: coordinate descent over discrete candidates, the
//! reweighted rounds then polish. Sweeps run until no node moves (at most
//! [`MAX_SWEEPS`]). The scale s is max(`outlier_sigma`, [`SPREAD_FACTOR`] x the
//! median residual), so edges whose sigmas are optimistic (real pairs) do not
//! make every inlier look like an outlier and every node jump.
//!
//! Chains and trees have no redundancy: every proposal fits its edges exactly,
//! costs equal, nothing moves.

use nalgebra::{Matrix3, Matrix6, Vector3};

use crate::averaging::consistency::edge_mahalanobis;
use crate::graph::{Edge, PoseGraph};

/// A move must lower a node's robust cost by this much (natural log units: one
/// edge going from 1.3 s to 0).
pub(super) const MARGIN: f64 = 1.0;
/// Most sweeps over the nodes.
pub(super) const MAX_SWEEPS: usize = 4;
/// The cost's scale is at least this times the median residual of the edges.
pub(super) const SPREAD_FACTOR: f64 = 2.0;

/// What the re-seeding did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Reseeding {
    /// Node moves over all sweeps.
    pub moves: usize,
    pub sweeps: usize,
}

/// Re-seeds the nodes of `graph` in place; `weights` are the edges' weights
/// (0: not used), `mahalanobis` their residuals at the poses given.
pub(super) fn reseed(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    weights: &[f64],
    mahalanobis: &[(f64, f64)],
    outlier_sigma: f64,
    (rotations, translations): (&mut [Matrix3<f64>], &mut [Vector3<f64>]),
) -> Reseeding {
    let scale = cost_scale(mahalanobis, weights, outlier_sigma);
    let mut incident = vec![Vec::new(); graph.n];
    for (k, e) in graph.edges.iter().enumerate() {
        if weights[k] > 0.0 && e.i != e.j {
            incident[e.i].push(k);
            incident[e.j].push(k);
        }
    }
    let mut done = Reseeding::default();
    while done.sweeps < MAX_SWEEPS {
        done.sweeps += 1;
        let mut moved = 0;
        for node in 0..graph.n {
            if incident[node].len() < 2 {
                continue;
            }
            let poses = (&*rotations, &*translations);
            let cost = |pose| {
                node_cost(
                    graph,
                    omegas,
                    weights,
                    &incident[node],
                    node,
                    pose,
                    poses,
                    scale,
                )
            };
            let current = cost((rotations[node], translations[node]));
            let best = incident[node]
                .iter()
                .map(|&k| proposal(&graph.edges[k], node, poses))
                .map(|pose| (cost(pose), pose))
                .min_by(|a, b| a.0.total_cmp(&b.0));
            if let Some((c, (r, t))) = best {
                if c < current - MARGIN {
                    rotations[node] = r;
                    translations[node] = t;
                    moved += 1;
                }
            }
        }
        done.moves += moved;
        if moved == 0 {
            break;
        }
    }
    done
}

/// max(`outlier_sigma`, SPREAD_FACTOR x median of the larger residual of the
/// weighted edges).
fn cost_scale(mahalanobis: &[(f64, f64)], weights: &[f64], outlier_sigma: f64) -> f64 {
    let mut d: Vec<f64> = mahalanobis
        .iter()
        .zip(weights)
        .filter(|(_, &w)| w > 0.0)
        .map(|(&(r, t), _)| r.max(t))
        .filter(|v| v.is_finite())
        .collect();
    if d.is_empty() {
        return outlier_sigma;
    }
    let mid = d.len() / 2;
    let median = *d.select_nth_unstable_by(mid, f64::total_cmp).1;
    outlier_sigma.max(SPREAD_FACTOR * median)
}

/// The pose (R, t) of `node` that edge `e` implies from its other node's pose:
/// M_j = M_i M_ij, M_i = M_j M_ij^-1.
fn proposal(
    e: &Edge,
    node: usize,
    (rotations, translations): (&[Matrix3<f64>], &[Vector3<f64>]),
) -> (Matrix3<f64>, Vector3<f64>) {
    let r_ij = e.rotation();
    if e.j == node {
        let (r_i, t_i) = (rotations[e.i], translations[e.i]);
        (r_i * r_ij, r_i * e.t_ij + t_i)
    } else {
        let (r_j, t_j) = (rotations[e.j], translations[e.j]);
        let r = r_j * r_ij.transpose();
        (r, t_j - r * e.t_ij)
    }
}

/// sum_f a_f ln(1 + (d_f / scale)^2) over the edges incident to `node`, the node
/// at `pose`, the others where they are.
#[allow(clippy::too_many_arguments)]
fn node_cost(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    weights: &[f64],
    incident: &[usize],
    node: usize,
    pose: (Matrix3<f64>, Vector3<f64>),
    (rotations, translations): (&[Matrix3<f64>], &[Vector3<f64>]),
    scale: f64,
) -> f64 {
    incident
        .iter()
        .map(|&k| {
            let e = &graph.edges[k];
            let at = |m: usize| {
                if m == node {
                    (pose.0, pose.1)
                } else {
                    (rotations[m], translations[m])
                }
            };
            let (p_i, p_j) = (at(e.i), at(e.j));
            let (r, t) = edge_mahalanobis(e, &omegas[k], (&p_i.0, &p_i.1), (&p_j.0, &p_j.1));
            weights[k] * (1.0 + (r.max(t) / scale).powi(2)).ln()
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poses::rigid::{from_parts, inverse_rigid};
    use nalgebra::Matrix4;

    fn pose(yaw_deg: f64, t: [f64; 3]) -> Matrix4<f64> {
        let r = *nalgebra::Rotation3::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()).matrix();
        from_parts(&r, &Vector3::from(t))
    }

    /// A star: node 0 joined to four fixed neighbours; two edges are exact,
    /// two are gross outliers, and node 0 starts on one outlier's proposal.
    #[test]
    fn a_node_in_an_outlier_basin_moves_to_the_consensus() {
        let truth = [
            pose(0.1, [0.0, 0.0, 0.0]),
            pose(-0.2, [100.0, 0.0, 1.0]),
            pose(0.3, [0.0, 100.0, -1.0]),
            pose(0.0, [-100.0, 0.0, 2.0]),
            pose(0.2, [0.0, -100.0, 0.0]),
        ];
        let mut edges = Vec::new();
        for (j, bad) in [(1, false), (2, false), (3, true), (4, true)] {
            let mut m = inverse_rigid(&truth[0]) * truth[j];
            if bad {
                m = pose(if j == 3 { 5.0 } else { -4.0 }, [7.0 * j as f64, -9.0, 3.0]) * m;
            }
            edges.push(Edge::new(0, j, m, 0.5, 0.1));
        }
        let graph = PoseGraph { n: 5, edges };
        let omega = Matrix6::from_diagonal(&nalgebra::Vector6::new(1e8, 1e8, 1e8, 1e3, 1e3, 1e3));
        let omegas = vec![omega; 4];
        let weights = vec![1.0; 4];
        let mut rotations: Vec<Matrix3<f64>> = truth
            .iter()
            .map(|m| m.fixed_view::<3, 3>(0, 0).into_owned())
            .collect();
        let mut translations: Vec<Vector3<f64>> = truth
            .iter()
            .map(|m| m.fixed_view::<3, 1>(0, 3).into_owned())
            .collect();
        let (r, t) = proposal(&graph.edges[2], 0, (&rotations, &translations));
        rotations[0] = r;
        translations[0] = t;
        let residuals = crate::averaging::consistency::mahalanobis_residuals(
            &graph,
            &omegas,
            &rotations,
            &translations,
        );
        let done = reseed(
            &graph,
            &omegas,
            &weights,
            &residuals,
            5.0,
            (&mut rotations, &mut translations),
        );
        assert_eq!(done.moves, 1);
        let t0 = truth[0].fixed_view::<3, 1>(0, 3).into_owned();
        assert!(
            (translations[0] - t0).norm() < 1e-9,
            "{:?}",
            translations[0]
        );
    }

    /// In a chain every proposal fits: nothing moves.
    #[test]
    fn a_chain_does_not_move() {
        let edges = vec![
            Edge::new(0, 1, pose(1.0, [99.0, 2.0, 0.0]), 0.5, 0.1),
            Edge::new(1, 2, pose(-0.3, [101.0, -1.0, 0.5]), 0.5, 0.1),
        ];
        let m1 = pose(0.2, [3.0, 1.0, 0.0]) * edges[0].m_ij();
        let poses = [pose(0.2, [3.0, 1.0, 0.0]), m1, m1 * edges[1].m_ij()];
        let graph = PoseGraph { n: 3, edges };
        let omegas = vec![Matrix6::identity() * 1e4; 2];
        let mut rotations: Vec<Matrix3<f64>> = poses
            .iter()
            .map(|m| m.fixed_view::<3, 3>(0, 0).into_owned())
            .collect();
        let mut translations: Vec<Vector3<f64>> = poses
            .iter()
            .map(|m| m.fixed_view::<3, 1>(0, 3).into_owned())
            .collect();
        let before = translations.clone();
        let residuals = crate::averaging::consistency::mahalanobis_residuals(
            &graph,
            &omegas,
            &rotations,
            &translations,
        );
        assert!(residuals.iter().all(|&(r, t)| r < 1e-6 && t < 1e-6));
        let done = reseed(
            &graph,
            &omegas,
            &[1.0, 1.0],
            &residuals,
            5.0,
            (&mut rotations, &mut translations),
        );
        assert_eq!(done.moves, 0);
        assert_eq!(translations, before);
    }
}
