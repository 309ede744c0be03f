//! Synthetic pose graphs with known truth, for tests and `tools/bench/averaging.rs`:
//! tiny random rotations and metre-scale translations (as between real DSMs), edges
//! laid out as a chain, a tile grid or a random graph, relative poses with Gaussian
//! noise (optionally of a different size on each edge, and about a point away from
//! the origin, as DSM pairs measured at their overlap), the paper's weights and, for
//! noisy graphs, each edge's true noise level as its standard errors. Also the
//! gauge-free error of estimated poses.
//! Deterministic: a seeded SplitMix64 generator, no external crate.

use super::gauge::fix_gauge;
use crate::graph::{paper_weights, Components, Edge, EdgeSigma, PoseGraph};
use crate::poses::rigid::{
    from_parts, inverse_rigid, rotation, rotation_between_deg, rotation_from_axis_angle,
    translation,
};
use nalgebra::{Matrix4, Vector3};

pub use crate::rng::SplitMix64;

pub mod informed;

/// Three independent normal deviates of standard deviation `sigma`.
pub fn normal3(rng: &mut SplitMix64, sigma: f64) -> Vector3<f64> {
    Vector3::new(rng.normal(), rng.normal(), rng.normal()) * sigma
}

/// How the nodes are connected.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Topology {
    /// Node k overlaps nodes k+1 ..= k+reach (reach 1 is a tree).
    Chain { reach: usize },
    /// Tiles in rows of `width`: edges to the right, below, both diagonals and two
    /// steps right and below (about 6 edges per node, as tiles overlapping by > 50 %).
    Grid { width: usize },
    /// Node k joined to k+1 (connected) and to edges_per_node - 1 uniformly random nodes.
    Random { edges_per_node: usize },
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SyntheticSpec {
    pub nodes: usize,
    pub topology: Topology,
    /// Standard deviation of the true rotation angle per axis, degrees.
    pub rotation_spread_deg: f64,
    /// Standard deviation of the true translations per axis, metres.
    pub translation_spread_m: f64,
    /// Noise on each relative rotation, degrees per axis (standard deviation).
    pub noise_rotation_deg: f64,
    /// Noise on each relative translation, metres per axis (standard deviation).
    pub noise_translation_m: f64,
    /// Each edge's noise is scaled by a factor log-uniform in [1/spread, spread]
    /// (1: the same noise level everywhere).
    pub noise_scale_spread: f64,
    /// Nodes sit this far apart on the ground (grid cells, chain steps; random
    /// graphs spread over the same area), centred on the origin, and each edge is
    /// measured at the midpoint of its two nodes, its rotation noise turning about
    /// that point, as for DSM pairs registered on their overlap. 0: every edge is
    /// measured at the origin.
    pub spacing_m: f64,
    pub seed: u64,
}

impl SyntheticSpec {
    /// Noise-free relative poses; rotations of ~0.05 degrees, translations of ~2 m.
    pub fn exact(nodes: usize, topology: Topology, seed: u64) -> Self {
        SyntheticSpec {
            nodes,
            topology,
            rotation_spread_deg: 0.05,
            translation_spread_m: 2.0,
            noise_rotation_deg: 0.0,
            noise_translation_m: 0.0,
            noise_scale_spread: 1.0,
            spacing_m: 0.0,
            seed,
        }
    }

    /// As [`SyntheticSpec::exact`] with noise on every edge.
    pub fn noisy(
        nodes: usize,
        topology: Topology,
        seed: u64,
        rotation_deg: f64,
        translation_m: f64,
    ) -> Self {
        SyntheticSpec {
            noise_rotation_deg: rotation_deg,
            noise_translation_m: translation_m,
            ..Self::exact(nodes, topology, seed)
        }
    }
}

/// A generated graph and the poses it was made from.
#[derive(Clone, Debug)]
pub struct SyntheticGraph {
    pub graph: PoseGraph,
    pub truth: Vec<Matrix4<f64>>,
}

