//! Gauge-free marginal covariances of a pose graph's normal equations H, shared
//! by the decoupled (3 x 3 blocks: [`super::covariance`]) and the joint (6 x 6:
//! [`super::joint`]) covariance: the free motions of each component, and the
//! exact marginals by selected inversion of a sparse factor ([`super::direct`]).
//!
//! Each component is anchored at its node of most information (its block of
//! the anchored inverse C is zero): C is the covariance in the gauge that
//! holds the anchor. The reported gauge sets the component's conditions G x
//! to zero (the joint graph: mean rotation and mean shift at the pivots; the
//! decoupled one: the motions' own directions, an orthogonal projection).
//! With V the free motions (node k's block V_k, the motions as columns), G_k
//! node k's block of G (the conditions as rows) and A = G V, the oblique
//! projection P = I - V A^-1 G moves any gauge there, and node k's block of
//! P C P^T is C_kk - V_k A^-1 S_k^T - S_k A^-T V_k^T + V_k A^-1 T A^-T V_k^T,
//! with S = C G^T and T = G C G^T = sum_k G_k S_k. (An orthogonal projection
//! of the joint motions would mix radians with metres and trade a loose shift
//! for a rotation: two 90 m SRTM DSMs got roll sigmas of 0.19 deg from their
//! 4.5 m shift sigmas.)

use nalgebra::{SMatrix, SVector};

use super::direct::{Budget, Factor, Symbolic};

/// The free motions of one component: its members and an orthonormal basis of
/// the motions, each vector given by its blocks at those members (zero
/// elsewhere; a dense vector per component and motion would be quadratic in a
/// graph of many components).
pub(crate) struct ComponentMotions<'a, const D: usize> {
    pub members: &'a [usize],
    pub basis: Vec<Vec<SVector<f64, D>>>,
    /// The gauge's conditions, one per motion, given like the basis: the rows
    /// of G (module doc). The basis itself gives the orthogonal projection.
    pub conditions: Vec<Vec<SVector<f64, D>>>,
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

/// Moves `x` (a vector in any gauge) to the reported gauge of each
/// component: x_k -= V_k A^-1 sum_j G_j x_j (module doc).
pub(crate) fn to_mean_gauge<const D: usize>(
    x: &mut [SVector<f64, D>],
    motions: &[ComponentMotions<D>],
) {
    for c in motions.iter().filter(|c| c.members.len() > 1) {
        let Some(b) = c.blocks() else {
            continue;
        };
        let sum: SVector<f64, D> = c.members.iter().zip(&b.g).map(|(&k, g)| g * x[k]).sum();
        let shift = b.a_inv * sum;
        for (&k, vk) in c.members.iter().zip(&b.v) {
            x[k] -= vk * shift;
        }
    }
}

/// A component's motions and conditions as blocks (module doc).
struct Blocks<const D: usize> {
    v: Vec<SMatrix<f64, D, D>>,
    g: Vec<SMatrix<f64, D, D>>,
    a_inv: SMatrix<f64, D, D>,
}

impl<const D: usize> ComponentMotions<'_, D> {
    /// V_k, G_k and A^-1 = (sum_k G_k V_k)^-1; None unless there are D
    /// motions and conditions and A is invertible.
    fn blocks(&self) -> Option<Blocks<D>> {
        if self.basis.len() != D || self.conditions.len() != D {
            return None;
        }
        let v: Vec<SMatrix<f64, D, D>> = (0..self.members.len())
            .map(|m| SMatrix::from_fn(|r, a| self.basis[a][m][r]))
            .collect();
        let g: Vec<SMatrix<f64, D, D>> = (0..self.members.len())
            .map(|m| SMatrix::from_fn(|a, r| self.conditions[a][m][r]))
            .collect();
        let a: SMatrix<f64, D, D> = g.iter().zip(&v).map(|(g, v)| g * v).sum();
        Some(Blocks {
            a_inv: a.try_inverse()?,
            v,
            g,
        })
    }
}

