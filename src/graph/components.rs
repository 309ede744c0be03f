//! Connected components of the scene graph: [`UnionFind`] (path halving, union
//! by size) and [`Components`] (members per component, ordered by their smallest
//! node).

/// Disjoint sets with path halving and union by size.
#[derive(Clone, Debug)]
pub struct UnionFind {
    parent: Vec<u32>,
    size: Vec<u32>,
}

impl UnionFind {
    pub fn new(n: usize) -> Self {
        UnionFind {
            parent: (0..n as u32).collect(),
            size: vec![1; n],
        }
    }

    pub fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] as usize != x {
            let grand = self.parent[self.parent[x] as usize];
            self.parent[x] = grand;
            x = grand as usize;
        }
        x
    }

    /// Joins the sets of a and b; false when they were already one set.
    pub fn union(&mut self, a: usize, b: usize) -> bool {
        let (mut ra, mut rb) = (self.find(a), self.find(b));
        if ra == rb {
            return false;
        }
        if self.size[ra] < self.size[rb] {
            std::mem::swap(&mut ra, &mut rb);
        }
        self.parent[rb] = ra as u32;
        self.size[ra] += self.size[rb];
        true
    }
}

/// Connected components: `members[c]` lists the nodes of component c in ascending
/// order; components are ordered by their smallest node; `component_of[node] = c`.
#[derive(Clone, Debug, PartialEq)]
pub struct Components {
    pub component_of: Vec<usize>,
    pub members: Vec<Vec<usize>>,
}

impl Components {
    pub fn new(n: usize, pairs: impl Iterator<Item = (usize, usize)>) -> Self {
        let mut sets = UnionFind::new(n);
        for (a, b) in pairs {
            sets.union(a, b);
        }
        let mut of_root = vec![usize::MAX; n];
        let mut members: Vec<Vec<usize>> = Vec::new();
        let component_of: Vec<usize> = (0..n)
            .map(|node| {
                let root = sets.find(node);
                if of_root[root] == usize::MAX {
                    of_root[root] = members.len();
                    members.push(Vec::new());
                }
                members[of_root[root]].push(node);
                of_root[root]
            })
            .collect();
        Components {
            component_of,
            members,
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::graph::fixtures::{edge, pose};
    use crate::graph::PoseGraph;

    #[test]
    fn components_split_and_order() {
        let mut g = PoseGraph::new(6);
        let truth: Vec<_> = (0..6).map(|k| pose(k as f64)).collect();
        g.edges = vec![
            edge(&truth, 4, 2, 0.5),
            edge(&truth, 0, 5, 0.5),
            edge(&truth, 1, 3, 0.5),
        ];
        g.edges[2].weight = 0.0; // ignored: 1 and 3 stay apart
        let c = g.components();
        assert_eq!(c.members, vec![vec![0, 5], vec![1], vec![2, 4], vec![3]]);
        assert_eq!(c.component_of, vec![0, 1, 2, 3, 2, 0]);
    }
}
