//! The pairs' rotation prior in the poses' sigmas: counted once per DSM.

use super::*;

/// Pairs whose fits were held by the rotation prior carry it in their
/// rotation information; the poses' sigmas count it once per DSM. On a chain
/// whose edges know their rotations mostly through a 1e-3 rad prior (the data
/// alone: 3.2e-3 rad), each DSM's rotation sigma is near the prior's, not the
/// fraction of it that counting the prior on every edge would claim.
#[test]
fn the_rotation_prior_counts_once_in_the_pose_sigmas() {
    let prior_rad: f64 = 1e-3;
    let data_information = 1e5;
    let options = InformedOptions {
        rotation_prior_rad: prior_rad,
        ..InformedOptions::default()
    };
    let mut case = case_chain(6, 11);
    for info in &mut case.information {
        info.rotation = Matrix3::identity() * (prior_rad.powi(-2) + data_information);
    }
    let sigmas = |information: &[EdgeInformation]| -> Vec<f64> {
        let result = average_informed(&case.graph, information, &options).unwrap();
        result
            .sigma
            .iter()
            .map(|s| s.rotation_deg[2].to_radians())
            .collect()
    };
    let counted_per_edge = sigmas(&case.information);
    let marked: Vec<EdgeInformation> = case
        .information
        .iter()
        .map(|i| i.with_rotation_prior(prior_rad))
        .collect();
    let once = sigmas(&marked);
    for (k, (&per_edge, &once)) in counted_per_edge.iter().zip(&once).enumerate() {
        // counted on each edge: 0.57-0.76 of the prior's sigma here
        assert!(per_edge < 0.8 * prior_rad, "node {k}: {per_edge}");
        assert!(
            once > 0.9 * prior_rad && once <= prior_rad,
            "node {k}: {once}"
        );
    }
    // the data alone: what is left once the prior's part is taken off
    let data = marked[0].without_prior().rotation;
    assert!((data - Matrix3::identity() * data_information).amax() < 1e-6 * data_information);
    // a direction the edge holds less about than the prior keeps a share
    let weak = EdgeInformation {
        rotation: Matrix3::identity() * 0.5 * prior_rad.powi(-2),
        ..case.information[0]
    }
    .with_rotation_prior(prior_rad);
    let kept = weak.without_prior().rotation[(0, 0)] / weak.rotation[(0, 0)];
    assert!((kept - (1.0 - MOST_PRIOR_SHARE)).abs() < 1e-9, "{kept}");
}
