//! The greedy baseline (`align --graph mst`): Kruskal maximum-overlap spanning
//! forest, and poses chained along its edges from a root by breadth-first search.

use super::{Edge, GraphError, PoseGraph, UnionFind};
use crate::poses::rigid::inverse_rigid;
use nalgebra::Matrix4;
use std::collections::VecDeque;

/// Kruskal maximum-overlap spanning forest (the greedy baseline): indices of the
/// chosen edges; ties broken by edge index. Edges of weight 0 are ignored.
pub fn mst(graph: &PoseGraph) -> Vec<usize> {
    max_spanning_forest(graph, |e| e.overlap)
}

/// Kruskal maximum spanning forest for any key (higher is better), over the edges
/// with a positive weight.
pub fn max_spanning_forest(graph: &PoseGraph, key: impl Fn(&Edge) -> f64) -> Vec<usize> {
    let mut order: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| graph.edges[k].weight > 0.0)
        .collect();
    let keys: Vec<f64> = graph.edges.iter().map(key).collect();
    order.sort_by(|&a, &b| keys[b].total_cmp(&keys[a]).then(a.cmp(&b)));
    let mut sets = UnionFind::new(graph.n);
    order.retain(|&k| sets.union(graph.edges[k].i, graph.edges[k].j));
    order
}

/// Poses chained along tree edges by BFS: M_root = I, M_j = M_i M_ij across each edge
/// (M_i = M_j M_ij^-1 when walked backwards). Nodes the tree does not connect to
/// `root` are chained from the smallest node of their own tree (identity there).
pub fn chain_poses(
    graph: &PoseGraph,
    tree_edges: &[usize],
    root: usize,
) -> Result<Vec<Matrix4<f64>>, GraphError> {
    if root >= graph.n {
        return Err(GraphError::RootOutOfRange { root, n: graph.n });
    }
    let adjacency = Adjacency::new(graph, tree_edges);
    let mut poses: Vec<Option<Matrix4<f64>>> = vec![None; graph.n];
    let mut queue = VecDeque::new();
    for start in std::iter::once(root).chain(0..graph.n) {
        if poses[start].is_some() {
            continue;
        }
        poses[start] = Some(Matrix4::identity());
        queue.push_back(start);
        while let Some(node) = queue.pop_front() {
            let m_node = poses[node].expect("queued nodes have poses");
            for &k in adjacency.edges_of(node) {
                let e = &graph.edges[k];
                let (other, m_other) = if e.i == node {
                    (e.j, m_node * e.m_ij())
                } else {
                    (e.i, m_node * inverse_rigid(&e.m_ij()))
                };
                if poses[other].is_none() {
                    poses[other] = Some(m_other);
                    queue.push_back(other);
                }
            }
        }
    }
    Ok(poses
        .into_iter()
        .map(|m| m.expect("every node visited"))
        .collect())
}

/// Compressed adjacency lists (edge indices per node) of a subset of edges.
struct Adjacency {
    offsets: Vec<usize>,
    edge_ids: Vec<usize>,
}

impl Adjacency {
    fn new(graph: &PoseGraph, edges: &[usize]) -> Self {
        let mut offsets = vec![0usize; graph.n + 1];
        for &k in edges {
            offsets[graph.edges[k].i + 1] += 1;
            offsets[graph.edges[k].j + 1] += 1;
        }
        for node in 0..graph.n {
            offsets[node + 1] += offsets[node];
        }
        let mut fill = offsets.clone();
        let mut edge_ids = vec![0usize; offsets[graph.n]];
        for &k in edges {
            for node in [graph.edges[k].i, graph.edges[k].j] {
                edge_ids[fill[node]] = k;
                fill[node] += 1;
            }
        }
        Adjacency { offsets, edge_ids }
    }

    fn edges_of(&self, node: usize) -> &[usize] {
        &self.edge_ids[self.offsets[node]..self.offsets[node + 1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::fixtures::{edge, pose};

    #[test]
    fn mst_prefers_overlap_and_chaining_recovers_poses() {
        let truth: Vec<_> = (0..4).map(|k| pose(k as f64)).collect();
        let mut g = PoseGraph::new(4);
        g.edges = vec![
            edge(&truth, 0, 1, 0.9),
            edge(&truth, 1, 2, 0.2),
            edge(&truth, 0, 2, 0.7),
            edge(&truth, 3, 2, 0.6),
            edge(&truth, 1, 3, 0.1),
        ];
        assert_eq!(mst(&g), vec![0, 2, 3]);
        let chained = chain_poses(&g, &mst(&g), 1).unwrap();
        let root_inv = inverse_rigid(&truth[1]);
        for k in 0..4 {
            let expected = root_inv * truth[k];
            assert!((chained[k] - expected).abs().max() < 1e-12, "node {k}");
        }
        assert_eq!(
            chain_poses(&g, &[], 7),
            Err(GraphError::RootOutOfRange { root: 7, n: 4 })
        );
    }

    #[test]
    fn chaining_a_forest_roots_each_tree() {
        let truth: Vec<_> = (0..4).map(|k| pose(k as f64)).collect();
        let mut g = PoseGraph::new(4);
        g.edges = vec![edge(&truth, 0, 1, 0.5), edge(&truth, 3, 2, 0.5)];
        let chained = chain_poses(&g, &[0, 1], 1).unwrap();
        assert!((chained[1] - Matrix4::identity()).abs().max() == 0.0);
        assert!((chained[2] - Matrix4::identity()).abs().max() == 0.0);
        let expected = inverse_rigid(&truth[2]) * truth[3];
        assert!((chained[3] - expected).abs().max() < 1e-12);
    }
}
