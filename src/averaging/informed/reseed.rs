//! Re-seeding between the reweighted rounds of the informed averaging
//! ([`super`]): a node, or a group of nodes, whose edges to the rest are half
//! outliers can sit in the basin of a bad edge, where the Cauchy rounds keep it
//! (they only descend). The groups are the pieces the consistent edges
//! (larger Mahalanobis residual below the scale s) hold together once their
//! bridges are cut: a group hanging on one consistent edge is not checked by
//! any cycle. Every edge from a group (but the largest) to the rest proposes a
//! rigid move of the group (the pose its far node implies for its near one);
//! the group takes the proposal with the least robust cost
//! sum_f a_f ln(1 + (d_f / s)^2) over its boundary edges f (d_f the larger
//! Mahalanobis residual, a_f the edge's weight) when that beats its current
//! cost by [`MARGIN`]. The rest is held and the group's inner edges do not
//! change, so a move lowers the graph's robust cost by the same amount:
//! descent over discrete candidates; the reweighted rounds then polish.
//! Sweeps run until no group moves (at most [`MAX_SWEEPS`]). The scale s is
//! max(`outlier_sigma`, [`SPREAD_FACTOR`] x the median residual), so edges whose
//! sigmas are optimistic (real pairs) do not make every inlier look like an
//! outlier.
//!
//! Chains and trees have no redundancy: every proposal fits its edges exactly,
//! costs equal, nothing moves. Known limit: a path of nodes hanging on an
//! outlier is all bridges, so it moves node by node, and a node whose one
//! consistent edge holds it to the rest cannot move alone (its inner edge
//! objects); only 2-edge-connected groups move as one.

use nalgebra::{Matrix3, Matrix6, Vector3};

use crate::averaging::consistency::{edge_mahalanobis, mahalanobis_residuals};
use crate::graph::{bridges, Components, Edge, PoseGraph};

/// A move must lower a group's robust cost by this much (natural log units:
/// one edge going from 1.3 s to 0).
pub(super) const MARGIN: f64 = 1.0;
/// A dropped edge is unopposed when moving its node to its proposal raises
/// the cost of the node's kept edges by at most this (natural log units).
pub(super) const UNOPPOSED: f64 = 1.0;
/// Most sweeps over the groups.
pub(super) const MAX_SWEEPS: usize = 4;
/// The cost's scale is at least this times the median residual of the edges.
pub(super) const SPREAD_FACTOR: f64 = 2.0;

/// What the re-seeding did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Reseeding {
    /// Group moves over all sweeps.
    pub moves: usize,
    /// Nodes moved over all sweeps.
    pub nodes_moved: usize,
    pub sweeps: usize,
}

/// Poses as rotations and translations, M = [R t].
type Poses<'a> = (&'a mut [Matrix3<f64>], &'a mut [Vector3<f64>]);

/// Re-seeds the nodes of `graph` in place; `weights` are the edges' weights
/// (0: not used), `mahalanobis` their residuals at the poses given.
pub(super) fn reseed(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    weights: &[f64],
    mahalanobis: &[(f64, f64)],
    outlier_sigma: f64,
    (rotations, translations): Poses,
) -> Reseeding {
    let scale = cost_scale(mahalanobis, weights, outlier_sigma);
    let mut residuals = mahalanobis.to_vec();
    let mut done = Reseeding::default();
    while done.sweeps < MAX_SWEEPS {
        done.sweeps += 1;
        let groups = groups(graph, weights, &residuals, scale);
        let largest = (0..groups.members.len())
            .max_by_key(|&c| groups.members[c].len())
            .unwrap_or(0);
        let mut boundary = vec![Vec::new(); groups.members.len()];
        for (k, e) in graph.edges.iter().enumerate() {
            let (a, b) = (groups.component_of[e.i], groups.component_of[e.j]);
            if weights[k] > 0.0 && a != b {
                boundary[a].push(k);
                boundary[b].push(k);
            }
        }
        let mut moved = 0;
        for (c, members) in groups.members.iter().enumerate() {
            if c == largest {
                continue;
            }
            let boundary = &boundary[c];
            let inside = |m: usize| groups.component_of[m] == c;
            let candidates = Candidates {
                graph,
                omegas,
                weights,
                boundary,
                scale,
            };
            if let Some(g) = candidates.best_move(&inside, (rotations, translations)) {
                for &m in members {
                    translations[m] = g.0 * translations[m] + g.1;
                    rotations[m] = g.0 * rotations[m];
                }
                moved += 1;
                done.nodes_moved += members.len();
            }
        }
        done.moves += moved;
        if moved == 0 {
            break;
        }
        residuals = mahalanobis_residuals(graph, omegas, rotations, translations);
    }
    done
}

