//! Edge residuals and outlier rejection. The residual of edge (i, j) compares the
//! averaged relative pose M_i^-1 M_j with the measured M_ij: the rotation between
//! them, and the offset of the image of the edge's centre (where the pair's
//! translation was measured). An edge is an outlier when either, normalised,
//! exceeds max(k * scale, floor), the scale being the median of the normalised
//! residuals over the active edges at the first round, kept for the later rounds (a
//! median taken again after each round shrinks as edges go, and rejection would
//! cascade through good edges). Normalised by the edge's own standard errors when
//! every edge has them and the options ask for it (per axis: a pair loose about one
//! axis is judged on that axis alone; the scale absorbs sigmas that are all too
//! small or too large, and the floor is in sigmas), else by the floors in metres and
//! degrees. Each round rejects only the clear culprits: edges at least half as bad as
//! the worst, and no two sharing a node (an outlier's error leaks into its
//! neighbours' residuals; re-solving shows the truth). A rejection that would
//! disconnect a component is turned into a down-weighting (w *= threshold /
//! residual), chosen Kruskal-style so the least bad edges keep the graph connected.

use super::EdgeResidual;
use crate::graph::{Edge, PoseGraph, UnionFind, VARIANCE_FLOOR_OF_MEDIAN};
use crate::poses::rigid::{rotation, translation};
use nalgebra::{Matrix3, Matrix4, Vector3};

/// Residuals of every edge (active or not) against the poses.
pub fn edge_residuals(graph: &PoseGraph, poses: &[Matrix4<f64>]) -> Vec<EdgeResidual> {
    residuals_of_parts(graph, |k| (rotation(&poses[k]), translation(&poses[k])))
}

/// Residuals against poses given as rotations and translations (no 4x4 copy of
/// them: at 10^6 nodes that is 128 MB).
pub(crate) fn residuals_of_parts(
    graph: &PoseGraph,
    pose: impl Fn(usize) -> (Matrix3<f64>, Vector3<f64>),
) -> Vec<EdgeResidual> {
    graph
        .edges
        .iter()
        .map(|e| {
            // M_i^-1 M_j = [R_i^T R_j, R_i^T (t_j - t_i)], applied to the centre.
            let ((r_i, t_i), (r_j, t_j)) = (pose(e.i), pose(e.j));
            let r_est = r_i.tr_mul(&r_j);
            let moved_est = r_i.tr_mul(&(r_j * e.centre_j + t_j - t_i));
            let rotation_rad = rotation_vector(&e.rotation().tr_mul(&r_est));
            let offset_m = moved_est - e.apply(&e.centre_j);
            EdgeResidual {
                rotation_deg: rotation_rad.norm().to_degrees(),
                translation_m: offset_m.norm(),
                rotation_rad: rotation_rad.cast(),
                offset_m: offset_m.cast(),
            }
        })
        .collect()
}

/// The rotation vector (axis times angle, radians) of a rotation matrix, accurate
/// for tiny angles.
pub(crate) fn rotation_vector(r: &Matrix3<f64>) -> Vector3<f64> {
    let skew = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    ) * 0.5;
    let sin = skew.norm();
    if sin == 0.0 {
        return skew;
    }
    skew * (sin.atan2((r.trace() - 1.0) * 0.5) / sin)
}

#[derive(Clone, Copy, Debug)]
pub(crate) struct OutlierRule {
    pub k: f64,
    pub floor_m: f64,
    pub floor_deg: f64,
    /// Floor of the normalised residuals when they are divided by the edges' sigmas.
    pub floor_sigma: f64,
    /// Divide by the edges' standard errors when every edge has them.
    pub by_sigma: bool,
}

/// What one round decided: edges to drop, and bridges to keep with a weight factor.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct OutlierRound {
    pub dropped: Vec<usize>,
    pub downweighted: Vec<(usize, f64)>,
}

/// The outlier test of one averaging: normalisation and limits fixed at the first round.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct OutlierTest {
    pub by_sigma: bool,
    /// Normalised rotation / translation residuals above these are outliers.
    pub limit_rotation: f64,
    pub limit_translation: f64,
    /// Smallest per-axis sigma believed (radians / metres): the information
    /// weights' variance floor, so that a pair claiming a tiny sigma (noise-free
    /// data) is neither over-weighted nor judged an outlier for centimetres.
    pub sigma_floor_rotation_rad: f64,
    pub sigma_floor_translation_m: f64,
}

/// A residual in units of its test: sigmas (per axis, root of the sum of squares) or
/// the floors (degrees / metres).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct NormalisedResidual {
    pub rotation: f64,
    pub translation: f64,
}

