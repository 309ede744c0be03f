//! The scene graph: DSMs are nodes, overlapping pairs registered by DSM-ICP are edges
//! carrying the relative pose M_ij = M_i^-1 M_j (R_ij = R_i^T R_j,
//! t_ij = R_i^T (t_j - t_i)), the overlap score, the final ICP RMSE and, when the
//! registration reports them, the standard errors of M_ij. Also the edge weights
//! (the paper's, or inverse variances: [`weights`]), connected components
//! (union-find), and the greedy baseline: Kruskal maximum-overlap spanning tree with
//! poses chained from a root.
//!
//! The ICP of pair (i, j) (reference i, moving j) returns T_ij mapping points of j
//! into i's frame; with poses p_corr = M_k p this is M_i T_ij = M_j, so T_ij = M_ij.

mod weights;

pub use weights::{information_weights, paper_weights, Weighting, VARIANCE_FLOOR_OF_MEDIAN};

use crate::poses::rigid::{from_parts, inverse_rigid, rotation, translation};
use nalgebra::{Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector3};
use std::collections::VecDeque;

/// One registered pair.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge {
    pub i: usize,
    pub j: usize,
    /// Rotation R_ij of the relative pose M_ij = M_i^-1 M_j (maps points of j
    /// into i's frame), as a unit quaternion; see [`Edge::rotation`] and
    /// [`Edge::m_ij`]. Kept as a quaternion and t, not a 4x4, so a graph of
    /// 10^6 DSMs and 6 x 10^6 edges holds 0.4 GB less.
    pub q_ij: UnitQuaternion<f64>,
    /// Translation t_ij of M_ij.
    pub t_ij: Vector3<f64>,
    /// Overlap score s_ij = #overlap pixels / #valid pixels, in [0, 1].
    pub overlap: f64,
    /// RMSE of the final ICP iteration, metres.
    pub rmse_m: f64,
    /// Weight of the rotation in the averaging (see [`weights`]); 0 means "ignore
    /// this edge" (rotation and translation).
    pub weight: f64,
    /// Weight of the translation in the averaging (used while `weight` > 0).
    pub translation_weight: f64,
    /// One-sigma standard errors of M_ij, if the registration reported them.
    pub sigma: Option<EdgeSigma>,
    /// Where the translation of M_ij was measured: a point of j's frame (the overlap
    /// centre, in the frame of the edges). Translation constraints and residuals are
    /// taken there, so a pair's rotation error does not leak into its translation
    /// through the lever arm to the origin.
    pub centre_j: Vector3<f64>,
}

/// One-sigma standard errors of a relative pose, per axis of the edges' frame:
/// rotations about x, y, z (radians) and the translation at `Edge::centre_j`.
/// Stored as f32: seven digits are plenty for a standard error, and a graph of
/// 6 x 10^6 edges holds 0.14 GB less.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeSigma {
    rotation_rad: [f32; 3],
    translation_m: [f32; 3],
}

impl EdgeSigma {
    pub fn new(rotation_rad: Vector3<f64>, translation_m: Vector3<f64>) -> Self {
        let narrow = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
        EdgeSigma {
            rotation_rad: narrow(rotation_rad),
            translation_m: narrow(translation_m),
        }
    }

    pub fn rotation_rad(&self) -> Vector3<f64> {
        Vector3::from(self.rotation_rad.map(f64::from))
    }

    pub fn translation_m(&self) -> Vector3<f64> {
        Vector3::from(self.translation_m.map(f64::from))
    }
}

impl Edge {
    /// An edge with unit weights, no standard errors, measured at the origin.
    pub fn new(i: usize, j: usize, m_ij: Matrix4<f64>, overlap: f64, rmse_m: f64) -> Self {
        Edge {
            i,
            j,
            q_ij: quaternion(&m_ij),
            t_ij: translation(&m_ij),
            overlap,
            rmse_m,
            weight: 1.0,
            translation_weight: 1.0,
            sigma: None,
            centre_j: Vector3::zeros(),
        }
    }

    /// The relative pose M_ij = [R_ij t_ij; 0 0 0 1].
    pub fn m_ij(&self) -> Matrix4<f64> {
        from_parts(&self.rotation(), &self.t_ij)
    }

    pub fn set_m_ij(&mut self, m_ij: &Matrix4<f64>) {
        self.q_ij = quaternion(m_ij);
        self.t_ij = translation(m_ij);
    }

