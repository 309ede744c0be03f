//! Per-node standard errors of the averaged poses: the marginal covariance of the
//! pose graph's normal equations H = sum J^T Omega J (rotations and translations
//! solved apart, the translation covariance given the rotations), in the mean
//! gauge of each component (the free motions projected out: C = P H^+ P).
//! Exact for graphs up to `exact_max_nodes` (a dense 3n x 3n inverse); larger ones
//! are sampled: x = H^+ J^T Omega^(1/2) xi for `samples` normal draws xi has
//! covariance H^+, so the mean of x_i x_i^T estimates node i's block, with a
//! relative error of about 1 / sqrt(2 samples) on each sigma (12 % at 32 samples).
//! A node in no active edge gets infinite sigmas.

use super::block::{BlockEdge, BlockSystem};
use super::cg::StepTolerance;
use super::marginals::{dense, gauge_free_marginals, project_out, ComponentMotions};
use crate::graph::PoseGraph;
use crate::rng::SplitMix64;
use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Vector3};

/// How the marginal covariances are computed (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CovarianceMethod {
    pub exact_max_nodes: usize,
    pub samples: usize,
    pub seed: u64,
}

impl Default for CovarianceMethod {
    fn default() -> Self {
        CovarianceMethod {
            exact_max_nodes: 400,
            samples: 32,
            seed: 1,
        }
    }
}

/// One-sigma standard errors of a node's pose, about its own axes: the
/// translation (metres, x y z) and rotation (degrees, roll pitch yaw).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct NodeSigma {
    pub shift_m: [f64; 3],
    pub rotation_deg: [f64; 3],
}

/// Standard errors of every node, from the (weighted, 6x6 block-diagonal) edge
/// information `omegas` (zero for inactive edges) at the final `rotations`.
pub(crate) fn node_sigmas(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    rotations: &[Matrix3<f64>],
    components: &[Vec<usize>],
    method: CovarianceMethod,
) -> Vec<NodeSigma> {
    let mut rotation_edges = Vec::new();
    let mut translation_edges = Vec::new();
    for (e, o) in graph.edges.iter().zip(omegas) {
        if o.amax() <= 0.0 {
            continue;
        }
        let (r_i, r_j) = (rotations[e.i], rotations[e.j]);
        let om_r = o.fixed_view::<3, 3>(0, 0).into_owned();
        let om_t = o.fixed_view::<3, 3>(3, 3).into_owned();
        let r0 = Vector3::zeros();
        rotation_edges.push(BlockEdge {
            i: e.i,
            j: e.j,
            b: r_j.tr_mul(&r_i),
            omega: om_r,
            r0,
        });
        translation_edges.push(translation_edge(e.i, e.j, &om_t, &r_i));
    }
    let rotation_null = rotation_null(rotations);
    let translation_null: Vec<Vec<Vector3<f64>>> = (0..3)
        .map(|a| vec![Vector3::ith(a, 1.0); graph.n])
        .collect();
    let rot = marginal_variances(graph.n, rotation_edges, &rotation_null, components, method);
    let tra = marginal_variances(
        graph.n,
        translation_edges,
        &translation_null,
        components,
        method,
    );
    let isolated = isolated_nodes(graph.n, components);
    (0..graph.n)
        .map(|k| {
            if isolated[k] {
                return NodeSigma {
                    shift_m: [f64::INFINITY; 3],
                    rotation_deg: [f64::INFINITY; 3],
                };
            }
            NodeSigma {
                shift_m: [0, 1, 2].map(|a| tra[k][a].max(0.0).sqrt()),
                rotation_deg: [0, 1, 2].map(|a| rot[k][a].max(0.0).sqrt().to_degrees()),
            }
        })
        .collect()
}

/// The translation block of an edge i -> j given the rotations: its
/// information `omega` (about i's axes) turned into world axes by i's rotation.
pub(crate) fn translation_edge(
    i: usize,
    j: usize,
    omega: &Matrix3<f64>,
    r_i: &Matrix3<f64>,
) -> BlockEdge {
    BlockEdge {
        i,
        j,
        b: Matrix3::identity(),
        omega: r_i * omega * r_i.transpose(),
        r0: Vector3::zeros(),
    }
}

fn isolated_nodes(n: usize, components: &[Vec<usize>]) -> Vec<bool> {
    let mut out = vec![true; n];
    for members in components.iter().filter(|m| m.len() > 1) {
        members.iter().for_each(|&k| out[k] = false);
    }
    out
}

