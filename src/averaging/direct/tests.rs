use super::*;
use crate::rng::SplitMix64;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// An off-diagonal block H_ij: (i, j, block).
type OffBlock = (usize, usize, Matrix3<f64>);

/// A random SPD block system on the given links: diagonal blocks dominate.
fn system(n: usize, links: &[(usize, usize)], seed: u64) -> (Vec<Matrix3<f64>>, Vec<OffBlock>) {
    let mut rng = SplitMix64::new(seed);
    let mut diagonal = vec![Matrix3::identity() * 1e-3; n];
    let mut off = Vec::new();
    for &(i, j) in links {
        let a = Matrix3::from_fn(|_, _| rng.normal());
        let omega = a * a.transpose() + Matrix3::identity();
        let b = Matrix3::from_fn(|_, _| 0.1 * rng.normal()) + Matrix3::identity();
        // Residual x_j - b x_i: H_ii += b^T O b, H_jj += O, H_ij = -b^T O.
        diagonal[i] += b.transpose() * omega * b;
        diagonal[j] += omega;
        off.push((i, j, -(b.transpose() * omega)));
    }
    (diagonal, off)
}

fn dense(n: usize, diagonal: &[Matrix3<f64>], off: &[OffBlock]) -> DMatrix<f64> {
    let mut h = DMatrix::zeros(3 * n, 3 * n);
    for (k, d) in diagonal.iter().enumerate() {
        let mut v = h.view_mut((3 * k, 3 * k), (3, 3));
        v += d;
    }
    for &(i, j, b) in off {
        let mut v = h.view_mut((3 * i, 3 * j), (3, 3));
        v += b;
        let mut v = h.view_mut((3 * j, 3 * i), (3, 3));
        v += b.transpose();
    }
    h
}

fn unbounded() -> Budget {
    Budget {
        max_blocks: usize::MAX,
        max_updates: usize::MAX,
    }
}

#[test]
fn the_factor_solves_a_random_graph_as_a_dense_solve_does() {
    let mut rng = SplitMix64::new(5);
    let n = 60;
    // A cycle plus random chords, one repeated link and one self-link.
    let mut links: Vec<(usize, usize)> = (0..n).map(|k| (k, (k + 1) % n)).collect();
    for _ in 0..40 {
        let i = (rng.next_f64() * n as f64) as usize;
        let j = (rng.next_f64() * n as f64) as usize;
        if i != j {
            links.push((i, j));
        }
    }
    links.push((3, 4));
    let (diagonal, off) = system(n, &links, 9);
    let rhs: Vec<Vector3<f64>> = (0..n)
        .map(|_| Vector3::new(rng.normal(), rng.normal(), rng.normal()))
        .collect();
    let symbolic = Symbolic::analyse(n, links.iter().copied(), unbounded()).unwrap();
    let factor = symbolic.factor(&diagonal, off.iter().copied()).unwrap();
    let x = factor.solve(&rhs);
    let h = dense(n, &diagonal, &off);
    let b = DVector::from_iterator(3 * n, rhs.iter().flat_map(|v| v.iter().copied()));
    let expected = h.cholesky().unwrap().solve(&b);
    let got = DVector::from_iterator(3 * n, x.iter().flat_map(|v| v.iter().copied()));
    assert!((got - &expected).amax() <= 1e-9 * expected.amax());
}

#[test]
fn the_selected_inverse_is_the_diagonal_of_the_dense_inverse() {
    let mut rng = SplitMix64::new(11);
    let n = 40;
    let mut links: Vec<(usize, usize)> = (1..n).map(|k| (k / 3, k)).collect();
    for _ in 0..25 {
        let i = (rng.next_f64() * n as f64) as usize;
        let j = (rng.next_f64() * n as f64) as usize;
        if i != j {
            links.push((i, j));
        }
    }
    let (diagonal, off) = system(n, &links, 4);
    let symbolic = Symbolic::analyse(n, links.iter().copied(), unbounded()).unwrap();
    let factor = symbolic.factor(&diagonal, off.iter().copied()).unwrap();
    let selected = factor.inverse_diagonal();
    let inverse = dense(n, &diagonal, &off).try_inverse().unwrap();
    for (k, block) in selected.iter().enumerate() {
        let expected = inverse.view((3 * k, 3 * k), (3, 3));
        assert!((block - expected).amax() <= 1e-9 * expected.amax(), "{k}");
    }
}

