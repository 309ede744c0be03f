//! Edge residuals and outlier rejection. The residual of edge (i, j) compares the
//! averaged relative pose M_i^-1 M_j with the measured M_ij: rotation angle in degrees
//! and translation offset in metres. An edge is an outlier when either exceeds
//! max(k * median, floor) over the active edges. Each round rejects only the clear
//! culprits: edges at least half as bad as the worst, and no two sharing a node (an
//! outlier's error leaks into its neighbours' residuals; re-solving shows the truth).
//! A rejection that would disconnect a component is turned into a down-weighting
//! (w *= threshold / residual), chosen Kruskal-style so the least bad edges keep the
//! graph connected.

use super::EdgeResidual;
use crate::graph::{PoseGraph, UnionFind};
use crate::poses::rigid::{rotation, rotation_between_deg, translation};
use nalgebra::Matrix4;

/// Residuals of every edge (active or not) against the poses.
pub fn edge_residuals(graph: &PoseGraph, poses: &[Matrix4<f64>]) -> Vec<EdgeResidual> {
    graph
        .edges
        .iter()
        .map(|e| {
            // M_i^-1 M_j = [R_i^T R_j, R_i^T (t_j - t_i)]
            let r_i = rotation(&poses[e.i]);
            let r_est = r_i.tr_mul(&rotation(&poses[e.j]));
            let t_est = r_i.tr_mul(&(translation(&poses[e.j]) - translation(&poses[e.i])));
            EdgeResidual {
                rotation_deg: rotation_between_deg(&rotation(&e.m_ij), &r_est),
                translation_m: (t_est - translation(&e.m_ij)).norm(),
            }
        })
        .collect()
}

#[derive(Clone, Copy, Debug)]
pub(crate) struct OutlierRule {
    pub k: f64,
    pub floor_m: f64,
    pub floor_deg: f64,
}

/// What one round decided: edges to drop, and bridges to keep with a weight factor.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct OutlierRound {
    pub dropped: Vec<usize>,
    pub downweighted: Vec<(usize, f64)>,
}

/// Picks this round's outliers among the active (weight > 0), unprotected edges.
pub(crate) fn select_outliers(
    graph: &PoseGraph,
    weights: &[f64],
    residuals: &[EdgeResidual],
    protected: &[bool],
    rule: OutlierRule,
) -> OutlierRound {
    let candidates_pool: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| weights[k] > 0.0 && !protected[k])
        .collect();
    let median_of = |f: &dyn Fn(&EdgeResidual) -> f64| {
        let mut values: Vec<f64> = candidates_pool.iter().map(|&k| f(&residuals[k])).collect();
        if values.is_empty() {
            return 0.0;
        }
        let mid = values.len() / 2;
        *values.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    let limit_m = (rule.k * median_of(&|r| r.translation_m)).max(rule.floor_m);
    let limit_deg = (rule.k * median_of(&|r| r.rotation_deg)).max(rule.floor_deg);
    let badness: Vec<f64> = residuals
        .iter()
        .map(|r| (r.translation_m / limit_m).max(r.rotation_deg / limit_deg))
        .collect();
    let mut outliers: Vec<usize> = candidates_pool
        .into_iter()
        .filter(|&k| badness[k] > 1.0)
        .collect();
    if outliers.is_empty() {
        return OutlierRound::default();
    }
    outliers.sort_by(|&a, &b| badness[b].total_cmp(&badness[a]).then(a.cmp(&b)));
    let worst = badness[outliers[0]];
    let mut touched = vec![false; graph.n];
    let mut chosen = Vec::new();
    for &k in outliers.iter().take_while(|&&k| badness[k] >= 0.5 * worst) {
        let e = &graph.edges[k];
        if !touched[e.i] && !touched[e.j] {
            touched[e.i] = true;
            touched[e.j] = true;
            chosen.push(k);
        }
    }
    keep_connected(graph, weights, &chosen, &badness)
}

