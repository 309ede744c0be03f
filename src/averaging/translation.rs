//! Translation averaging given the rotations (paper step 4): weighted linear least
//! squares  min sum_ij w_ij |t_j - t_i - b_ij|^2, b_ij = R_i M_ij c - R_j c, from
//! M_i M_ij c = M_j c at the point c of j's frame where the pair's translation was
//! measured (its overlap centre). With c = 0 this is the paper's
//! b_ij = R_i t_ij (from t_ij = R_i^T (t_j - t_i)); at the centre, M_ij c depends on
//! the pair's translation alone, so the pair's rotation error (seen by the rotation
//! averaging) does not come back through the lever arm |c|.
//! The normal equations are the weighted graph Laplacian L t = b with three
//! right-hand sides (x, y, z), solved by conjugate gradient preconditioned by the
//! Jacobi step or the multigrid V-cycle ([`super::multilevel`]): one pass over a
//! compact edge list per iteration, O(edges) time and O(nodes + edges) memory. L is singular (one constant per component); b is made
//! consistent by removing its per-component mean, and the solution keeps the
//! per-component mean of the start, fixed later by the gauge.

use super::cg::{pcg, CgReport, CgTolerance};
use super::multilevel::Multilevel;
use crate::graph::{Components, PoseGraph};
use nalgebra::{Matrix3, Vector3};

#[derive(Clone, Debug)]
pub(crate) struct TranslationSolution {
    pub translations: Vec<Vector3<f64>>,
    pub report: CgReport,
}

/// Solves for t_i given R_i, starting from `initial`; `hierarchy` holds the weighted
/// Laplacian of the active edges and its preconditioner.
pub(crate) fn solve_translations(
    graph: &PoseGraph,
    weights: &[f64],
    components: &Components,
    rotations: &[Matrix3<f64>],
    hierarchy: &Multilevel,
    initial: Vec<Vector3<f64>>,
    tolerance: CgTolerance,
) -> TranslationSolution {
    let mut rhs = vec![Vector3::zeros(); graph.n];
    for (e, &w) in graph.edges.iter().zip(weights) {
        if w > 0.0 {
            let b_ij = rotations[e.i] * e.apply(&e.centre_j) - rotations[e.j] * e.centre_j;
            let offset = b_ij * w;
            rhs[e.j] += offset;
            rhs[e.i] -= offset;
        }
    }
    remove_component_means(components, &mut rhs);
    let laplacian = hierarchy.finest();
    let mut work = hierarchy.workspace();
    let mut translations = initial;
    let report = pcg(
        |p, out| laplacian.apply(p, out),
        |r, out| hierarchy.apply(&|k| r[k], out, &mut work),
        rhs,
        &mut translations,
        tolerance,
    );
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
    use crate::poses::rigid::{rotation, translation};

    #[test]
    fn exact_rotations_give_exact_translations_up_to_a_shift() {
        let synthetic = generate(&SyntheticSpec::exact(2000, Topology::Grid { width: 50 }, 9));
        let weights: Vec<f64> = synthetic.graph.edges.iter().map(|e| e.weight).collect();
        let rotations: Vec<_> = synthetic.truth.iter().map(rotation).collect();
        let tolerance = CgTolerance {
            relative: 1e-12,
            absolute: 0.0,
            max_iter: 2000,
        };
        let components = synthetic.graph.components();
        let hierarchy = Multilevel::new(
            super::super::active_laplacian(&synthetic.graph, &weights),
            true,
        );
        let solution = solve_translations(
            &synthetic.graph,
            &weights,
            &components,
            &rotations,
            &hierarchy,
            vec![Vector3::zeros(); 2000],
            tolerance,
        );
        assert!(solution.report.converged);
        let shift = solution.translations[0] - translation(&synthetic.truth[0]);
        for (est, tru) in solution.translations.iter().zip(&synthetic.truth) {
            assert!((est - translation(tru) - shift).norm() < 1e-9);
        }
    }
}
