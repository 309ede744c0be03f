//! The weighted graph Laplacian L = D - W of the active edges as a compact edge list
//! (one pass per product, prefetching the randomly accessed nodes), and the two
//! steps of aggregation coarsening used by [`super::multilevel`]: heavy-edge pairwise
//! matching and the aggregated (Galerkin) graph.

use super::cg::{prefetch, Lanes};

/// Edges looked ahead when prefetching the randomly accessed nodes.
const PREFETCH_DISTANCE: usize = 16;

/// A weighted graph Laplacian L = D - W as a compact edge list (i, j, w_ij).
pub(crate) struct Laplacian {
    pub n: usize,
    pub edges: Vec<(u32, u32, f64)>,
    pub degree: Vec<f64>,
}

impl Laplacian {
    pub fn new(n: usize, edges: Vec<(u32, u32, f64)>) -> Self {
        let mut degree = vec![0.0; n];
        for &(i, j, w) in &edges {
            degree[i as usize] += w;
            degree[j as usize] += w;
        }
        Laplacian { n, edges, degree }
    }

    /// out = L p, applied to every entry of the blocks.
    pub fn apply<B: Lanes>(&self, p: &[B], out: &mut [B]) {
        for ((o, pi), &d) in out.iter_mut().zip(p).zip(&self.degree) {
            *o = B::zero();
            o.axpy(d, pi);
        }
        for (k, &(i, j, w)) in self.edges.iter().enumerate() {
            if let Some(&(_, ahead, _)) = self.edges.get(k + PREFETCH_DISTANCE) {
                prefetch(p, ahead as usize);
                prefetch(out, ahead as usize);
            }
            let (i, j) = (i as usize, j as usize);
            out[i].axpy(-w, &p[j]);
            out[j].axpy(-w, &p[i]);
        }
    }
}

/// Heavy-edge matching: each node, in order, pairs with its unmatched neighbour of
/// largest weight (or stays alone). Returns node -> pair index and the pair count.
pub(crate) fn pair_match(laplacian: &Laplacian) -> (Vec<u32>, usize) {
    let n = laplacian.n;
    let mut offsets = vec![0u32; n + 1];
    for &(i, j, _) in &laplacian.edges {
        offsets[i as usize + 1] += 1;
        offsets[j as usize + 1] += 1;
    }
    for k in 0..n {
        offsets[k + 1] += offsets[k];
    }
    let mut fill = offsets.clone();
    // (neighbour, edge index): 8 bytes an entry, the weight read from the edge
    let mut neighbours = vec![(0u32, 0u32); offsets[n] as usize];
    for (k, &(i, j, _)) in laplacian.edges.iter().enumerate() {
        for (a, b) in [(i, j), (j, i)] {
            neighbours[fill[a as usize] as usize] = (b, k as u32);
            fill[a as usize] += 1;
        }
    }
    drop(fill);
    let mut pair_of = vec![u32::MAX; n];
    let mut pairs = 0u32;
    for k in 0..n {
        if pair_of[k] != u32::MAX {
            continue;
        }
        let candidates = &neighbours[offsets[k] as usize..offsets[k + 1] as usize];
        let best = candidates
            .iter()
            .filter(|&&(j, _)| pair_of[j as usize] == u32::MAX && j as usize != k)
            .map(|&(j, edge)| (j, laplacian.edges[edge as usize].2))
            .fold(None, |best: Option<(u32, f64)>, (j, w)| match best {
                Some((_, bw)) if bw >= w => best,
                _ => Some((j, w)),
            });
        pair_of[k] = pairs;
        if let Some((j, _)) = best {
            pair_of[j as usize] = pairs;
        }
        pairs += 1;
    }
    (pair_of, pairs as usize)
}

/// The edges between aggregates, parallel edges summed, internal edges dropped.
pub(crate) fn aggregate_edges(
    edges: &[(u32, u32, f64)],
    aggregate_of: &[u32],
) -> Vec<(u32, u32, f64)> {
    let mut keyed: Vec<(u64, f64)> = edges
        .iter()
        .filter_map(|&(i, j, w)| {
            let (a, b) = (aggregate_of[i as usize], aggregate_of[j as usize]);
            (a != b).then(|| (((a.min(b) as u64) << 32) | a.max(b) as u64, w))
        })
        .collect();
    keyed.sort_unstable_by_key(|&(key, _)| key);
    // Sum parallel edges in place, then reuse the buffer (same size and
    // alignment): no second edge list at any time.
    let mut len = 0;
    for k in 0..keyed.len() {
        if len > 0 && keyed[len - 1].0 == keyed[k].0 {
            keyed[len - 1].1 += keyed[k].1;
        } else {
            keyed[len] = keyed[k];
            len += 1;
        }
    }
    keyed.truncate(len);
    keyed
        .into_iter()
        .map(|(key, w)| ((key >> 32) as u32, key as u32, w))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aggregation_merges_parallel_edges_and_drops_internal_ones() {
        let edges = vec![(0, 1, 1.0), (1, 2, 2.0), (0, 3, 0.5), (2, 3, 4.0)];
        let merged = aggregate_edges(&edges, &[0, 0, 1, 1]);
        assert_eq!(merged, vec![(0, 1, 2.5)]);
        let (pairs, count) = pair_match(&Laplacian::new(4, edges));
        assert_eq!(count, 2);
        // 0 pairs with its heavier neighbour 1 (1.0 > 0.5); 2 then takes 3.
        assert_eq!(pairs, vec![0, 0, 1, 1]);
    }
}