/// The free motions of the rotation unknowns (left perturbations): a common turn
/// about axis a is node k's block R_k^T e_a.
fn rotation_null(rotations: &[Matrix3<f64>]) -> Vec<Vec<Vector3<f64>>> {
    (0..3)
        .map(|a| {
            rotations
                .iter()
                .map(|r| r.transpose() * Vector3::ith(a, 1.0))
                .collect()
        })
        .collect()
}

/// The free motions of each component: `null[a][k]` is node k's block of the
/// motion along axis a, scaled to unit length over the component.
pub(crate) fn component_motions<'a>(
    null: &[Vec<Vector3<f64>>],
    components: &'a [Vec<usize>],
) -> Vec<ComponentMotions<'a, 3>> {
    components
        .iter()
        .map(|members| {
            let scale = 1.0 / (members.len() as f64).sqrt();
            let basis: Vec<Vec<Vector3<f64>>> = null
                .iter()
                .map(|axis| members.iter().map(|&k| axis[k] * scale).collect())
                .collect();
            ComponentMotions {
                members,
                conditions: basis.clone(),
                basis,
            }
        })
        .collect()
}

/// Diagonals of node blocks of P H^+ P.
fn marginal_variances(
    n: usize,
    edges: Vec<BlockEdge>,
    null: &[Vec<Vector3<f64>>],
    components: &[Vec<usize>],
    method: CovarianceMethod,
) -> Vec<Vector3<f64>> {
    let motions = component_motions(null, components);
    if n <= method.exact_max_nodes {
        exact(n, &edges, &dense(n, &motions))
    } else if let Some(variances) = selected(n, &edges, &motions) {
        variances
    } else {
        sampled(n, edges, &motions, method)
    }
}

/// Exact marginal variances of a large graph whose factor is within the direct
/// budget (`marginals::gauge_free_marginals`); None when over it.
fn selected(
    n: usize,
    edges: &[BlockEdge],
    motions: &[ComponentMotions<3>],
) -> Option<Vec<Vector3<f64>>> {
    let mut diagonal = vec![Matrix3::zeros(); n];
    for e in edges {
        diagonal[e.i] += e.b.transpose() * e.omega * e.b;
        diagonal[e.j] += e.omega;
    }
    let links = edges
        .iter()
        .map(|e| (e.i, e.j, -(e.b.transpose() * e.omega)));
    let (blocks, updates) = super::direct::BUDGET_PER_NODE_AND_LINK;
    let budget = super::direct::Budget::relative(n, edges.len(), blocks, updates);
    gauge_free_marginals(diagonal, links, motions, budget)
}

fn exact(n: usize, edges: &[BlockEdge], null: &[Vec<Vector3<f64>>]) -> Vec<Vector3<f64>> {
    let mut h = DMatrix::<f64>::zeros(3 * n, 3 * n);
    for e in edges {
        let (i, j) = (3 * e.i, 3 * e.j);
        let bt_om = e.b.transpose() * e.omega;
        let add = |h: &mut DMatrix<f64>, r: usize, c: usize, m: &Matrix3<f64>| {
            let mut view = h.view_mut((r, c), (3, 3));
            view += m;
        };
        add(&mut h, i, i, &(bt_om * e.b));
        add(&mut h, j, j, &e.omega);
        add(&mut h, i, j, &(-bt_om));
        add(&mut h, j, i, &(-bt_om.transpose()));
    }
    let flat: Vec<DVector<f64>> = null
        .iter()
        .map(|v| DVector::from_iterator(3 * n, v.iter().flat_map(|b| [b.x, b.y, b.z])))
        .collect();
    let Some(diagonal) = gauge_free_diagonal(h, &flat) else {
        return vec![Vector3::repeat(f64::INFINITY); n];
    };
    (0..n)
        .map(|k| Vector3::from_fn(|a, _| diagonal[3 * k + a]))
        .collect()
}

/// The diagonal of P H^+ P, P projecting out the orthonormal free motions
/// `null` (H is regularised along them at its mean diagonal, then the projection
/// removes them again); None when the regularised H is not positive definite.
pub(crate) fn gauge_free_diagonal(h: DMatrix<f64>, null: &[DVector<f64>]) -> Option<DVector<f64>> {
    gauge_free_inverse(h, null).map(|c| c.diagonal())
}

/// P H^+ P of [`gauge_free_diagonal`], whole.
pub(crate) fn gauge_free_inverse(
    mut h: DMatrix<f64>,
    null: &[DVector<f64>],
) -> Option<DMatrix<f64>> {
    let size = h.nrows();
    let scale = (h.trace() / size.max(1) as f64).max(f64::MIN_POSITIVE);
    for v in null {
        h += v * v.transpose() * scale;
    }
    let inverse = h.cholesky()?.inverse();
    let mut projector = DMatrix::<f64>::identity(size, size);
    for v in null {
        projector -= v * v.transpose();
    }
    Some(&projector * inverse * &projector)
}

