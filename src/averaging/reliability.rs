//! What an outlier edge the graph could not catch would do to the poses
//! (Baarda's reliability, as in geodetic network adjustment): the variance of
//! the shifts it adds, summed over edges, at the rate pairs are outliers.
//!
//! An edge is checked by the rest of the graph only as far as other paths
//! measure the same relative pose: its redundancy r = 1 - h along each
//! direction of its information (h the leverage, the share of an error along
//! it that the solve absorbs). The graph's test drops an edge beyond
//! [`detect_sigma`] sigmas; an error that test finds with 80 % power is
//! sqrt(lambda / r) sigmas (lambda = (detect + 0.84)^2, the minimal detectable
//! bias), and smaller ones pass, moving every node by C J^T Omega b. With a
//! fraction [`OUTLIER_RATE`] of edges carrying such an error, each edge adds
//! OUTLIER_RATE x (its effect)^2 to each node's variance.
//!
//! Where the graph is dense (r near 1) this is nothing; where a group of DSMs
//! hangs on a few edges that weak ones barely check, it is metres: on the
//! 50 x 50 grid of 64 m tiles a corner of 58 DSMs, linked to the rest by one
//! converged edge 8.8 m off at a 0.8 m sigma and ambiguous ones, sat 4.6 m
//! off with a 0.83 m sigma. With all edges within their own covariance of the
//! truth (an oracle), every DSM there was within 3 of its sigmas; the pairs'
//! tails, which no check can see where nothing else measures the same thing,
//! are what this term carries. A bridge (r = 0) has no check at all and adds
//! nothing: the DSMs beyond it rest on that pair's own sigma.
//!
//! Cost: three solves with the graph's sparse factor per edge; graphs with
//! more than [`MAX_WORK`] edges x nodes take the redundancies from the
//! selected inverse and sample the sum ([`SAMPLES`] solves); graphs whose
//! factor exceeds the direct budget keep the model's sigmas (None).

use super::block::BlockEdge;
use super::covariance::component_motions;
use super::direct::{Budget, Factor, BUDGET_PER_NODE_AND_LINK};
use super::marginals::{anchored_factor, project_out, ComponentMotions};
use crate::rng::SplitMix64;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

/// Share of pairs whose error lies beyond their own covariance: the pairs
/// beyond 3 sigma on an axis over the generated collections (1.3 % on the
/// 50 x 50 grid of 64 m tiles, under 1 % on larger tiles).
pub(crate) const OUTLIER_RATE: f64 = 0.01;
/// Standard normal quantile of 80 % power.
const POWER_80: f64 = 0.84;
/// Redundancy below which an edge direction counts as unchecked (a bridge).
const BRIDGE: f64 = 1e-6;
/// Most edges x nodes (the solves' cost) for which the term is exact.
pub(crate) const MAX_WORK: f64 = 5e7;
/// Draws of the sampled sum (about 9 % on each variance).
const SAMPLES: usize = 64;
/// Seed of the first draw.
const SEED: u64 = 11;
/// Edges per parallel chunk (fixed, so the sums do not depend on the threads).
const CHUNK: usize = 32;

/// Per node, the variance (x, y, z, the edges' axes) that outlier edges the
/// test at `detect_sigma` could miss add to its shift, in the mean gauge of
/// its component; zero for nodes in no component. `edges`: the translation
/// blocks (b = identity, information in world axes) of the kept edges.
/// Exact up to [`MAX_WORK`] edges x nodes; above, the redundancies come from
/// the selected inverse and the sum is sampled ([`SAMPLES`] draws).
pub(crate) fn outlier_variances(
    n: usize,
    edges: &[BlockEdge],
    components: &[Vec<usize>],
    detect_sigma: f64,
) -> Option<Vec<Vector3<f64>>> {
    let system = Anchored::new(n, edges, components)?;
    let lambda = (detect_sigma + POWER_80).powi(2);
    let out = if edges.len() as f64 * n as f64 <= MAX_WORK {
        system.exact(edges, lambda)
    } else {
        system.sampled(edges, lambda)?
    };
    out.iter()
        .all(|v| v.iter().all(|x| x.is_finite()))
        .then_some(out)
}

/// The translation normal equations with each component anchored at its node
/// of most information (the leverages do not depend on the gauge; the effects
/// are moved to the mean gauge), factored.
struct Anchored<'a> {
    n: usize,
    fixed: Vec<bool>,
    /// Each component's free shifts, projected out of the effects (mean gauge).
    motions: Vec<ComponentMotions<'a, 3>>,
    factor: Factor<3>,
}