/// Builds the graph: M_ij = (M_i^-1 M_j) * noise, overlap in [0.3, 0.9], rmse from the
/// noise level, paper weights; sigma = the edge's noise level when there is noise.
pub fn generate(spec: &SyntheticSpec) -> SyntheticGraph {
    let mut rng = SplitMix64::new(spec.seed);
    let truth: Vec<Matrix4<f64>> = (0..spec.nodes)
        .map(|_| {
            let r =
                rotation_from_axis_angle(&normal3(&mut rng, spec.rotation_spread_deg.to_radians()));
            from_parts(&r, &normal3(&mut rng, spec.translation_spread_m))
        })
        .collect();
    let pairs = pairs(spec, &mut rng);
    let positions = node_positions(spec);
    let mut edges = Vec::with_capacity(pairs.len());
    let noisy = spec.noise_rotation_deg > 0.0 || spec.noise_translation_m > 0.0;
    for (i, j) in pairs {
        // Extra draws only when asked for, so older specs keep their numbers.
        let scale = if spec.noise_scale_spread > 1.0 {
            spec.noise_scale_spread.powf(2.0 * rng.next_f64() - 1.0)
        } else {
            1.0
        };
        let centre_j = (positions[i] + positions[j]) / 2.0;
        let sigma_rad = spec.noise_rotation_deg.to_radians() * scale;
        let sigma_m = spec.noise_translation_m * scale;
        let noise_r = rotation_from_axis_angle(&normal3(&mut rng, sigma_rad));
        // Turns about centre_j, then shifts: p -> R (p - c) + c + t.
        let shift = normal3(&mut rng, sigma_m) + centre_j - noise_r * centre_j;
        let noise = from_parts(&noise_r, &shift);
        let overlap = 0.3 + 0.6 * rng.next_f64();
        let rmse_m = spec.noise_translation_m * (1.0 + rng.next_f64()) + 0.05;
        edges.push(Edge {
            sigma: noisy
                .then(|| EdgeSigma::new(Vector3::repeat(sigma_rad), Vector3::repeat(sigma_m))),
            centre_j,
            ..Edge::new(
                i,
                j,
                inverse_rigid(&truth[i]) * truth[j] * noise,
                overlap,
                rmse_m,
            )
        });
    }
    paper_weights(&mut edges);
    SyntheticGraph {
        graph: PoseGraph {
            n: spec.nodes,
            edges,
        },
        truth,
    }
}

/// Ground positions of the nodes (see [`SyntheticSpec::spacing_m`]), from their own
/// generator so the rest of the graph does not depend on the spacing.
pub fn node_positions(spec: &SyntheticSpec) -> Vec<Vector3<f64>> {
    let n = spec.nodes;
    let mut rng = SplitMix64::new(spec.seed ^ 0x9e37_79b9_7f4a_7c15);
    let side = (n as f64).sqrt();
    let raw: Vec<Vector3<f64>> = (0..n)
        .map(|k| match spec.topology {
            Topology::Chain { .. } => Vector3::new(k as f64, 0.0, 0.0),
            Topology::Grid { width } => Vector3::new((k % width) as f64, (k / width) as f64, 0.0),
            Topology::Random { .. } => {
                Vector3::new(rng.next_f64() * side, rng.next_f64() * side, 0.0)
            }
        })
        .collect();
    let mean = raw.iter().sum::<Vector3<f64>>() / n.max(1) as f64;
    raw.iter().map(|p| (p - mean) * spec.spacing_m).collect()
}

fn pairs(spec: &SyntheticSpec, rng: &mut SplitMix64) -> Vec<(usize, usize)> {
    let n = spec.nodes;
    let mut pairs = Vec::new();
    match spec.topology {
        Topology::Chain { reach } => {
            for i in 0..n {
                pairs.extend((i + 1..(i + 1 + reach).min(n)).map(|j| (i, j)));
            }
        }
        Topology::Grid { width } => {
            let height = n.div_ceil(width) as i64;
            let steps = [(1, 0), (0, 1), (1, 1), (-1, 1), (2, 0), (0, 2)];
            for i in 0..n {
                let (col, row) = ((i % width) as i64, (i / width) as i64);
                for (dc, dr) in steps {
                    let (c, r) = (col + dc, row + dr);
                    let j = (r * width as i64 + c) as usize;
                    if c >= 0 && c < width as i64 && r < height && j < n {
                        pairs.push((i, j));
                    }
                }
            }
        }
        Topology::Random { edges_per_node } => {
            for i in 0..n {
                if i + 1 < n {
                    pairs.push((i, i + 1));
                }
                for _ in 1..edges_per_node {
                    let j = rng.below(n as u64) as usize;
                    if j != i {
                        pairs.push((i, j));
                    }
                }
            }
        }
    }
    pairs
}