fn sampled(
    n: usize,
    edges: Vec<BlockEdge>,
    motions: &[ComponentMotions<3>],
    method: CovarianceMethod,
) -> Vec<Vector3<f64>> {
    let roots: Vec<Matrix3<f64>> = edges
        .iter()
        .map(|e| {
            e.omega
                .cholesky()
                .map(|c| c.l())
                .unwrap_or_else(Matrix3::zeros)
        })
        .collect();
    let mean = edges.iter().map(|e| e.omega.trace() / 3.0).sum::<f64>() / edges.len().max(1) as f64;
    let system = BlockSystem {
        n,
        edges,
        prior: (1e-9 * mean).max(f64::MIN_POSITIVE),
    };
    let hierarchy = system.preconditioner();
    let mut rng = SplitMix64::new(method.seed);
    let mut sum = vec![Vector3::zeros(); n];
    let samples = method.samples.max(1);
    for _ in 0..samples {
        let draws: Vec<Vector3<f64>> = roots
            .iter()
            .map(|l| l * Vector3::new(rng.normal(), rng.normal(), rng.normal()))
            .collect();
        let mut rhs = system.gather(|k, _| draws[k]);
        project_out(&mut rhs, motions);
        let (mut x, _) = system.solve(&hierarchy, &rhs, None, StepTolerance::sample(20_000));
        project_out(&mut x, motions);
        sum.iter_mut()
            .zip(&x)
            .for_each(|(s, v)| *s += v.component_mul(v));
    }
    sum.into_iter().map(|s| s / samples as f64).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::rigid::rotation_from_axis_angle;

    /// Two components (a tree with chords, and a triangle), two isolated nodes;
    /// rotation-like edges (b = R_j^T R_i) with anisotropic information.
    struct Case {
        n: usize,
        edges: Vec<BlockEdge>,
        null: Vec<Vec<Vector3<f64>>>,
        components: Vec<Vec<usize>>,
    }

    fn case() -> Case {
        let mut rng = SplitMix64::new(3);
        let n = 30;
        let rotations: Vec<Matrix3<f64>> = (0..n)
            .map(|_| {
                rotation_from_axis_angle(&Vector3::new(rng.normal(), rng.normal(), rng.normal()))
            })
            .collect();
        let mut links: Vec<(usize, usize)> = (1..25).map(|k| (k / 2, k)).collect();
        links.extend([(3, 17), (5, 22), (25, 26), (26, 27), (27, 25)]);
        let edges: Vec<BlockEdge> = links
            .iter()
            .map(|&(i, j)| {
                let a = Matrix3::from_fn(|_, _| rng.normal());
                BlockEdge {
                    i,
                    j,
                    b: rotations[j].tr_mul(&rotations[i]),
                    omega: a * a.transpose() + Matrix3::identity() * 0.1,
                    r0: Vector3::zeros(),
                }
            })
            .collect();
        let components: Vec<Vec<usize>> =
            vec![(0..25).collect(), vec![25, 26, 27], vec![28], vec![29]];
        let null = rotation_null(&rotations);
        Case {
            n,
            edges,
            null,
            components,
        }
    }

    #[test]
    fn the_selected_inverse_gives_the_dense_gauge_free_variances() {
        let Case {
            n,
            edges,
            null,
            components,
        } = case();
        let motions = component_motions(&null, &components);
        let dense = exact(n, &edges, &dense(n, &motions));
        let direct = selected(n, &edges, &motions).unwrap();
        for k in 0..28 {
            let scale = dense[k].amax();
            assert!(scale > 0.0 && scale.is_finite(), "{k}");
            assert!(
                (direct[k] - dense[k]).amax() <= 1e-8 * scale,
                "{k}: {direct:?}"
            );
        }
    }

    /// Sampling with each component's free motions projected out converges to
    /// the dense gauge-free variances (relative error about 1 / sqrt(2 samples)).
    #[test]
    fn sampled_variances_match_the_dense_ones_per_component() {
        let Case {
            n,
            edges,
            null,
            components,
        } = case();
        let motions = component_motions(&null, &components);
        let dense = exact(n, &edges, &dense(n, &motions));
        let method = CovarianceMethod {
            exact_max_nodes: 0,
            samples: 2000,
            seed: 5,
        };
        let sampled = sampled(n, edges, &motions, method);
        for k in 0..28 {
            for a in 0..3 {
                let ratio = sampled[k][a] / dense[k][a];
                // 2000 samples: 3 % per variance, 5 sigma
                assert!((ratio - 1.0).abs() < 0.16, "{k} {a}: {ratio}");
            }
        }
    }
}