impl OutlierTest {
    /// Fixes the limits from the residuals of the first solve over the active edges.
    pub fn new(
        graph: &PoseGraph,
        weights: &[f64],
        residuals: &[EdgeResidual],
        rule: OutlierRule,
    ) -> Self {
        let by_sigma = rule.by_sigma && graph.edges.iter().all(|e| e.sigma.is_some());
        // per-axis sigma floors, as the weights' variance floor (mean over axes)
        let floor_of = |part: &dyn Fn(&crate::graph::EdgeSigma) -> Vector3<f64>| {
            let mut variances: Vec<f64> = (0..graph.edges.len())
                .filter(|&k| weights[k] > 0.0)
                .filter_map(|k| graph.edges[k].sigma.as_ref())
                .map(|s| part(s).norm_squared() / 3.0)
                .collect();
            if variances.is_empty() {
                return 0.0;
            }
            let mid = variances.len() / 2;
            let median = *variances.select_nth_unstable_by(mid, f64::total_cmp).1;
            (VARIANCE_FLOOR_OF_MEDIAN * median).sqrt()
        };
        let unit = OutlierTest {
            by_sigma,
            limit_rotation: 1.0,
            limit_translation: 1.0,
            sigma_floor_rotation_rad: floor_of(&|s| s.rotation_rad()),
            sigma_floor_translation_m: floor_of(&|s| s.translation_m()),
        };
        let normalised: Vec<NormalisedResidual> = (0..graph.edges.len())
            .filter(|&k| weights[k] > 0.0)
            .map(|k| unit.normalise(&graph.edges[k], &residuals[k], rule))
            .collect();
        let median = |f: &dyn Fn(&NormalisedResidual) -> f64| {
            let mut values: Vec<f64> = normalised.iter().map(f).collect();
            if values.is_empty() {
                return 0.0;
            }
            let mid = values.len() / 2;
            *values.select_nth_unstable_by(mid, f64::total_cmp).1
        };
        let floor = if by_sigma { rule.floor_sigma } else { 1.0 };
        OutlierTest {
            limit_rotation: (rule.k * median(&|r| r.rotation)).max(floor),
            limit_translation: (rule.k * median(&|r| r.translation)).max(floor),
            ..unit
        }
    }

    pub fn normalise(
        &self,
        edge: &Edge,
        residual: &EdgeResidual,
        rule: OutlierRule,
    ) -> NormalisedResidual {
        match edge.sigma.filter(|_| self.by_sigma) {
            Some(sigma) => NormalisedResidual {
                rotation: in_sigmas(
                    &residual.rotation_rad,
                    &sigma.rotation_rad(),
                    self.sigma_floor_rotation_rad,
                ),
                translation: in_sigmas(
                    &residual.offset_m,
                    &sigma.translation_m(),
                    self.sigma_floor_translation_m,
                ),
            },
            None => NormalisedResidual {
                rotation: residual.rotation_deg / rule.floor_deg,
                translation: residual.translation_m / rule.floor_m,
            },
        }
    }

    /// How far past its limit a residual is (> 1: outlier).
    fn badness(&self, r: NormalisedResidual) -> f64 {
        (r.rotation / self.limit_rotation).max(r.translation / self.limit_translation)
    }
}