/// Errors of estimated poses against the truth, gauge free: both sets are put in
/// the mean gauge of each component before comparing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseErrors {
    pub rotation_rms_deg: f64,
    pub rotation_max_deg: f64,
    pub translation_rms_m: f64,
    pub translation_max_m: f64,
}

pub fn pose_errors(
    estimate: &[Matrix4<f64>],
    truth: &[Matrix4<f64>],
    components: &Components,
) -> PoseErrors {
    let (mut est, mut tru) = (estimate.to_vec(), truth.to_vec());
    for members in &components.members {
        fix_gauge(&mut est, members, None);
        fix_gauge(&mut tru, members, None);
    }
    let mut errors = PoseErrors {
        rotation_rms_deg: 0.0,
        rotation_max_deg: 0.0,
        translation_rms_m: 0.0,
        translation_max_m: 0.0,
    };
    for (a, b) in est.iter().zip(&tru) {
        let angle = rotation_between_deg(&rotation(a), &rotation(b));
        let offset = (translation(a) - translation(b)).norm();
        errors.rotation_rms_deg += angle * angle;
        errors.translation_rms_m += offset * offset;
        errors.rotation_max_deg = errors.rotation_max_deg.max(angle);
        errors.translation_max_m = errors.translation_max_m.max(offset);
    }
    let n = est.len().max(1) as f64;
    errors.rotation_rms_deg = (errors.rotation_rms_deg / n).sqrt();
    errors.translation_rms_m = (errors.translation_rms_m / n).sqrt();
    errors
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topologies_have_the_stated_shape() {
        let grid = generate(&SyntheticSpec::exact(100, Topology::Grid { width: 10 }, 1));
        // 10x10 tiles: 90 right + 90 down + 81 + 81 diagonals + 80 + 80 two-step.
        assert_eq!(grid.graph.edges.len(), 502);
        let chain = generate(&SyntheticSpec::exact(10, Topology::Chain { reach: 2 }, 1));
        assert_eq!(chain.graph.edges.len(), 17);
        let random = generate(&SyntheticSpec::exact(
            1000,
            Topology::Random { edges_per_node: 6 },
            1,
        ));
        let per_node = random.graph.edges.len() as f64 / 1000.0;
        assert!((5.9..=6.0).contains(&per_node), "{per_node}");
        assert_eq!(random.graph.components().members.len(), 1);
        assert_eq!(random.graph.validate(), Ok(()));
    }

    #[test]
    fn exact_edges_are_consistent_with_the_truth() {
        let g = generate(&SyntheticSpec::exact(30, Topology::Grid { width: 6 }, 2));
        for e in &g.graph.edges {
            let expected = inverse_rigid(&g.truth[e.i]) * g.truth[e.j];
            assert!((e.m_ij() - expected).abs().max() < 1e-12);
        }
        let errors = pose_errors(&g.truth, &g.truth, &g.graph.components());
        assert_eq!(errors.translation_max_m, 0.0);
    }

    #[test]
    fn errors_ignore_a_global_rigid_motion() {
        let g = generate(&SyntheticSpec::exact(
            40,
            Topology::Random { edges_per_node: 4 },
            5,
        ));
        let motion = from_parts(
            &rotation_from_axis_angle(&Vector3::new(0.1, -0.2, 0.3)),
            &Vector3::new(5.0, -7.0, 1.0),
        );
        let moved: Vec<_> = g.truth.iter().map(|m| motion * m).collect();
        let errors = pose_errors(&moved, &g.truth, &g.graph.components());
        assert!(
            errors.rotation_max_deg < 1e-10 && errors.translation_max_m < 1e-10,
            "{errors:?}"
        );
    }
}
