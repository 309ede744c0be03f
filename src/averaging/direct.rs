//! Sparse direct solves of block normal equations (one D x D block per node):
//! a block Cholesky factor H = L L^T in a minimum-degree elimination order.
//!
//! On sparse, nearly tree-like graphs (the percolating graph of a grid of small
//! tiles, where most pairs come out degenerate) the conjugate-gradient solves
//! need thousands of iterations, because such a graph has almost no spectral
//! gap, while elimination in minimum-degree order creates almost no fill: the
//! factor costs about as much as a few CG iterations. The symbolic phase counts
//! the fill first and gives up above a budget ([`Budget`]), so well-connected 2-D
//! grids, where the fill grows as n log n and the work as n^1.5, stay with CG.
//!
//! Minimum degree here is the exact rule (explicit elimination graph, ties to the
//! lower node index): deterministic, and cheap wherever the budget lets it run,
//! because its own cost is that of the factor.

use nalgebra::{SMatrix, SVector};
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Limits of a factor, in blocks: off-diagonal blocks kept, and block updates
/// (one D x D product each) spent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Budget {
    pub max_blocks: usize,
    pub max_updates: usize,
}

impl Budget {
    /// A factor within `blocks` and `updates` times the size of the system (nodes
    /// plus links): the memory of the system itself, and the work of that many
    /// preconditioned CG iterations, give or take.
    /// No factor at all (too many links per node to be worth analysing) when
    /// `links` exceeds [`MAX_LINKS_PER_NODE`] x `nodes`.
    pub fn relative(nodes: usize, links: usize, blocks: usize, updates: usize) -> Self {
        let size = nodes + links;
        if links as f64 > MAX_LINKS_PER_NODE * nodes as f64 {
            return Budget {
                max_blocks: 0,
                max_updates: 0,
            };
        }
        Budget {
            max_blocks: blocks.saturating_mul(size),
            max_updates: updates.saturating_mul(size),
        }
    }
}

/// Graphs with more links per node than this are not analysed: a grid of tiles
/// with all its 8-neighbour pairs has about 4, and the analysis of a large one
/// would run long before it exceeded the budget (2 x 10^6 nodes: minutes). The
/// sparse graphs the factor is for have 1 to 2 (a percolating grid of small
/// tiles: 1.4).
pub(crate) const MAX_LINKS_PER_NODE: f64 = 2.5;

/// Merged adjacency entries the analysis may spend per block update of the
/// budget: an entry is an integer compare and copy, an update a D x D block
/// product (216 multiply-adds for D = 6).
const ANALYSIS_PER_UPDATE: usize = 16;

/// The elimination order and the structure of the factor.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Symbolic {
    /// Node eliminated at each position.
    order: Vec<usize>,
    /// Position of each node.
    position: Vec<usize>,
    /// For each position, the later positions its column of L holds (sorted).
    columns: Vec<Vec<usize>>,
    /// Block updates the factor costs.
    pub updates: usize,
}

/// The sorted union of `a` and `b`, without `skip_a` and `skip_b`.
fn merge(a: &[usize], b: &[usize], skip_a: usize, skip_b: usize) -> Vec<usize> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut x, mut y) = (0, 0);
    while x < a.len() || y < b.len() {
        let next = match (a.get(x), b.get(y)) {
            (Some(&u), Some(&v)) if u == v => {
                x += 1;
                y += 1;
                u
            }
            (Some(&u), Some(&v)) if u < v => {
                x += 1;
                u
            }
            (Some(&u), None) => {
                x += 1;
                u
            }
            (_, Some(&v)) => {
                y += 1;
                v
            }
            (None, None) => unreachable!(),
        };
        if next != skip_a && next != skip_b {
            out.push(next);
        }
    }
    out
}

