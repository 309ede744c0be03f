//! The scene graph: DSMs are nodes, overlapping pairs registered by DSM-ICP are edges
//! carrying the relative pose M_ij = M_i^-1 M_j (R_ij = R_i^T R_j,
//! t_ij = R_i^T (t_j - t_i)), the overlap score, the final ICP RMSE and, when the
//! registration reports them, the standard errors of M_ij.
//!
//! - [`model`]: [`Edge`], [`EdgeSigma`], [`PoseGraph`] and its validation.
//! - [`components`]: union-find and connected components.
//! - [`bridges`]: the edges whose removal splits a component.
//! - [`tree`]: the greedy baseline, a Kruskal maximum-overlap spanning tree with
//!   poses chained from a root.
//! - [`weights`]: the edge weights (the paper's, or inverse variances).

pub mod bridges;
pub mod components;
pub mod model;
pub mod tree;
mod weights;

pub use bridges::bridges;
pub use components::{Components, UnionFind};
pub use model::{Edge, EdgeSigma, GraphError, PoseGraph};
pub use tree::{chain_poses, max_spanning_forest, mst};
pub use weights::{information_weights, paper_weights, Weighting, VARIANCE_FLOOR_OF_MEDIAN};

/// Poses and edges the tests of every graph file build on.
#[cfg(test)]
pub(crate) mod fixtures {
    use super::Edge;
    use crate::poses::rigid::{from_parts, inverse_rigid, rotation_from_axis_angle};
    use nalgebra::{Matrix4, Vector3};

    pub fn pose(k: f64) -> Matrix4<f64> {
        let r = rotation_from_axis_angle(&Vector3::new(1e-3 * k, -2e-3, 5e-4 * k));
        from_parts(&r, &Vector3::new(k, 2.0 * k - 1.0, -0.5 * k))
    }

    pub fn edge(truth: &[Matrix4<f64>], i: usize, j: usize, overlap: f64) -> Edge {
        Edge::new(i, j, inverse_rigid(&truth[i]) * truth[j], overlap, 0.1)
    }
}
