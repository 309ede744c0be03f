//! The graph's data: [`Edge`] (one registered pair, its relative pose M_ij, overlap,
//! RMSE, weights and standard errors [`EdgeSigma`]), [`PoseGraph`] (nodes 0..n and
//! the edges) and its validation ([`GraphError`]).
//!
//! The ICP of pair (i, j) (reference i, moving j) returns T_ij mapping points of j
//! into i's frame; with poses p_corr = M_k p this is M_i T_ij = M_j, so T_ij = M_ij.

use super::Components;
use crate::poses::rigid::{from_parts, rotation, translation};
use nalgebra::{Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector3};

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::fixtures::{edge, pose};

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