    /// R_ij.
    pub fn rotation(&self) -> Matrix3<f64> {
        self.q_ij.to_rotation_matrix().into_inner()
    }

    /// M_ij applied to a point of j's frame.
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.q_ij * p + self.t_ij
    }
}

/// The rotation of a rigid transform (orthonormal, as ICP and the averaging
/// make them) as a unit quaternion.
fn quaternion(m: &Matrix4<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rotation(m)))
}

/// Nodes 0..n and the registered pairs between them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseGraph {
    pub n: usize,
    pub edges: Vec<Edge>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum GraphError {
    #[error("edge {edge}: node {node} out of range (graph has {n} nodes)")]
    NodeOutOfRange { edge: usize, node: usize, n: usize },
    #[error("edge {edge}: joins node {node} to itself")]
    SelfLoop { edge: usize, node: usize },
    #[error("edge {edge}: {what} is not a finite number")]
    NotFinite { edge: usize, what: &'static str },
    #[error("edge {edge}: negative weight {weight}")]
    NegativeWeight { edge: usize, weight: f64 },
    #[error("root node {root} out of range (graph has {n} nodes)")]
    RootOutOfRange { root: usize, n: usize },
    #[error("edge {edge}: translation weight 0 on an edge with a rotation weight")]
    ZeroTranslationWeight { edge: usize },
    #[error("edge {edge}: no standard errors (journaled before they were reported, or the point-to-point metric)")]
    MissingSigma { edge: usize },
    #[error("graph has {n} nodes; at most {max} are supported")]
    TooLarge { n: usize, max: usize },
}

impl PoseGraph {
    pub fn new(n: usize) -> Self {
        PoseGraph {
            n,
            edges: Vec::new(),
        }
    }

    /// Checks indices, self loops and that every number is finite, weights >= 0.
    pub fn validate(&self) -> Result<(), GraphError> {
        if self.n > u32::MAX as usize {
            return Err(GraphError::TooLarge {
                n: self.n,
                max: u32::MAX as usize,
            });
        }
        for (k, e) in self.edges.iter().enumerate() {
            for node in [e.i, e.j] {
                if node >= self.n {
                    return Err(GraphError::NodeOutOfRange {
                        edge: k,
                        node,
                        n: self.n,
                    });
                }
            }
            if e.i == e.j {
                return Err(GraphError::SelfLoop { edge: k, node: e.i });
            }
            let sigma_finite = e.sigma.is_none_or(|s| {
                s.rotation_rad().iter().all(|v| v.is_finite())
                    && s.translation_m().iter().all(|v| v.is_finite())
            });
            let checks = [
                (
                    "m_ij",
                    e.q_ij
                        .coords
                        .iter()
                        .chain(e.t_ij.iter())
                        .all(|v| v.is_finite()),
                ),
                ("overlap", e.overlap.is_finite()),
                ("rmse_m", e.rmse_m.is_finite()),
                ("weight", e.weight.is_finite()),
                ("translation_weight", e.translation_weight.is_finite()),
                ("sigma", sigma_finite),
                ("centre_j", e.centre_j.iter().all(|v| v.is_finite())),
            ];
            if let Some((what, _)) = checks.iter().find(|(_, ok)| !ok) {
                return Err(GraphError::NotFinite { edge: k, what });
            }
            if let Some(&weight) = [e.weight, e.translation_weight].iter().find(|&&w| w < 0.0) {
                return Err(GraphError::NegativeWeight { edge: k, weight });
            }
            if e.weight > 0.0 && e.translation_weight == 0.0 {
                return Err(GraphError::ZeroTranslationWeight { edge: k });
            }
        }
        Ok(())
    }

    /// Connected components over the edges with a positive weight.
    pub fn components(&self) -> Components {
        Components::new(
            self.n,
            self.edges
                .iter()
                .filter(|e| e.weight > 0.0)
                .map(|e| (e.i, e.j)),
        )
    }
}

/// Disjoint sets with path halving and union by size.
#[derive(Clone, Debug)]
pub struct UnionFind {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl UnionFind {
    pub fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n as u32).collect(),
            size: vec![1; n],
        }
    }

    pub fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] as usize != x {
            let grand = self.parent[self.parent[x] as usize];
            self.parent[x] = grand;
            x = grand as usize;
        }
        x
    }

    /// Joins the sets of a and b; false when they were already one set.
    pub fn union(&mut self, a: usize, b: usize) -> bool {
        let (mut ra, mut rb) = (self.find(a), self.find(b));
        if ra == rb {
            return false;
        }
        if self.size[ra] < self.size[rb] {
            std::mem::swap(&mut ra, &mut rb);
        }
        self.parent[rb] = ra as u32;
        self.size[ra] += self.size[rb];
        true
    }
}