/// The factor of H with each component (`members`) anchored at its node of
/// most information (the largest trace of its diagonal block: the anchored
/// inverse is the covariance in the gauge that holds it), and which nodes are
/// fixed: the anchors and the nodes outside the components, decoupled with an
/// identity block. None when the factor exceeds `budget` or H is not positive
/// definite there.
pub(crate) fn anchored_factor<'a, const D: usize>(
    mut diagonal: Vec<SMatrix<f64, D, D>>,
    links: impl Iterator<Item = (usize, usize, SMatrix<f64, D, D>)> + Clone,
    members: impl Iterator<Item = &'a [usize]>,
    budget: Budget,
) -> Option<(Factor<D>, Vec<bool>)> {
    let n = diagonal.len();
    let mut fixed = vec![true; n];
    for members in members {
        let anchor = members.iter().copied().max_by(|&a, &b| {
            diagonal[a]
                .trace()
                .total_cmp(&diagonal[b].trace())
                .then(b.cmp(&a))
        })?;
        members.iter().for_each(|&k| fixed[k] = k == anchor);
    }
    for (d, _) in diagonal.iter_mut().zip(&fixed).filter(|(_, &f)| f) {
        *d = SMatrix::identity();
    }
    let off = links.filter(|(i, j, _)| !fixed[*i] && !fixed[*j]);
    let symbolic = Symbolic::analyse(n, off.clone().map(|(i, j, _)| (i, j)), budget)?;
    let factor = symbolic.factor(&diagonal, off)?;
    Some((factor, fixed))
}

/// The diagonal of each node's block of P C P^T (module doc), from H's diagonal
/// blocks and its blocks H_ij of linked nodes; zero for nodes in no component
/// of two or more. None when the factor exceeds `budget` or the anchored
/// matrix is not positive definite (a component with more free directions than
/// `motions` names).
pub(crate) fn gauge_free_marginals<const D: usize>(
    diagonal: Vec<SMatrix<f64, D, D>>,
    links: impl Iterator<Item = (usize, usize, SMatrix<f64, D, D>)> + Clone,
    motions: &[ComponentMotions<D>],
    budget: Budget,
) -> Option<Vec<SVector<f64, D>>> {
    let n = diagonal.len();
    let linked: Vec<&ComponentMotions<D>> =
        motions.iter().filter(|c| c.members.len() > 1).collect();
    let blocks: Vec<_> = linked.iter().map(|c| c.blocks()).collect::<Option<_>>()?;
    let members = linked.iter().map(|c| c.members);
    let (factor, fixed) = anchored_factor(diagonal, links, members, budget)?;
    let mut c = factor.inverse_diagonal();
    // S = C G^T: the components are decoupled, so one solve per condition
    // serves all of them.
    let mut s = vec![SMatrix::<f64, D, D>::zeros(); n];
    for a in 0..D {
        let mut rhs = vec![SVector::zeros(); n];
        for comp in &linked {
            for (&k, g) in comp.members.iter().zip(&comp.conditions[a]) {
                if !fixed[k] {
                    rhs[k] = *g;
                }
            }
        }
        let x = factor.solve(&rhs);
        for k in (0..n).filter(|&k| !fixed[k]) {
            s[k].set_column(a, &x[k]);
        }
    }
    for (k, block) in c.iter_mut().enumerate() {
        if fixed[k] {
            *block = SMatrix::zeros();
        }
    }
    let mut out = vec![SVector::zeros(); n];
    for (comp, b) in linked.iter().zip(&blocks) {
        let t: SMatrix<f64, D, D> = comp.members.iter().zip(&b.g).map(|(&k, g)| g * s[k]).sum();
        let middle = b.a_inv * t * b.a_inv.transpose();
        for (&k, vk) in comp.members.iter().zip(&b.v) {
            let left = vk * b.a_inv * s[k].transpose();
            let block = c[k] - left - left.transpose() + vk * middle * vk.transpose();
            out[k] = block.diagonal();
        }
    }
    out.iter()
        .all(|d| d.iter().all(|x| x.is_finite()))
        .then_some(out)
}