impl<'a> Anchored<'a> {
    fn new(n: usize, edges: &[BlockEdge], components: &'a [Vec<usize>]) -> Option<Self> {
        let mut diagonal = vec![Matrix3::zeros(); n];
        for e in edges {
            diagonal[e.i] += e.omega;
            diagonal[e.j] += e.omega;
        }
        let linked: Vec<&Vec<usize>> = components.iter().filter(|m| m.len() > 1).collect();
        let links = edges.iter().map(|e| (e.i, e.j, -e.omega));
        let (blocks, updates) = BUDGET_PER_NODE_AND_LINK;
        let budget = Budget::relative(n, edges.len(), blocks, updates);
        let members = linked.iter().map(|m| m.as_slice());
        let (factor, fixed) = anchored_factor(diagonal, links, members, budget)?;
        let shifts: Vec<Vec<Vector3<f64>>> =
            (0..3).map(|a| vec![Vector3::ith(a, 1.0); n]).collect();
        Some(Anchored {
            n,
            fixed,
            motions: component_motions(&shifts, components),
            factor,
        })
    }

    /// J^T g for an edge i -> j: g at j, -g at i (none at an anchor).
    fn add_edge(&self, rhs: &mut [Vector3<f64>], e: &BlockEdge, g: Vector3<f64>) {
        if !self.fixed[e.j] {
            rhs[e.j] += g;
        }
        if !self.fixed[e.i] {
            rhs[e.i] -= g;
        }
    }

    /// Each edge direction's effect solved for (three solves per edge).
    fn exact(&self, edges: &[BlockEdge], lambda: f64) -> Vec<Vector3<f64>> {
        let n = self.n;
        let partial: Vec<Vec<Vector3<f64>>> = edges
            .par_chunks(CHUNK)
            .map(|chunk| {
                let mut sum = vec![Vector3::zeros(); n];
                for e in chunk {
                    for (w, v) in directions(&e.omega) {
                        let g = v * w.sqrt();
                        let mut rhs = vec![Vector3::zeros(); n];
                        self.add_edge(&mut rhs, e, g);
                        let mut x = self.factor.solve(&rhs);
                        let redundancy = (1.0 - g.dot(&(x[e.j] - x[e.i]))).min(1.0);
                        if redundancy <= BRIDGE {
                            continue;
                        }
                        project_out(&mut x, &self.motions);
                        let weight = OUTLIER_RATE * lambda / redundancy;
                        for (s, xk) in sum.iter_mut().zip(&x) {
                            *s += xk.component_mul(xk) * weight;
                        }
                    }
                }
                sum
            })
            .collect();
        let mut out = vec![Vector3::zeros(); n];
        for part in &partial {
            out.iter_mut().zip(part).for_each(|(o, p)| *o += p);
        }
        out
    }

    /// The same sum as the covariance of x = C sum_e J^T g_e xi_e (xi_e
    /// standard normal per edge direction, g_e scaled by the square root of
    /// its weight), estimated from [`SAMPLES`] draws (relative error about
    /// 1 / sqrt(2 SAMPLES) per variance); the redundancies from the blocks of
    /// C at the edges (selected inversion).
    fn sampled(&self, edges: &[BlockEdge], lambda: f64) -> Option<Vec<Vector3<f64>>> {
        self.sampled_with(edges, lambda, SAMPLES)
    }

    fn sampled_with(
        &self,
        edges: &[BlockEdge],
        lambda: f64,
        samples: usize,
    ) -> Option<Vec<Vector3<f64>>> {
        let n = self.n;
        let links: Vec<(usize, usize)> = edges.iter().map(|e| (e.i, e.j)).collect();
        let diagonal = self.factor.inverse_diagonal();
        let cross = self.factor.inverse_links(&links);
        let block = |k: usize| {
            if self.fixed[k] {
                Matrix3::zeros()
            } else {
                diagonal[k]
            }
        };
        let mut scaled: Vec<(usize, Vector3<f64>)> = Vec::new();
        for (k, e) in edges.iter().enumerate() {
            let c_ij = if self.fixed[e.i] || self.fixed[e.j] {
                Matrix3::zeros()
            } else {
                cross[k]?
            };
            let q = block(e.i) + block(e.j) - c_ij - c_ij.transpose();
            for (w, v) in directions(&e.omega) {
                let g = v * w.sqrt();
                let redundancy = (1.0 - g.dot(&(q * g))).min(1.0);
                if redundancy > BRIDGE {
                    scaled.push((k, g * (OUTLIER_RATE * lambda / redundancy).sqrt()));
                }
            }
        }
        let mut out = vec![Vector3::zeros(); n];
        for s in 0..samples {
            let mut rng = SplitMix64::new(SEED + s as u64);
            let mut rhs = vec![Vector3::zeros(); n];
            for (k, g) in &scaled {
                self.add_edge(&mut rhs, &edges[*k], g * rng.normal());
            }
            let mut x = self.factor.solve(&rhs);
            project_out(&mut x, &self.motions);
            out.iter_mut()
                .zip(&x)
                .for_each(|(o, v)| *o += v.component_mul(v) / samples as f64);
        }
        Some(out)
    }
}