#[test]
fn a_tree_is_eliminated_without_fill_and_a_dense_graph_exceeds_a_small_budget() {
    // A binary tree: leaves first, every column holds one block (its parent).
    let n = 63;
    let tree: Vec<(usize, usize)> = (1..n).map(|k| ((k - 1) / 2, k)).collect();
    let symbolic = Symbolic::analyse(n, tree.iter().copied(), unbounded()).unwrap();
    assert!(symbolic.columns.iter().all(|c| c.len() <= 1));
    assert_eq!(symbolic.updates, n - 1);
    // The complete graph on 30 nodes: 435 blocks, over a budget of 100.
    let complete: Vec<(usize, usize)> = (0..30)
        .flat_map(|i| (i + 1..30).map(move |j| (i, j)))
        .collect();
    let budget = Budget {
        max_blocks: 100,
        max_updates: usize::MAX,
    };
    assert!(Symbolic::analyse(30, complete.iter().copied(), budget).is_none());
    assert!(Symbolic::analyse(30, complete.iter().copied(), unbounded()).is_some());
}

#[test]
fn lanes_of_a_scalar_factor_solve_like_one_column_each() {
    // The Laplacian of a path plus a chord, shifted to be definite.
    let links = [(0, 1), (1, 2), (2, 3), (3, 4), (0, 3)];
    let mut diagonal = vec![nalgebra::Matrix1::new(0.5); 5];
    let mut off = Vec::new();
    for &(i, j) in &links {
        diagonal[i][(0, 0)] += 2.0;
        diagonal[j][(0, 0)] += 2.0;
        off.push((i, j, nalgebra::Matrix1::new(-2.0)));
    }
    let factor = Symbolic::analyse(5, links, unbounded())
        .unwrap()
        .factor(&diagonal, off)
        .unwrap();
    let width = 3;
    let rhs: Vec<f64> = (0..5 * width).map(|v| (v as f64).sin()).collect();
    let mut lanes = rhs.clone();
    factor.solve_lanes(&mut lanes, width);
    for c in 0..width {
        let column: Vec<nalgebra::Vector1<f64>> = (0..5)
            .map(|k| nalgebra::Vector1::new(rhs[k * width + c]))
            .collect();
        let x = factor.solve(&column);
        for k in 0..5 {
            assert!((x[k][0] - lanes[k * width + c]).abs() < 1e-12);
        }
    }
}

#[test]
fn an_indefinite_matrix_gives_no_factor() {
    let diagonal = vec![Matrix3::identity(), -Matrix3::identity()];
    let symbolic = Symbolic::analyse(2, [(0, 1)], unbounded()).unwrap();
    let off = [(0, 1, Matrix3::identity() * 0.1)];
    assert!(symbolic.factor(&diagonal, off).is_none());
}

#[test]
fn merge_is_a_sorted_union_without_the_skipped() {
    assert_eq!(merge(&[1, 3, 5], &[2, 3, 6], 5, 2), vec![1, 3, 6]);
    assert_eq!(merge(&[], &[4], 0, 0), vec![4]);
}

#[test]
fn graphs_with_many_links_per_node_are_not_analysed() {
    // 10 nodes, 30 links: over 2.5 links per node, whatever the budget factors.
    let budget = Budget::relative(10, 30, 1000, 1000);
    assert_eq!(budget.max_blocks, 0);
    let links = (0..30).map(|k| (k % 10, (k * 3 + 1) % 10));
    assert!(Symbolic::analyse(10, links, budget).is_none());
    assert!(Budget::relative(10, 20, 3, 32).max_blocks > 0);
}