/// Each of `n` nodes' neighbours under `links` (either order, repeats and
/// self-links allowed), sorted and without repeats.
pub(crate) fn adjacency_lists(
    n: usize,
    links: impl IntoIterator<Item = (usize, usize)>,
) -> Vec<Vec<usize>> {
    let mut adjacency: Vec<Vec<usize>> = vec![Vec::new(); n];
    for (i, j) in links {
        if i != j {
            adjacency[i].push(j);
            adjacency[j].push(i);
        }
    }
    for a in &mut adjacency {
        a.sort_unstable();
        a.dedup();
    }
    adjacency
}

impl Symbolic {
    /// Minimum-degree elimination of the graph of `n` nodes and these links
    /// (repeats and self-links allowed); None when the factor would exceed `budget`.
    pub fn analyse(
        n: usize,
        links: impl IntoIterator<Item = (usize, usize)>,
        budget: Budget,
    ) -> Option<Self> {
        if budget.max_blocks == 0 && n > 0 {
            return None;
        }
        let mut adjacency = adjacency_lists(n, links);
        let mut heap: BinaryHeap<Reverse<(usize, usize)>> =
            (0..n).map(|k| Reverse((adjacency[k].len(), k))).collect();
        let mut eliminated = vec![false; n];
        let mut position = vec![usize::MAX; n];
        let mut order = Vec::with_capacity(n);
        let mut columns = Vec::with_capacity(n);
        // Work of the analysis itself (merged adjacency entries, each far cheaper
        // than a block update): bounded by ANALYSIS_PER_UPDATE x the update
        // budget, so a graph over budget is given up quickly.
        let (mut blocks, mut updates, mut work) = (0usize, 0usize, 0usize);
        while let Some(Reverse((degree, k))) = heap.pop() {
            // Stale entries (the degree changed since) are skipped: every change
            // pushed the current one.
            if eliminated[k] || degree != adjacency[k].len() {
                continue;
            }
            eliminated[k] = true;
            position[k] = order.len();
            order.push(k);
            let neighbours = std::mem::take(&mut adjacency[k]);
            blocks += neighbours.len();
            updates += neighbours.len() * (neighbours.len() + 1) / 2;
            if blocks > budget.max_blocks || updates > budget.max_updates {
                tracing::debug!(
                    n,
                    eliminated = order.len(),
                    blocks,
                    updates,
                    "elimination over budget"
                );
                return None;
            }
            // A leaf only leaves its neighbour's list (a hub of many leaves would
            // otherwise cost its degree per leaf).
            if let [a] = neighbours[..] {
                if let Ok(at) = adjacency[a].binary_search(&k) {
                    adjacency[a].remove(at);
                }
                work += 1;
                heap.push(Reverse((adjacency[a].len(), a)));
                columns.push(neighbours);
                continue;
            }
            // The neighbours of k become a clique.
            for &a in &neighbours {
                work += adjacency[a].len() + neighbours.len();
                if work > budget.max_updates.saturating_mul(ANALYSIS_PER_UPDATE) {
                    tracing::debug!(
                        n,
                        eliminated = order.len(),
                        work,
                        "elimination analysis over budget"
                    );
                    return None;
                }
                adjacency[a] = merge(&adjacency[a], &neighbours, a, k);
                heap.push(Reverse((adjacency[a].len(), a)));
            }
            columns.push(neighbours);
        }
        for column in &mut columns {
            column.iter_mut().for_each(|a| *a = position[*a]);
            column.sort_unstable();
        }
        tracing::debug!(n, blocks, updates, "elimination analysed");
        Some(Symbolic {
            order,
            position,
            columns,
            updates,
        })
    }

