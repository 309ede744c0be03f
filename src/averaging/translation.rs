//! Translation averaging given the rotations (paper step 4): weighted linear least
//! squares  min sum_ij w_ij |t_j - t_i - R_i t_ij|^2  (from t_ij = R_i^T (t_j - t_i)).
//! The normal equations are the weighted graph Laplacian L t = b with three
//! right-hand sides (x, y, z), solved by conjugate gradient with the Jacobi
//! preconditioner: one pass over a compact edge list per iteration, O(edges) time and
//! O(nodes + edges) memory. L is singular (one constant per component); b is made
//! consistent by removing its per-component mean, and the solution keeps the
//! per-component mean of the start, fixed later by the gauge.

use super::cg::{pcg, CgReport, CgTolerance};
use crate::graph::{Components, PoseGraph};
use crate::poses::rigid::translation;
use nalgebra::{Matrix3, Vector3};

#[derive(Clone, Debug)]
pub(crate) struct TranslationSolution {
    pub translations: Vec<Vector3<f64>>,
    pub report: CgReport,
}

/// Solves for t_i given R_i, starting from `initial`.
pub(crate) fn solve_translations(
    graph: &PoseGraph,
    weights: &[f64],
    components: &Components,
    rotations: &[Matrix3<f64>],
    initial: Vec<Vector3<f64>>,
    tolerance: CgTolerance,
) -> TranslationSolution {
    let n = graph.n;
    let mut lap_edges: Vec<(u32, u32, f64)> = Vec::new();
    let mut degree = vec![0.0; n];
    let mut rhs = vec![Vector3::zeros(); n];
    for (e, &w) in graph.edges.iter().zip(weights) {
        if w > 0.0 {
            lap_edges.push((e.i as u32, e.j as u32, w));
            degree[e.i] += w;
            degree[e.j] += w;
            let offset = rotations[e.i] * translation(&e.m_ij) * w;
            rhs[e.j] += offset;
            rhs[e.i] -= offset;
        }
    }
    remove_component_means(components, &mut rhs);
    let apply = |p: &[Vector3<f64>], out: &mut [Vector3<f64>]| {
        for ((o, pi), &d) in out.iter_mut().zip(p).zip(&degree) {
            *o = pi * d;
        }
        for &(i, j, w) in &lap_edges {
            let (i, j) = (i as usize, j as usize);
            out[i] -= p[j] * w;
            out[j] -= p[i] * w;
        }
    };
    let precondition = |r: &[Vector3<f64>], out: &mut [Vector3<f64>]| {
        for ((o, ri), &d) in out.iter_mut().zip(r).zip(&degree) {
            *o = if d > 0.0 { ri / d } else { Vector3::zeros() };
        }
    };
    let mut translations = initial;
    let report = pcg(apply, precondition, rhs, &mut translations, tolerance);
    tracing::debug!(
        iterations = report.iterations,
        converged = report.converged,
        "translations solved"
    );
    TranslationSolution {
        translations,
        report,
    }
}

/// v_i -= mean of v over i's component.
fn remove_component_means(components: &Components, v: &mut [Vector3<f64>]) {
    for members in &components.members {
        let mean = members.iter().map(|&k| v[k]).sum::<Vector3<f64>>() / members.len() as f64;
        for &k in members {
            v[k] -= mean;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::averaging::synthetic::{generate, SyntheticSpec, Topology};
    use crate::poses::rigid::rotation;

    #[test]
    fn exact_rotations_give_exact_translations_up_to_a_shift() {
        let synthetic = generate(&SyntheticSpec::exact(200, Topology::Grid { width: 20 }, 9));
        let weights: Vec<f64> = synthetic.graph.edges.iter().map(|e| e.weight).collect();
        let rotations: Vec<_> = synthetic.truth.iter().map(rotation).collect();
        let tolerance = CgTolerance {
            relative: 1e-12,
            absolute: 0.0,
            max_iter: 2000,
        };
        let components = synthetic.graph.components();
        let solution = solve_translations(
            &synthetic.graph,
            &weights,
            &components,
            &rotations,
            vec![Vector3::zeros(); 200],
            tolerance,
        );
        assert!(solution.report.converged);
        let shift = solution.translations[0] - translation(&synthetic.truth[0]);
        for (est, tru) in solution.translations.iter().zip(&synthetic.truth) {
            assert!((est - translation(tru) - shift).norm() < 1e-9);
        }
    }
}
