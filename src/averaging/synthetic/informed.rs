//! Synthetic tile grids as `align` sees them when its pairs carry covariances,
//! for the informed averaging ([`crate::averaging::average_informed`]) and its
//! benchmark (`tools/bench/informed.rs`): a `width` x `width` grid of DSMs with
//! 8-neighbour overlaps (right, below, both diagonals), each pair's relative
//! pose measured at its overlap centre with an anisotropic 6x6 covariance
//! (random axes, cm and 10^-5 rad), a fraction of flat overlaps (height and
//! tilt known to the mm, x, y and yaw only to a metre and a tenth of a degree),
//! a fraction of unreliable pairs (not converged: `reliable` false, five times
//! the noise) and a fraction of gross outliers (degrees and metres off).

use super::{normal3, SplitMix64};
use crate::averaging::EdgeInformation;
use crate::graph::{Edge, PoseGraph};
use crate::poses::rigid::{apply, from_parts, inverse_rigid, rotation_from_axis_angle};
use nalgebra::{Matrix3, Matrix4, Matrix6, Vector3};

/// What the grid looks like.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InformedGridSpec {
    /// Tiles per row and per column.
    pub width: usize,
    /// Distance between tile centres, metres.
    pub spacing_m: f64,
    /// Fraction of pairs over flat fields.
    pub flat_fraction: f64,
    /// Fraction of pairs that did not converge (`reliable` false).
    pub unreliable_fraction: f64,
    /// Fraction of gross outliers.
    pub outlier_fraction: f64,
    /// Fraction of the 8-neighbour pairs that become edges (1: all). Below one
    /// the graph percolates: about 0.36 gives the sparse, nearly tree-like graph
    /// of a grid of 32 m tiles, where most pairs come out degenerate.
    pub keep_fraction: f64,
    pub seed: u64,
}

impl InformedGridSpec {
    /// 200 m tiles, 10 % flat, 3 % unreliable, 3 % outliers.
    pub fn new(width: usize, seed: u64) -> Self {
        InformedGridSpec {
            width,
            spacing_m: 200.0,
            flat_fraction: 0.1,
            unreliable_fraction: 0.03,
            outlier_fraction: 0.03,
            keep_fraction: 1.0,
            seed,
        }
    }
}

/// A generated grid: the graph, one information per edge, the truth, and which
/// edges are gross outliers.
#[derive(Clone, Debug)]
pub struct InformedGrid {
    pub graph: PoseGraph,
    pub information: Vec<EdgeInformation>,
    pub truth: Vec<Matrix4<f64>>,
    pub outliers: Vec<usize>,
}

/// A covariance with these standard deviations along random axes, and a draw
/// from it.
fn anisotropic(rng: &mut SplitMix64, sigmas: [f64; 3]) -> (Matrix3<f64>, Vector3<f64>) {
    let axes = rotation_from_axis_angle(&normal3(rng, 1.0));
    let root = axes * Matrix3::from_diagonal(&Vector3::from(sigmas));
    let draw = root * Vector3::new(rng.normal(), rng.normal(), rng.normal());
    (root * root.transpose(), draw)
}

/// The 8-neighbour pairs of a `width` x `width` grid (each once, i < j).
pub fn grid_pairs(width: usize) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    for k in 0..width * width {
        let (x, y) = (k % width, k / width);
        if x + 1 < width {
            pairs.push((k, k + 1));
        }
        if y + 1 < width {
            pairs.push((k, k + width));
            if x + 1 < width {
                pairs.push((k, k + width + 1));
            }
            if x > 0 {
                pairs.push((k, k + width - 1));
            }
        }
    }
    pairs
}

