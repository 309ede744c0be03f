//! The hard decisions that end the informed averaging ([`super`], step 3): a
//! few edges dropped per round (see [`select`]), the undecided edges still
//! Cauchy-weighted so that outliers not yet dropped do not bend the poses; an
//! edge dropped while a worse one bent them comes back (once) when it fits
//! again, or when no kept edge opposes it ([`unopposed`]). When nothing
//! changes, the kept edges are solved at full weight and judged once more.

use nalgebra::{Matrix3, Matrix6, Vector3};

use super::refine::refine;
use super::reseed::unopposed;
use super::{cauchy_weights, InformedOptions};
use crate::averaging::consistency::{mahalanobis_residuals, select};
use crate::graph::PoseGraph;

/// Where the decisions ended.
pub(super) struct Decisions {
    /// Each edge's weight factor: 1 kept, 0 dropped, in between down-weighted.
    pub active: Vec<f64>,
    /// Edges down-weighted at some round (unsorted, may repeat).
    pub downweighted: Vec<usize>,
    /// Conjugate-gradient iterations of the refinements.
    pub iterations: usize,
    /// Mahalanobis residuals at the final poses.
    pub mahalanobis: Vec<(f64, f64)>,
}

/// Runs the decision rounds (at most 4 x `options.max_rounds`) from the poses
/// given, whose residuals are `mahalanobis`; `usable` edges may be kept.
pub(super) fn decide(
    graph: &PoseGraph,
    omegas: &[Matrix6<f64>],
    usable: &[f64],
    options: &InformedOptions,
    mahalanobis: Vec<(f64, f64)>,
    (rotations, translations): (&mut [Matrix3<f64>], &mut [Vector3<f64>]),
) -> Decisions {
    let edges = graph.edges.len();
    let mut out = Decisions {
        active: usable.to_vec(),
        downweighted: Vec::new(),
        iterations: 0,
        mahalanobis,
    };
    let mut readmitted = vec![false; edges];
    let mut full_weight = false;
    for _ in 0..4 * options.max_rounds {
        let (active, mahalanobis) = (&mut out.active, &out.mahalanobis);
        let (dropped, downweighted) = select(graph, active, mahalanobis, options);
        let mut back: Vec<usize> = (0..edges)
            .filter(|&k| active[k] == 0.0 && usable[k] > 0.0 && !readmitted[k])
            .filter(|&k| mahalanobis[k].0.max(mahalanobis[k].1) < options.outlier_sigma)
            .collect();
        let candidates: Vec<f64> = (0..edges)
            .map(|k| if readmitted[k] { 0.0 } else { usable[k] })
            .collect();
        let unopposed_edges = unopposed(
            graph,
            omegas,
            (active, &candidates),
            mahalanobis,
            options.outlier_sigma,
            (&mut *rotations, &mut *translations),
        );
        if !unopposed_edges.is_empty() {
            tracing::info!(edges = unopposed_edges.len(), "unopposed edges readmitted");
        }
        back.extend(unopposed_edges);
        let changed = !(dropped.is_empty() && downweighted.is_empty() && back.is_empty());
        if !changed && full_weight {
            break;
        }
        for &k in &back {
            active[k] = usable[k];
            readmitted[k] = true;
        }
        for &k in &dropped {
            active[k] = 0.0;
        }
        for &(k, f) in &downweighted {
            active[k] *= f;
            out.downweighted.push(k);
        }
        full_weight = !changed;
        let weights: Vec<f64> = if full_weight {
            active.clone()
        } else {
            cauchy_weights(mahalanobis, active, options.outlier_sigma)
        };
        out.iterations += refine(graph, omegas, &weights, options, rotations, translations);
        out.mahalanobis = mahalanobis_residuals(graph, omegas, rotations, translations);
    }
    out
}