/// The directions of an edge's information with their weights (eigenvalues
/// above a relative 1e-12 of the largest).
fn directions(omega: &Matrix3<f64>) -> Vec<(f64, Vector3<f64>)> {
    let eig = omega.symmetric_eigen();
    let top = eig.eigenvalues.max();
    eig.eigenvalues
        .iter()
        .zip(eig.eigenvectors.column_iter())
        .filter(|(w, _)| top > 0.0 && **w > 1e-12 * top)
        .map(|(w, v)| (*w, v.into_owned()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn edge(i: usize, j: usize, sigma: f64) -> BlockEdge {
        BlockEdge {
            i,
            j,
            b: Matrix3::identity(),
            omega: Matrix3::identity() / (sigma * sigma),
            r0: Vector3::zeros(),
        }
    }

    /// A ring of `n` DSMs (centimetre edges) with a weak chord to the seventh
    /// next at every `chord_every`-th.
    fn ring(n: usize, chord_every: usize) -> Vec<BlockEdge> {
        let mut edges = Vec::new();
        for k in 0..n {
            edges.push(edge(k, (k + 1) % n, 0.01 + 0.001 * k as f64));
            if k % chord_every == 0 {
                edges.push(edge(k, (k + 7) % n, 0.5 + 0.1 * k as f64));
            }
        }
        edges
    }

    /// Two groups of three DSMs, each group a tight triangle (1 cm), joined by
    /// one 10 cm edge checked only by a weak 10 m one: an error of a metre on
    /// the 10 cm edge would pass the test and move every DSM of one group
    /// against the other, so each DSM gets decimetres; the same groups joined
    /// by two 10 cm edges check each other and get centimetres; joined by the
    /// 10 cm edge alone (a bridge: no check at all) it adds nothing (the
    /// triangles' own edges, checked, millimetres).
    #[test]
    fn a_group_that_hangs_on_an_unchecked_edge_gets_its_possible_error() {
        let triangles = |more: &[BlockEdge]| {
            let mut e = vec![
                edge(0, 1, 0.01),
                edge(1, 2, 0.01),
                edge(2, 0, 0.01),
                edge(3, 4, 0.01),
                edge(4, 5, 0.01),
                edge(5, 3, 0.01),
            ];
            e.extend_from_slice(more);
            e
        };
        let all = vec![(0..6).collect::<Vec<usize>>()];
        let sd = |edges: Vec<BlockEdge>| {
            outlier_variances(6, &edges, &all, 5.0)
                .unwrap()
                .iter()
                .map(|v| v.x.sqrt())
                .fold(0.0, f64::max)
        };
        let weakly_checked = sd(triangles(&[edge(2, 3, 0.1), edge(0, 5, 10.0)]));
        let checked = sd(triangles(&[edge(2, 3, 0.1), edge(0, 5, 0.1)]));
        let bridge = sd(triangles(&[edge(2, 3, 0.1)]));
        // weak check: r = 1e-4, the detectable bias 5.84 / 1e-2 = 584 sigmas
        // (58 m), each group half of it from the mean, at 1 %: 2.9 m
        assert!(weakly_checked > 1.0, "{weakly_checked}");
        assert!(checked < 0.05, "{checked}");
        assert!(bridge < 0.01, "{bridge}");
    }

    /// The sampled sum (large graphs) agrees with the exact one: a ring of 40
    /// DSMs with chords, 4000 draws (2 % per variance; 15 % allowed).
    #[test]
    fn the_sampled_sum_matches_the_exact_one() {
        let n = 40;
        let edges = ring(n, 3);
        let all = vec![(0..n).collect::<Vec<usize>>()];
        let system = Anchored::new(n, &edges, &all).unwrap();
        let exact = system.exact(&edges, 34.0);
        let sampled = system.sampled_with(&edges, 34.0, 4000).unwrap();
        for k in 0..n {
            for a in 0..2 {
                let ratio = sampled[k][a] / exact[k][a];
                assert!((ratio - 1.0).abs() < 0.15, "{k} {a}: {ratio}");
            }
        }
    }

    /// The same sums whatever the number of threads (fixed chunks, summed in order).
    #[test]
    fn the_sums_do_not_depend_on_the_threads() {
        let n = 40;
        let edges = ring(n, 1);
        let all = vec![(0..n).collect::<Vec<usize>>()];
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| outlier_variances(n, &edges, &all, 5.0).unwrap())
        };
        assert_eq!(run(1), run(3));
    }
}