/// Builds the grid (deterministic in `spec.seed`).
pub fn informed_grid(spec: &InformedGridSpec) -> InformedGrid {
    let mut rng = SplitMix64::new(spec.seed);
    let width = spec.width;
    let n = width * width;
    let positions: Vec<Vector3<f64>> = (0..n)
        .map(|k| Vector3::new((k % width) as f64, (k / width) as f64, 0.0) * spec.spacing_m)
        .collect();
    let truth: Vec<Matrix4<f64>> = (0..n)
        .map(|_| {
            let r = rotation_from_axis_angle(&normal3(&mut rng, 0.05f64.to_radians()));
            from_parts(&r, &normal3(&mut rng, 2.0))
        })
        .collect();
    // Which pairs are kept comes from a stream of its own, so the edges a grid
    // keeps are drawn exactly as in the full grid.
    let mut keep = SplitMix64::new(crate::rng::derive_seed(spec.seed, 0x6b65_6570));
    let pairs: Vec<(usize, usize)> = grid_pairs(width)
        .into_iter()
        .filter(|_| spec.keep_fraction >= 1.0 || keep.next_f64() < spec.keep_fraction)
        .collect();
    let mut out = InformedGrid {
        graph: PoseGraph {
            n,
            edges: Vec::with_capacity(pairs.len()),
        },
        information: Vec::with_capacity(pairs.len()),
        truth,
        outliers: Vec::new(),
    };
    for (k, &(i, j)) in pairs.iter().enumerate() {
        let scale = 1.0 + 2.0 * rng.next_f64();
        let reliable = rng.next_f64() >= spec.unreliable_fraction;
        let noise = if reliable { 1.0 } else { 5.0 };
        let (cov_t, cov_r, mut dt, mut dr) = if rng.next_f64() < spec.flat_fraction {
            let st = Vector3::new(1.0, 1.0, 0.005 * scale);
            let sr = Vector3::new(1e-5 * scale, 1e-5 * scale, 2e-3);
            (
                Matrix3::from_diagonal(&st.component_mul(&st)),
                Matrix3::from_diagonal(&sr.component_mul(&sr)),
                st.map(|s| s * rng.normal()),
                sr.map(|s| s * rng.normal()),
            )
        } else {
            let (ct, dt) = anisotropic(&mut rng, [0.02 * scale, 0.03 * scale, 0.05 * scale]);
            let (cr, dr) = anisotropic(&mut rng, [2e-5 * scale, 3e-5 * scale, 5e-5 * scale]);
            (ct, cr, dt, dr)
        };
        dt *= noise;
        dr *= noise;
        if rng.next_f64() < spec.outlier_fraction {
            dr += normal3(&mut rng, 1.0).normalize() * (2.0 + 8.0 * rng.next_f64()).to_radians();
            dt += normal3(&mut rng, 1.0).normalize() * (2.0 + 18.0 * rng.next_f64());
            out.outliers.push(k);
        }
        // Noise about the overlap centre c: p -> Rn (p - c) + c + dt; the measured
        // M_ij = truth * noise^-1, so the residual at c is +dt and the rotation one +dr.
        let truth = &out.truth;
        let centre = (positions[i] + positions[j]) / 2.0;
        let c_j = apply(&inverse_rigid(&truth[j]), &centre);
        let rn = rotation_from_axis_angle(&dr);
        let noise = from_parts(&rn, &(c_j - rn * c_j + dt));
        let m_ij = inverse_rigid(&truth[i]) * truth[j] * inverse_rigid(&noise);
        out.graph.edges.push(Edge {
            centre_j: c_j,
            ..Edge::new(i, j, m_ij, 0.5, 0.1)
        });
        let mut covariance = Matrix6::zeros();
        covariance.fixed_view_mut::<3, 3>(0, 0).copy_from(&cov_t);
        covariance.fixed_view_mut::<3, 3>(3, 3).copy_from(&cov_r);
        out.information
            .push(EdgeInformation::from_covariance(&covariance, reliable));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_100_grid_has_the_issue_12_edge_count() {
        assert_eq!(grid_pairs(100).len(), 39_402);
        assert_eq!(grid_pairs(1).len(), 0);
    }

    #[test]
    fn outliers_and_unreliable_edges_come_in_the_stated_fractions() {
        let grid = informed_grid(&InformedGridSpec::new(40, 3));
        let edges = grid.graph.edges.len() as f64;
        let outliers = grid.outliers.len() as f64 / edges;
        let unreliable = grid.information.iter().filter(|e| !e.reliable).count() as f64 / edges;
        assert!((0.02..0.04).contains(&outliers), "{outliers}");
        assert!((0.02..0.04).contains(&unreliable), "{unreliable}");
        assert!(grid.information.iter().all(|e| e.is_valid()));
    }
}
