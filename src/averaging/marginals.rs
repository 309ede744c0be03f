//! Gauge-free marginal covariances of a pose graph's normal equations H, shared
//! by the decoupled (3 x 3 blocks: [`super::covariance`]) and the joint (6 x 6:
//! [`super::joint`]) covariance: the free motions of each component, and the
//! exact marginals by selected inversion of a sparse factor ([`super::direct`]).
//!
//! Each component is anchored at its node of most information (its block of
//! the anchored inverse C is zero); C is then a generalised inverse of H, and
//! with V the component's orthonormal free motions and P = I - V V^T,
//! P C P = H^+: node k's block is C_kk - V_k W_k^T - W_k V_k^T + V_k (V^T W) V_k^T
//! with W = C V.

use nalgebra::{SMatrix, SVector};

use super::direct::{Budget, Symbolic};

/// The free motions of one component: its members and an orthonormal basis of
/// the motions, each vector given by its blocks at those members (zero
/// elsewhere; a dense vector per component and motion would be quadratic in a
/// graph of many components).
pub(crate) struct ComponentMotions<'a, const D: usize> {
    pub members: &'a [usize],
    pub basis: Vec<Vec<SVector<f64, D>>>,
}

/// The motions as dense vectors over all `n` nodes (for a dense inverse).
pub(crate) fn dense<const D: usize>(
    n: usize,
    motions: &[ComponentMotions<D>],
) -> Vec<Vec<SVector<f64, D>>> {
    let mut out = Vec::new();
    for c in motions {
        for b in &c.basis {
            let mut v = vec![SVector::zeros(); n];
            c.members.iter().zip(b).for_each(|(&k, x)| v[k] = *x);
            out.push(v);
        }
    }
    out
}

/// Projects the free motions out of `x`.
pub(crate) fn project_out<const D: usize>(
    x: &mut [SVector<f64, D>],
    motions: &[ComponentMotions<D>],
) {
    for c in motions {
        for b in &c.basis {
            let d: f64 = c.members.iter().zip(b).map(|(&k, y)| x[k].dot(y)).sum();
            c.members.iter().zip(b).for_each(|(&k, y)| x[k] -= y * d);
        }
    }
}

/// The diagonal of each node's block of P H^+ P (module doc), from H's diagonal
/// blocks and its blocks H_ij of linked nodes; zero for nodes in no component
/// of two or more. None when the factor exceeds `budget` or the anchored
/// matrix is not positive definite (a component with more free directions than
/// `motions` names).
pub(crate) fn gauge_free_marginals<const D: usize>(
    mut diagonal: Vec<SMatrix<f64, D, D>>,
    links: impl Iterator<Item = (usize, usize, SMatrix<f64, D, D>)> + Clone,
    motions: &[ComponentMotions<D>],
    budget: Budget,
) -> Option<Vec<SVector<f64, D>>> {
    let n = diagonal.len();
    let linked: Vec<&ComponentMotions<D>> =
        motions.iter().filter(|c| c.members.len() > 1).collect();
    // Anchors and nodes outside the components are decoupled with an identity block.
    let mut fixed = vec![true; n];
    for c in &linked {
        let anchor = c.members.iter().copied().max_by(|&a, &b| {
            diagonal[a]
                .trace()
                .total_cmp(&diagonal[b].trace())
                .then(b.cmp(&a))
        })?;
        c.members.iter().for_each(|&k| fixed[k] = k == anchor);
    }
    for (d, _) in diagonal.iter_mut().zip(&fixed).filter(|(_, &f)| f) {
        *d = SMatrix::identity();
    }
    let off = links.filter(|(i, j, _)| !fixed[*i] && !fixed[*j]);
    let symbolic = Symbolic::analyse(n, off.clone().map(|(i, j, _)| (i, j)), budget)?;
    let factor = symbolic.factor(&diagonal, off)?;
    let mut c = factor.inverse_diagonal();
    // W = C V: the components are decoupled, so one solve per motion index
    // serves all of them.
    let count = linked.iter().map(|c| c.basis.len()).max().unwrap_or(0);
    let (mut v, mut w) = (
        vec![SMatrix::<f64, D, D>::zeros(); n],
        vec![SMatrix::<f64, D, D>::zeros(); n],
    );
    for a in 0..count {
        let mut rhs = vec![SVector::zeros(); n];
        for comp in &linked {
            if let Some(b) = comp.basis.get(a) {
                for (&k, x) in comp.members.iter().zip(b) {
                    v[k].set_column(a, x);
                    if !fixed[k] {
                        rhs[k] = *x;
                    }
                }
            }
        }
        let x = factor.solve(&rhs);
        for k in (0..n).filter(|&k| !fixed[k]) {
            w[k].set_column(a, &x[k]);
        }
    }
    for (k, block) in c.iter_mut().enumerate() {
        if fixed[k] {
            *block = SMatrix::zeros();
        }
    }
    let mut out = vec![SVector::zeros(); n];
    for comp in &linked {
        let vtw: SMatrix<f64, D, D> = comp.members.iter().map(|&k| v[k].tr_mul(&w[k])).sum();
        for &k in comp.members {
            let (vk, wk) = (v[k], w[k]);
            let block =
                c[k] - vk * wk.transpose() - wk * vk.transpose() + vk * vtw * vk.transpose();
            out[k] = block.diagonal();
        }
    }
    out.iter()
        .all(|d| d.iter().all(|x| x.is_finite()))
        .then_some(out)
}