    /// The numeric factor of H: `diagonal[k]` is node k's block, `off` gives
    /// blocks H_ij (row i, column j; H_ji is its transpose) of linked nodes,
    /// repeats summed. None when H is not positive definite to working precision.
    pub fn factor<const D: usize>(
        self,
        diagonal: &[SMatrix<f64, D, D>],
        off: impl IntoIterator<Item = (usize, usize, SMatrix<f64, D, D>)>,
    ) -> Option<Factor<D>> {
        let n = self.order.len();
        let mut diag: Vec<SMatrix<f64, D, D>> = self.order.iter().map(|&k| diagonal[k]).collect();
        let mut blocks: Vec<Vec<SMatrix<f64, D, D>>> = self
            .columns
            .iter()
            .map(|c| vec![SMatrix::zeros(); c.len()])
            .collect();
        for (i, j, h) in off {
            let (pi, pj) = (self.position[i], self.position[j]);
            // Stored below the diagonal: row = later position, column = earlier.
            let (row, column, block) = if pi > pj {
                (pi, pj, h)
            } else {
                (pj, pi, h.transpose())
            };
            let at = self.columns[column].binary_search(&row).ok()?;
            blocks[column][at] += block;
        }
        let mut inverse = Vec::with_capacity(n);
        for p in 0..n {
            let l = diag[p].cholesky()?.unpack();
            let l_inv = l.solve_lower_triangular(&SMatrix::identity())?;
            if !l_inv.iter().all(|v| v.is_finite()) {
                return None;
            }
            let (done, rest) = blocks.split_at_mut(p + 1);
            let column = &mut done[p];
            for b in column.iter_mut() {
                *b *= l_inv.transpose();
            }
            let rows = &self.columns[p];
            for (u, &b) in rows.iter().enumerate() {
                let l_bp = column[u];
                diag[b] -= l_bp * l_bp.transpose();
                for (v, &a) in rows.iter().enumerate().skip(u + 1) {
                    let target = &mut rest[b - p - 1];
                    let at = self.columns[b].binary_search(&a).ok()?;
                    target[at] -= column[v] * l_bp.transpose();
                }
            }
            inverse.push(l_inv);
        }
        Some(Factor {
            symbolic: self,
            inverse,
            blocks,
        })
    }
}

/// H = L L^T: the inverses of L's diagonal blocks and its blocks below them.
pub(crate) struct Factor<const D: usize> {
    symbolic: Symbolic,
    inverse: Vec<SMatrix<f64, D, D>>,
    blocks: Vec<Vec<SMatrix<f64, D, D>>>,
}

impl<const D: usize> Factor<D> {
    /// The diagonal blocks of H^-1, one per node (selected inversion: the
    /// Takahashi recurrence on the factor's pattern, from the last position back,
    /// at the cost of the factor). With Z = H^-1 and S_p the later positions in
    /// column p, L^T Z = L^-1 gives, for q in S_p,
    /// Z_pq = -L_pp^-T sum_{a in S_p} L_ap^T Z_aq, and
    /// Z_pp = L_pp^-T (L_pp^-1 - sum_{a in S_p} L_ap^T Z_ap);
    /// every Z_aq needed is on the pattern (S_p is a clique of the factor).
    pub fn inverse_diagonal(&self) -> Vec<SMatrix<f64, D, D>> {
        let (diag, _) = self.selected_inverse();
        let mut out = vec![SMatrix::zeros(); diag.len()];
        for (p, &k) in self.symbolic.order.iter().enumerate() {
            out[k] = diag[p];
        }
        out
    }

    /// The blocks Z_ij of H^-1 for `links` (i, j), by the same recurrence: every
    /// link of H is on the factor's pattern (None for a pair that is not).
    pub fn inverse_links(&self, links: &[(usize, usize)]) -> Vec<Option<SMatrix<f64, D, D>>> {
        let (diag, z) = self.selected_inverse();
        let s = &self.symbolic;
        links
            .iter()
            .map(|&(i, j)| {
                let (pi, pj) = (s.position[i], s.position[j]);
                if pi == pj {
                    return Some(diag[pi]);
                }
                // z[p][u] = Z_ap for a = S_p[u], a later than p
                let (a, p) = (pi.max(pj), pi.min(pj));
                let u = s.columns[p].binary_search(&a).ok()?;
                let z_ap = z[p][u];
                Some(if pi > pj { z_ap } else { z_ap.transpose() })
            })
            .collect()
    }