/// Dropped edges that no kept edge opposes: an edge `k` (usable, not active)
/// inconsistent at the current poses whose proposal for one of its nodes leaves
/// that node's active edges as content as they are now (cost up by at most
/// [`UNOPPOSED`]): the kept edges know nothing along the directions it fixes
/// (flat fields: x, y and yaw), so it was dropped only because the node sat
/// where a worse edge had put it. The node moves to the proposal; the edges are
/// returned, to be readmitted. One node per edge, each node at most once.
pub(super) fn unopposed(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    (active, usable): (&[f64], &[f64]),
    mahalanobis: &[(f64, f64)],
    outlier_sigma: f64,
    (rotations, translations): Poses,
) -> Vec<usize> {
    let scale = cost_scale(mahalanobis, active, outlier_sigma);
    let mut incident = vec![Vec::new(); graph.n];
    for (k, e) in graph.edges.iter().enumerate() {
        if active[k] > 0.0 && e.i != e.j {
            incident[e.i].push(k);
            incident[e.j].push(k);
        }
    }
    let mut moved = vec![false; graph.n];
    let mut back = Vec::new();
    for (k, e) in graph.edges.iter().enumerate() {
        let (r, t) = mahalanobis[k];
        if active[k] > 0.0 || usable[k] <= 0.0 || e.i == e.j || r.max(t) < scale {
            continue;
        }
        for node in [e.i, e.j] {
            if moved[node] {
                continue;
            }
            let inside = |m: usize| m == node;
            let candidates = Candidates {
                graph,
                omegas,
                weights: active,
                boundary: &incident[node],
                scale,
            };
            let poses = (&*rotations, &*translations);
            let stay = (Matrix3::identity(), Vector3::zeros());
            let (p_r, p_t) = proposal(e, node, poses);
            let r_g = p_r * rotations[node].transpose();
            let g = (r_g, p_t - r_g * translations[node]);
            if candidates.cost(&inside, &g, poses)
                <= candidates.cost(&inside, &stay, poses) + UNOPPOSED
            {
                rotations[node] = p_r;
                translations[node] = p_t;
                moved[node] = true;
                back.push(k);
                break;
            }
        }
    }
    back
}

/// The groups the consistent edges (larger residual below `scale`) hold together
/// once their bridges are cut.
fn groups(graph: &PoseGraph, weights: &[f64], residuals: &[(f64, f64)], scale: f64) -> Components {
    let pairs: Vec<(usize, usize)> = graph.edges.iter().map(|e| (e.i, e.j)).collect();
    let consistent: Vec<bool> = (0..pairs.len())
        .map(|k| weights[k] > 0.0 && residuals[k].0.max(residuals[k].1) < scale)
        .collect();
    let bridge = bridges(graph.n, &pairs, &consistent);
    Components::new(
        graph.n,
        (0..pairs.len())
            .filter(|&k| consistent[k] && !bridge[k])
            .map(|k| pairs[k]),
    )
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

/// The rigid moves one group's boundary edges propose, and their costs.
struct Candidates<'a> {
    graph: &'a PoseGraph,
    omegas: &'a [Matrix6<f64>],
    weights: &'a [f64],
    boundary: &'a [usize],
    scale: f64,
}

/// A rigid move G = (R_g, t_g) applied on the left: M' = G M.
type Move = (Matrix3<f64>, Vector3<f64>);