/// Connected components: `members[c]` lists the nodes of component c in ascending
/// order; components are ordered by their smallest node; `component_of[node] = c`.
#[derive(Clone, Debug, PartialEq)]
pub struct Components {
    pub component_of: Vec<usize>,
    pub members: Vec<Vec<usize>>,
}

impl Components {
    pub fn new(n: usize, pairs: impl Iterator<Item = (usize, usize)>) -> Self {
        let mut sets = UnionFind::new(n);
        for (a, b) in pairs {
            sets.union(a, b);
        }
        let mut of_root = vec![usize::MAX; n];
        let mut members: Vec<Vec<usize>> = Vec::new();
        let component_of: Vec<usize> = (0..n)
            .map(|node| {
                let root = sets.find(node);
                if of_root[root] == usize::MAX {
                    of_root[root] = members.len();
                    members.push(Vec::new());
                }
                members[of_root[root]].push(node);
                of_root[root]
            })
            .collect();
        Components {
            component_of,
            members,
        }
    }
}

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
    use crate::poses::rigid::{from_parts, rotation_from_axis_angle};
    use nalgebra::Vector3;

    fn pose(k: f64) -> Matrix4<f64> {
        let r = rotation_from_axis_angle(&Vector3::new(1e-3 * k, -2e-3, 5e-4 * k));
        from_parts(&r, &Vector3::new(k, 2.0 * k - 1.0, -0.5 * k))
    }

    fn edge(truth: &[Matrix4<f64>], i: usize, j: usize, overlap: f64) -> Edge {
        Edge::new(i, j, inverse_rigid(&truth[i]) * truth[j], overlap, 0.1)
    }

    #[test]
    fn components_split_and_order() {
        let mut g = PoseGraph::new(6);
        let truth: Vec<_> = (0..6).map(|k| pose(k as f64)).collect();
        g.edges = vec![
            edge(&truth, 4, 2, 0.5),
            edge(&truth, 0, 5, 0.5),
            edge(&truth, 1, 3, 0.5),
        ];
        g.edges[2].weight = 0.0; // ignored: 1 and 3 stay apart
        let c = g.components();
        assert_eq!(c.members, vec![vec![0, 5], vec![1], vec![2, 4], vec![3]]);
        assert_eq!(c.component_of, vec![0, 1, 2, 3, 2, 0]);
    }

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

    #[test]
    fn validation_names_the_edge() {
        let truth: Vec<_> = (0..3).map(|k| pose(k as f64)).collect();
        let mut g = PoseGraph::new(3);
        g.edges = vec![edge(&truth, 0, 1, 0.5), edge(&truth, 1, 2, 0.5)];
        assert_eq!(g.validate(), Ok(()));
        g.edges[1].j = 3;
        assert_eq!(
            g.validate(),
            Err(GraphError::NodeOutOfRange {
                edge: 1,
                node: 3,
                n: 3
            })
        );
        g.edges[1].j = 1;
        assert_eq!(g.validate(), Err(GraphError::SelfLoop { edge: 1, node: 1 }));
        g.edges[1].j = 2;
        g.edges[0].rmse_m = f64::NAN;
        assert_eq!(
            g.validate(),
            Err(GraphError::NotFinite {
                edge: 0,
                what: "rmse_m"
            })
        );
        g.edges[0].rmse_m = 0.1;
        g.edges[0].translation_weight = -1.0;
        assert!(g
            .validate()
            .unwrap_err()
            .to_string()
            .contains("negative weight"));
        g.edges[0].translation_weight = 1.0;
        g.edges[1].sigma = Some(EdgeSigma::new(
            Vector3::new(1e-5, f64::INFINITY, 1e-4),
            Vector3::repeat(0.01),
        ));
        assert_eq!(
            g.validate(),
            Err(GraphError::NotFinite {
                edge: 1,
                what: "sigma"
            })
        );
    }
}