    /// The diagonal blocks of H^-1 by position and its blocks on the factor's
    /// pattern (`z[p][u]` = Z_ap for a = S_p[u]).
    #[allow(clippy::type_complexity)]
    fn selected_inverse(&self) -> (Vec<SMatrix<f64, D, D>>, Vec<Vec<SMatrix<f64, D, D>>>) {
        let s = &self.symbolic;
        let n = s.order.len();
        let mut diag = vec![SMatrix::<f64, D, D>::zeros(); n];
        // z[p][u] = Z_ap for a = S_p[u] (below the diagonal, like L).
        let mut z: Vec<Vec<SMatrix<f64, D, D>>> = s
            .columns
            .iter()
            .map(|c| vec![SMatrix::zeros(); c.len()])
            .collect();
        for p in (0..n).rev() {
            let rows = &s.columns[p];
            let l = &self.blocks[p];
            let inv_t = self.inverse[p].transpose();
            // Z_aq for a, q in S_p (a, q > p).
            let entry = |a: usize, q: usize, z: &[Vec<SMatrix<f64, D, D>>]| {
                if a == q {
                    diag[a]
                } else if a > q {
                    z[q][s.columns[q].binary_search(&a).expect("on the pattern")]
                } else {
                    z[a][s.columns[a].binary_search(&q).expect("on the pattern")].transpose()
                }
            };
            let column: Vec<SMatrix<f64, D, D>> = rows
                .iter()
                .map(|&q| {
                    let mut sum = SMatrix::<f64, D, D>::zeros();
                    for (&a, l_ap) in rows.iter().zip(l) {
                        sum += l_ap.tr_mul(&entry(a, q, &z));
                    }
                    // Z_pq; stored as Z_qp = Z_pq^T.
                    -(inv_t * sum)
                })
                .map(|z_pq| z_pq.transpose())
                .collect();
            let mut sum = SMatrix::<f64, D, D>::zeros();
            for (l_ap, z_ap) in l.iter().zip(&column) {
                sum += l_ap.tr_mul(z_ap);
            }
            let z_pp = inv_t * (self.inverse[p] - sum);
            diag[p] = (z_pp + z_pp.transpose()) * 0.5;
            z[p] = column;
        }
        (diag, z)
    }

    /// x = H^-1 rhs.
    pub fn solve(&self, rhs: &[SVector<f64, D>]) -> Vec<SVector<f64, D>> {
        let s = &self.symbolic;
        let mut y: Vec<SVector<f64, D>> = s.order.iter().map(|&k| rhs[k]).collect();
        for p in 0..y.len() {
            y[p] = self.inverse[p] * y[p];
            let yp = y[p];
            for (&a, l) in s.columns[p].iter().zip(&self.blocks[p]) {
                y[a] -= l * yp;
            }
        }
        for p in (0..y.len()).rev() {
            let mut sum = y[p];
            for (&a, l) in s.columns[p].iter().zip(&self.blocks[p]) {
                sum -= l.tr_mul(&y[a]);
            }
            y[p] = self.inverse[p].tr_mul(&sum);
        }
        let mut x = vec![SVector::zeros(); y.len()];
        for (p, &k) in s.order.iter().enumerate() {
            x[k] = y[p];
        }
        x
    }
}

/// The off-diagonal blocks a direct solve may keep, and the block updates it may
/// spend, per node and link of the system ([`Budget::relative`]). A nearly
/// tree-like graph needs few (a percolating 100 x 100 grid with 36 % of its
/// pairs: 1.5 and 8); a well-connected grid of 10^4 tiles many more (8 blocks),
/// and there CG with a multilevel preconditioner is cheaper (measured:
/// tools/bench/informed.rs).
pub(crate) const BUDGET_PER_NODE_AND_LINK: (usize, usize) = (8, 128);

/// A system H x = rhs over `n` nodes for [`solve_within_budget`]: its block
/// diagonal, its off-diagonal blocks H_ij of linked nodes, and H applied to a
/// vector (to measure the residual).
pub(crate) struct BlockMatrix<'a, const D: usize, L, A>
where
    L: Iterator<Item = (usize, usize, SMatrix<f64, D, D>)> + Clone,
    A: Fn(&[SVector<f64, D>], &mut [SVector<f64, D>]),
{
    pub diagonal: Vec<SMatrix<f64, D, D>>,
    pub off: L,
    pub apply: &'a A,
}