/// |v / max(sigma, floor)| over the axes with a positive sigma (the others are
/// not estimated).
fn in_sigmas(v: &Vector3<f32>, sigma: &Vector3<f64>, floor: f64) -> f64 {
    v.iter()
        .zip(sigma.iter())
        .filter(|(_, &s)| s > 0.0)
        .map(|(&x, &s)| (x as f64 / s.max(floor)).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Picks this round's outliers among the active (weight > 0), unprotected edges.
pub(crate) fn select_outliers(
    graph: &PoseGraph,
    weights: &[f64],
    residuals: &[EdgeResidual],
    protected: &[bool],
    test: &OutlierTest,
    rule: OutlierRule,
) -> OutlierRound {
    let badness: Vec<f64> = graph
        .edges
        .iter()
        .zip(residuals)
        .map(|(e, r)| test.badness(test.normalise(e, r, rule)))
        .collect();
    let mut outliers: Vec<usize> = (0..graph.edges.len())
        .filter(|&k| weights[k] > 0.0 && !protected[k] && badness[k] > 1.0)
        .collect();
    if outliers.is_empty() {
        return OutlierRound::default();
    }
    outliers.sort_by(|&a, &b| badness[b].total_cmp(&badness[a]).then(a.cmp(&b)));
    let worst = badness[outliers[0]];
    let mut touched = vec![false; graph.n];
    let mut chosen = Vec::new();
    for &k in outliers.iter().take_while(|&&k| badness[k] >= 0.5 * worst) {
        let e = &graph.edges[k];
        if !touched[e.i] && !touched[e.j] {
            touched[e.i] = true;
            touched[e.j] = true;
            chosen.push(k);
        }
    }
    keep_connected(graph, weights, &chosen, &badness)
}

/// Splits `chosen` into drops and down-weighted bridges so that the active graph keeps
/// its components: every other active edge joins first, then the chosen ones from the
/// least bad, each kept only if it joins two still separate parts.
fn keep_connected(
    graph: &PoseGraph,
    weights: &[f64],
    chosen: &[usize],
    badness: &[f64],
) -> OutlierRound {
    let mut is_chosen = vec![false; graph.edges.len()];
    chosen.iter().for_each(|&k| is_chosen[k] = true);
    let mut sets = UnionFind::new(graph.n);
    for (k, e) in graph.edges.iter().enumerate() {
        if weights[k] > 0.0 && !is_chosen[k] {
            sets.union(e.i, e.j);
        }
    }
    let mut round = OutlierRound::default();
    for &k in chosen.iter().rev() {
        let e = &graph.edges[k];
        if sets.union(e.i, e.j) {
            round.downweighted.push((k, 1.0 / badness[k]));
        } else {
            round.dropped.push(k);
        }
    }
    round.dropped.sort_unstable();
    round
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::averaging::synthetic::{generate, SyntheticSpec, Topology};

    const RULE: OutlierRule = OutlierRule {
        k: 5.0,
        floor_m: 0.05,
        floor_deg: 0.005,
        floor_sigma: 4.0,
        by_sigma: true,
    };

    fn residual(translation_m: f64) -> EdgeResidual {
        EdgeResidual {
            rotation_deg: 0.0,
            translation_m,
            rotation_rad: Vector3::zeros(),
            offset_m: Vector3::new(translation_m as f32, 0.0, 0.0),
        }
    }

    /// The test as `average` builds it, then one round.
    fn one_round(
        graph: &PoseGraph,
        weights: &[f64],
        residuals: &[EdgeResidual],
        protected: &[bool],
    ) -> OutlierRound {
        let test = OutlierTest::new(graph, weights, residuals, RULE);
        select_outliers(graph, weights, residuals, protected, &test, RULE)
    }

    #[test]
    fn residuals_are_taken_at_the_centre() {
        // A measured rotation error of 0.01 deg about z turns about the centre: the
        // residual there is pure rotation, while at the origin, 300 m away, it
        // would be 5 cm of translation.
        let mut g = generate(&SyntheticSpec::exact(3, Topology::Chain { reach: 1 }, 1));
        let e = &mut g.graph.edges[0];
        e.centre_j = Vector3::new(300.0, 0.0, 0.0);
        let turn = crate::poses::rigid::rotation_from_axis_angle(&Vector3::new(
            0.0,
            0.0,
            1e-2f64.to_radians(),
        ));
        let about_centre =
            crate::poses::rigid::from_parts(&turn, &(e.centre_j - turn * e.centre_j));
        let m_ij = e.m_ij() * about_centre;
        e.set_m_ij(&m_ij);
        let r = edge_residuals(&g.graph, &g.truth)[0];
        assert!((r.rotation_deg - 0.01).abs() < 1e-12, "{r:?}");
        let expected = Vector3::new(0.0, 0.0, -1e-2f64.to_radians());
        assert!((r.rotation_rad.cast::<f64>() - expected).norm() < 1e-10);
        assert!(r.translation_m < 1e-9, "{r:?}");
        g.graph.edges[0].centre_j = Vector3::zeros();
        let r = edge_residuals(&g.graph, &g.truth)[0];
        assert!(
            (r.translation_m - 300.0 * 1e-2f64.to_radians()).abs() < 1e-6,
            "{r:?}"
        );
    }

    #[test]
    fn residuals_vanish_for_the_truth_and_see_a_bad_edge() {
        let mut g = generate(&SyntheticSpec::exact(20, Topology::Chain { reach: 2 }, 1));
        g.graph.edges[3].t_ij.x += 5.0;
        let residuals = edge_residuals(&g.graph, &g.truth);
        for (k, r) in residuals.iter().enumerate() {
            let expected = if k == 3 { 5.0 } else { 0.0 };
            assert!(
                (r.translation_m - expected).abs() < 1e-9 && r.rotation_deg < 1e-9,
                "{k}: {r:?}"
            );
        }
    }

    #[test]
    fn the_worst_edges_go_first_and_neighbours_wait() {
        // Chain of 21 nodes, each joined to the next two; node 20 hangs on the bridge (19, 20).
        let mut g = generate(&SyntheticSpec::exact(21, Topology::Chain { reach: 2 }, 1));
        g.graph.edges.remove(37); // (18, 20)
        assert_eq!((g.graph.edges[37].i, g.graph.edges[37].j), (19, 20));
        let weights = vec![1.0; 38];
        let protected = vec![false; 38];
        let with = |bad: &[(usize, f64)]| {
            let mut r = vec![residual(0.01); 38];
            bad.iter().for_each(|&(k, v)| r[k] = residual(v));
            r
        };
        // 10 = (5, 6) is worst; 11 = (5, 7) shares node 5 and waits; 20 = (10, 11) is
        // at least half as bad and goes too; 30 = (15, 16) is far less bad and waits.
        let residuals = with(&[(10, 4.0), (11, 3.0), (20, 2.5), (30, 1.0)]);
        let round = one_round(&g.graph, &weights, &residuals, &protected);
        assert_eq!(
            round,
            OutlierRound {
                dropped: vec![10, 20],
                downweighted: vec![]
            }
        );
        // The bridge is never dropped, only down-weighted.
        let residuals = with(&[(37, 2.5)]);
        let round = one_round(&g.graph, &weights, &residuals, &protected);
        assert_eq!(round.dropped, Vec::<usize>::new());
        assert_eq!(round.downweighted.len(), 1);
        assert_eq!(round.downweighted[0].0, 37);
        assert!((round.downweighted[0].1 - 0.05 / 2.5).abs() < 1e-12);
        // Protected edges are not looked at again.
        let mut protected_bridge = protected.clone();
        protected_bridge[37] = true;
        let round = one_round(&g.graph, &weights, &residuals, &protected_bridge);
        assert_eq!(round, OutlierRound::default());
        // Nothing above the floors (0.05 m here): nothing happens.
        let residuals = with(&[(3, 0.045)]);
        assert_eq!(
            one_round(&g.graph, &weights, &residuals, &protected),
            OutlierRound::default()
        );
    }

    fn with_sigma(edge: &mut Edge, rotation_rad: [f64; 3], translation_m: [f64; 3]) {
        edge.sigma = Some(crate::graph::EdgeSigma::new(
            Vector3::from(rotation_rad),
            Vector3::from(translation_m),
        ));
    }

    #[test]
    fn sigma_normalised_residuals_judge_each_axis_by_its_own_spread() {
        // 39 edges whose residuals are all about one sigma; sigma 0.1 m in x, 0.01 m in z.
        let mut g = generate(&SyntheticSpec::exact(21, Topology::Chain { reach: 2 }, 1));
        for e in &mut g.graph.edges {
            with_sigma(e, [1e-5; 3], [0.1, 0.1, 0.01]);
        }
        let n = g.graph.edges.len();
        let (weights, protected) = (vec![1.0; n], vec![false; n]);
        let mut residuals: Vec<EdgeResidual> = (0..n)
            .map(|k| EdgeResidual {
                offset_m: Vector3::new(0.1, 0.0, 0.005 * (k % 3) as f32),
                ..residual(0.0)
            })
            .collect();
        // Edge 5 is 0.3 m off in x (3 sigma): kept. Edge 30 is 0.3 m off in z (30 sigma).
        residuals[5].offset_m.x = 0.3;
        residuals[30].offset_m.z = 0.3;
        let round = one_round(&g.graph, &weights, &residuals, &protected);
        assert_eq!(round.dropped, vec![30]);
        // Without sigmas both are 0.3 m and the metre floors judge them alike.
        g.graph.edges[0].sigma = None;
        let test = OutlierTest::new(&g.graph, &weights, &residuals, RULE);
        assert!(!test.by_sigma);
    }

    #[test]
    fn sigmas_that_are_all_too_small_do_not_drop_everything() {
        // Every residual is 20 claimed sigmas: the scale absorbs it (limit 5 x 20),
        // and only the edge at 300 sigmas goes.
        let mut g = generate(&SyntheticSpec::exact(21, Topology::Chain { reach: 2 }, 1));
        for e in &mut g.graph.edges {
            with_sigma(e, [1e-6; 3], [0.001; 3]);
        }
        let n = g.graph.edges.len();
        let (weights, protected) = (vec![1.0; n], vec![false; n]);
        let mut residuals = vec![residual(0.02); n];
        residuals[12] = residual(0.3);
        let test = OutlierTest::new(&g.graph, &weights, &residuals, RULE);
        assert!((test.limit_translation - 100.0).abs() < 1e-5, "{test:?}"); // f32 residuals
        assert_eq!(test.limit_rotation, 4.0); // the floor, in sigmas
        let round = select_outliers(&g.graph, &weights, &residuals, &protected, &test, RULE);
        assert_eq!(round.dropped, vec![12]);
        // The limits stay for later rounds: with edge 12 gone, residuals of 5x the
        // new median (below the first) are not rejected.
        let mut weights = weights;
        weights[12] = 0.0;
        let mut later = vec![residual(0.004); n];
        later[3] = residual(0.05);
        let round = select_outliers(&g.graph, &weights, &later, &protected, &test, RULE);
        assert_eq!(round, OutlierRound::default());
    }
}