impl Candidates<'_> {
    /// The proposal with the least cost, if it beats staying by MARGIN.
    fn best_move(
        &self,
        inside: &dyn Fn(usize) -> bool,
        (rotations, translations): (&[Matrix3<f64>], &[Vector3<f64>]),
    ) -> Option<Move> {
        let poses = (rotations, translations);
        let stay = (Matrix3::identity(), Vector3::zeros());
        let current = self.cost(inside, &stay, poses);
        self.boundary
            .iter()
            .map(|&k| {
                let e = &self.graph.edges[k];
                let near = if inside(e.i) { e.i } else { e.j };
                let (r, t) = proposal(e, near, poses);
                let r_g = r * rotations[near].transpose();
                (r_g, t - r_g * translations[near])
            })
            .map(|g| (self.cost(inside, &g, poses), g))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .filter(|(c, _)| *c < current - MARGIN)
            .map(|(_, g)| g)
    }

    /// sum_f a_f ln(1 + (d_f / scale)^2) over the boundary edges, the group
    /// moved by `g`.
    fn cost(
        &self,
        inside: &dyn Fn(usize) -> bool,
        g: &Move,
        (rotations, translations): (&[Matrix3<f64>], &[Vector3<f64>]),
    ) -> f64 {
        let at = |m: usize| {
            if inside(m) {
                (g.0 * rotations[m], g.0 * translations[m] + g.1)
            } else {
                (rotations[m], translations[m])
            }
        };
        self.boundary
            .iter()
            .map(|&k| {
                let e = &self.graph.edges[k];
                let (p_i, p_j) = (at(e.i), at(e.j));
                let (r, t) =
                    edge_mahalanobis(e, &self.omegas[k], (&p_i.0, &p_i.1), (&p_j.0, &p_j.1));
                self.weights[k] * (1.0 + (r.max(t) / self.scale).powi(2)).ln()
            })
            .sum()
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poses::rigid::{from_parts, inverse_rigid};
    use nalgebra::Matrix4;

    fn pose(yaw_deg: f64, t: [f64; 3]) -> Matrix4<f64> {
        let r = *nalgebra::Rotation3::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()).matrix();
        from_parts(&r, &Vector3::from(t))
    }

    /// The rotations and translations of `poses`.
    fn parts(poses: &[Matrix4<f64>]) -> (Vec<Matrix3<f64>>, Vec<Vector3<f64>>) {
        let rotations = poses
            .iter()
            .map(|m| m.fixed_view::<3, 3>(0, 0).into_owned())
            .collect();
        let translations = poses
            .iter()
            .map(|m| m.fixed_view::<3, 1>(0, 3).into_owned())
            .collect();
        (rotations, translations)
    }

    /// Re-seeds from the poses given (scale 5), residuals taken there.
    fn reseed_from(
        graph: &PoseGraph,
        omegas: &[Matrix6<f64>],
        weights: &[f64],
        (rotations, translations): Poses,
    ) -> Reseeding {
        let residuals = crate::averaging::consistency::mahalanobis_residuals(
            graph,
            omegas,
            rotations,
            translations,
        );
        reseed(
            graph,
            omegas,
            weights,
            &residuals,
            5.0,
            (rotations, translations),
        )
    }

    /// A star: node 0 joined to four neighbours that a ring of exact edges
    /// holds; two of node 0's edges are exact, two are gross outliers, and node 0
    /// starts on one outlier's proposal (so that outlier is its only consistent
    /// edge: a bridge, and node 0 a group of its own).
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
        // the neighbours' ring, exact: most edges of the graph fit
        for (i, j) in [(1, 2), (2, 3), (3, 4), (4, 1)] {
            edges.push(Edge::new(
                i,
                j,
                inverse_rigid(&truth[i]) * truth[j],
                0.5,
                0.1,
            ));
        }
        let graph = PoseGraph { n: 5, edges };
        let omega = Matrix6::from_diagonal(&nalgebra::Vector6::new(1e8, 1e8, 1e8, 1e3, 1e3, 1e3));
        let omegas = vec![omega; 8];
        let weights = vec![1.0; 8];
        let (mut rotations, mut translations) = parts(&truth);
        let (r, t) = proposal(&graph.edges[2], 0, (&rotations, &translations));
        rotations[0] = r;
        translations[0] = t;
        let done = reseed_from(
            &graph,
            &omegas,
            &weights,
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

    /// A triangle of exact edges hangs on an outlier edge (moved rigidly to
    /// its proposal) while two exact edges from the rest disagree: the three
    /// nodes move back as one group. (A path hanging on the outlier would be
    /// all bridges: groups are 2-edge-connected, a known limit.)
    #[test]
    fn a_group_on_an_outlier_bridge_moves_back_as_one() {
        let truth: Vec<Matrix4<f64>> = (0..8)
            .map(|k| {
                pose(
                    0.1 * k as f64,
                    [100.0 * (k % 3) as f64, 80.0 * (k / 3) as f64, 0.5],
                )
            })
            .collect();
        let exact =
            |i: usize, j: usize| Edge::new(i, j, inverse_rigid(&truth[i]) * truth[j], 0.5, 0.1);
        let mut edges: Vec<Edge> = [
            (0, 1),
            (1, 2),
            (2, 3),
            (3, 0),
            (0, 2),
            (1, 3),
            (5, 6),
            (6, 7),
            (5, 7),
            (1, 5),
            (2, 6),
        ]
        .iter()
        .map(|&(i, j)| exact(i, j))
        .collect();
        let bad = pose(4.0, [12.0, -7.0, 2.0]) * inverse_rigid(&truth[3]) * truth[5];
        edges.push(Edge::new(3, 5, bad, 0.5, 0.1));
        let graph = PoseGraph { n: 8, edges };
        let omegas = vec![Matrix6::identity() * 1e4; graph.edges.len()];
        let weights = vec![1.0; graph.edges.len()];
        let (mut rotations, mut translations) = parts(&truth);
        let (r5, t5) = proposal(&graph.edges[11], 5, (&rotations, &translations));
        let r_g = r5 * rotations[5].transpose();
        let t_g = t5 - r_g * translations[5];
        for m in [5, 6, 7] {
            translations[m] = r_g * translations[m] + t_g;
            rotations[m] = r_g * rotations[m];
        }
        let done = reseed_from(
            &graph,
            &omegas,
            &weights,
            (&mut rotations, &mut translations),
        );
        assert_eq!((done.moves, done.nodes_moved), (1, 3));
        for m in [5, 6, 7] {
            let t = truth[m].fixed_view::<3, 1>(0, 3).into_owned();
            assert!(
                (translations[m] - t).norm() < 1e-9,
                "node {m}: {:?}",
                translations[m]
            );
        }
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
        let (mut rotations, mut translations) = parts(&poses);
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