/// H x = rhs by a sparse block Cholesky factor when the graph's elimination fill
/// is within [`BUDGET_PER_NODE_AND_LINK`] and the solution, after up to two
/// steps of iterative refinement, meets `tolerance` (its error energy
/// r^T H^-1 r measured with the factor); None otherwise.
pub(crate) fn solve_within_budget<const D: usize, L, A>(
    h: BlockMatrix<'_, D, L, A>,
    rhs: &[SVector<f64, D>],
    tolerance: crate::averaging::cg::StepTolerance,
) -> Option<Vec<SVector<f64, D>>>
where
    L: Iterator<Item = (usize, usize, SMatrix<f64, D, D>)> + Clone,
    A: Fn(&[SVector<f64, D>], &mut [SVector<f64, D>]),
{
    let n = h.diagonal.len();
    let links = h.off.clone().count();
    let (blocks, updates) = BUDGET_PER_NODE_AND_LINK;
    let budget = Budget::relative(n, links, blocks, updates);
    let symbolic = Symbolic::analyse(n, h.off.clone().map(|(i, j, _)| (i, j)), budget)?;
    let factor = symbolic.factor(&h.diagonal, h.off)?;
    let dot = |a: &[SVector<f64, D>], b: &[SVector<f64, D>]| {
        a.iter().zip(b).map(|(x, y)| x.dot(y)).sum::<f64>()
    };
    let b_norm = dot(rhs, rhs).sqrt();
    let mut x = factor.solve(rhs);
    let mut q = vec![SVector::zeros(); n];
    for _ in 0..3 {
        (h.apply)(&x, &mut q);
        let r: Vec<SVector<f64, D>> = rhs.iter().zip(&q).map(|(b, q)| b - q).collect();
        let z = factor.solve(&r);
        if tolerance.met(dot(&r, &r).sqrt(), b_norm, dot(&r, &z), D * n) {
            return Some(x);
        }
        x.iter_mut().zip(&z).for_each(|(x, z)| *x += z);
    }
    None
}

impl Factor<1> {
    /// x <- H^-1 x for `width` right-hand sides at once: `x` holds node k's
    /// entries at k * width .. (k + 1) * width (a scalar factor, e.g. of a
    /// weighted graph Laplacian, applied to vectors or matrices per node).
    pub fn solve_lanes(&self, x: &mut [f64], width: usize) {
        let s = &self.symbolic;
        let n = s.order.len();
        let mut y = vec![0.0; n * width];
        for (p, &k) in s.order.iter().enumerate() {
            y[p * width..(p + 1) * width].copy_from_slice(&x[k * width..(k + 1) * width]);
        }
        for p in 0..n {
            let inverse = self.inverse[p][(0, 0)];
            let (head, tail) = y.split_at_mut((p + 1) * width);
            let yp = &mut head[p * width..];
            yp.iter_mut().for_each(|v| *v *= inverse);
            for (&a, l) in s.columns[p].iter().zip(&self.blocks[p]) {
                let l = l[(0, 0)];
                let at = (a - p - 1) * width;
                for (t, v) in tail[at..at + width].iter_mut().zip(yp.iter()) {
                    *t -= l * v;
                }
            }
        }
        for p in (0..n).rev() {
            let (head, tail) = y.split_at_mut((p + 1) * width);
            let yp = &mut head[p * width..];
            for (&a, l) in s.columns[p].iter().zip(&self.blocks[p]) {
                let l = l[(0, 0)];
                let at = (a - p - 1) * width;
                for (v, t) in yp.iter_mut().zip(&tail[at..at + width]) {
                    *v -= l * t;
                }
            }
            let inverse = self.inverse[p][(0, 0)];
            yp.iter_mut().for_each(|v| *v *= inverse);
        }
        for (p, &k) in s.order.iter().enumerate() {
            x[k * width..(k + 1) * width].copy_from_slice(&y[p * width..(p + 1) * width]);
        }
    }
}

#[cfg(test)]
mod tests;
