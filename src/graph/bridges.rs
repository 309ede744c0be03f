//! Bridges of an undirected multigraph: the edges whose removal splits their
//! component (Tarjan's low-link rule, iterative so that long chains of 10^6
//! nodes do not overflow the stack). Parallel edges are never bridges.

/// `result[k]` is true when edge k of `pairs` is live and a bridge of the graph
/// the live edges form (self-loops and dead edges: false).
pub fn bridges(n: usize, pairs: &[(usize, usize)], live: &[bool]) -> Vec<bool> {
    let mut adjacent = vec![Vec::new(); n];
    for (k, &(a, b)) in pairs.iter().enumerate() {
        if live[k] && a != b {
            adjacent[a].push((b, k));
            adjacent[b].push((a, k));
        }
    }
    const UNSEEN: usize = usize::MAX;
    let (mut discovered, mut low) = (vec![UNSEEN; n], vec![0usize; n]);
    let mut bridge = vec![false; pairs.len()];
    let mut clock = 0;
    for root in 0..n {
        if discovered[root] != UNSEEN {
            continue;
        }
        discovered[root] = clock;
        low[root] = clock;
        clock += 1;
        // (node, edge it was reached by, next neighbour to look at)
        let mut stack = vec![(root, UNSEEN, 0usize)];
        while let Some(top) = stack.last_mut() {
            let (v, via) = (top.0, top.1);
            if let Some(&(w, k)) = adjacent[v].get(top.2) {
                top.2 += 1;
                if k == via {
                    continue;
                }
                if discovered[w] == UNSEEN {
                    discovered[w] = clock;
                    low[w] = clock;
                    clock += 1;
                    stack.push((w, k, 0));
                } else {
                    low[v] = low[v].min(discovered[w]);
                }
            } else {
                stack.pop();
                if let Some(&(u, _, _)) = stack.last() {
                    low[u] = low[u].min(low[v]);
                    if low[v] > discovered[u] {
                        bridge[via] = true;
                    }
                }
            }
        }
    }
    bridge
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_triangle_with_a_tail_has_the_tail_as_bridges() {
        // 0-1-2-0 triangle, 2-3, 3-4 tail, 5-6 parallel pair, 7 alone
        let pairs = [(0, 1), (1, 2), (2, 0), (2, 3), (3, 4), (5, 6), (6, 5)];
        let b = bridges(8, &pairs, &[true; 7]);
        assert_eq!(b, vec![false, false, false, true, true, false, false]);
        // a dead edge of the triangle makes the rest of it bridges
        let b = bridges(8, &pairs, &[false, true, true, true, true, true, false]);
        assert_eq!(b, vec![false, true, true, true, true, true, false]);
    }

    #[test]
    fn a_long_chain_is_all_bridges() {
        let n = 200_000;
        let pairs: Vec<(usize, usize)> = (0..n - 1).map(|k| (k, k + 1)).collect();
        let b = bridges(n, &pairs, &vec![true; n - 1]);
        assert!(b.iter().all(|&x| x));
    }
}