/// Splits `chosen` into drops and down-weighted bridges so that the active graph keeps
/// its components: every other active edge joins first, then the chosen ones from the
/// least bad, each kept only if it joins two still separate parts.
fn keep_connected(
    graph: &PoseGraph,
    weights: &[f64],
    chosen: &[usize],
    badness: &[f64],
) -> OutlierRound {
    let mut is_chosen = vec![false; graph.edges.len()];
    chosen.iter().for_each(|&k| is_chosen[k] = true);
    let mut sets = UnionFind::new(graph.n);
    for (k, e) in graph.edges.iter().enumerate() {
        if weights[k] > 0.0 && !is_chosen[k] {
            sets.union(e.i, e.j);
        }
    }
    let mut round = OutlierRound::default();
    for &k in chosen.iter().rev() {
        let e = &graph.edges[k];
        if sets.union(e.i, e.j) {
            round.downweighted.push((k, 1.0 / badness[k]));
        } else {
            round.dropped.push(k);
        }
    }
    round.dropped.sort_unstable();
    round
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::averaging::synthetic::{generate, SyntheticSpec, Topology};

    const RULE: OutlierRule = OutlierRule {
        k: 5.0,
        floor_m: 0.05,
        floor_deg: 0.005,
    };

    fn residual(translation_m: f64) -> EdgeResidual {
        EdgeResidual {
            rotation_deg: 0.0,
            translation_m,
        }
    }

    #[test]
    fn residuals_vanish_for_the_truth_and_see_a_bad_edge() {
        let mut g = generate(&SyntheticSpec::exact(20, Topology::Chain { reach: 2 }, 1));
        g.graph.edges[3].m_ij[(0, 3)] += 5.0;
        let residuals = edge_residuals(&g.graph, &g.truth);
        for (k, r) in residuals.iter().enumerate() {
            let expected = if k == 3 { 5.0 } else { 0.0 };
            assert!(
                (r.translation_m - expected).abs() < 1e-9 && r.rotation_deg < 1e-9,
                "{k}: {r:?}"
            );
        }
    }

    #[test]
    fn the_worst_edges_go_first_and_neighbours_wait() {
        // Chain of 21 nodes, each joined to the next two; node 20 hangs on the bridge (19, 20).
        let mut g = generate(&SyntheticSpec::exact(21, Topology::Chain { reach: 2 }, 1));
        g.graph.edges.remove(37); // (18, 20)
        assert_eq!((g.graph.edges[37].i, g.graph.edges[37].j), (19, 20));
        let weights = vec![1.0; 38];
        let protected = vec![false; 38];
        let with = |bad: &[(usize, f64)]| {
            let mut r = vec![residual(0.01); 38];
            bad.iter().for_each(|&(k, v)| r[k] = residual(v));
            r
        };
        // 10 = (5, 6) is worst; 11 = (5, 7) shares node 5 and waits; 20 = (10, 11) is
        // at least half as bad and goes too; 30 = (15, 16) is far less bad and waits.
        let residuals = with(&[(10, 4.0), (11, 3.0), (20, 2.5), (30, 1.0)]);
        let round = select_outliers(&g.graph, &weights, &residuals, &protected, RULE);
        assert_eq!(
            round,
            OutlierRound {
                dropped: vec![10, 20],
                downweighted: vec![]
            }
        );
        // The bridge is never dropped, only down-weighted.
        let residuals = with(&[(37, 2.5)]);
        let round = select_outliers(&g.graph, &weights, &residuals, &protected, RULE);
        assert_eq!(round.dropped, Vec::<usize>::new());
        assert_eq!(round.downweighted.len(), 1);
        assert_eq!(round.downweighted[0].0, 37);
        assert!((round.downweighted[0].1 - 0.05 / 2.5).abs() < 1e-12);
        // Protected edges are not looked at again.
        let mut protected_bridge = protected.clone();
        protected_bridge[37] = true;
        let round = select_outliers(&g.graph, &weights, &residuals, &protected_bridge, RULE);
        assert_eq!(round, OutlierRound::default());
        // Nothing above the floors (0.05 m here): nothing happens.
        let residuals = with(&[(3, 0.045)]);
        assert_eq!(
            select_outliers(&g.graph, &weights, &residuals, &protected, RULE),
            OutlierRound::default()
        );
    }
}
