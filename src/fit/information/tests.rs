//! Tests of [`super`]: degenerate directions named on a flat plane and a ridge,
//! and standard errors that cover the truth when residuals are correlated.

use super::*;
use crate::fit::{point_to_plane_prior, point_to_plane_with, Correspondence, FitSigma, Model};
use crate::rng::SplitMix64;
use nalgebra::{Isometry3, Point3, UnitQuaternion, Vector3};

/// Points of z = f(x, y) on an n x n lattice with their analytic normals.
fn surface(n: usize, f: impl Fn(f64, f64) -> (f64, f64, f64)) -> Vec<(Vector3<f64>, Vector3<f64>)> {
    let mut out = Vec::new();
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f64 - n as f64 / 2.0, j as f64 - n as f64 / 2.0);
            let (z, dzdx, dzdy) = f(x, y);
            out.push((
                Vector3::new(x, y, z),
                Vector3::new(-dzdx, -dzdy, 1.0).normalize(),
            ));
        }
    }
    out
}

fn wavy(x: f64, y: f64) -> (f64, f64, f64) {
    (
        (x / 3.0).sin() * 3.0 + (y / 4.0).cos() * 2.0,
        (x / 3.0).cos(),
        -(y / 4.0).sin() * 0.5,
    )
}

fn correspondences(
    pts: &[(Vector3<f64>, Vector3<f64>)],
    mut moved: impl FnMut(usize, &Vector3<f64>) -> Vector3<f64>,
) -> Vec<Correspondence> {
    pts.iter()
        .enumerate()
        .map(|(k, (p, n))| Correspondence {
            moving: moved(k, p),
            reference: *p,
            normal: *n,
            weight: 1.0,
            normal_var: 0.0,
        })
        .collect()
}

#[test]
fn a_flat_plane_holds_x_y_and_yaw() {
    let pts = surface(20, |_, _| (0.0, 0.0, 0.0));
    let mut rng = SplitMix64::new(1);
    let corrs = correspondences(&pts, |_, p| {
        p + Vector3::new(0.3, -0.2, 0.2 + 0.01 * rng.normal())
    });
    let rule = DegeneracyRule::default();
    let step = point_to_plane_with(&corrs, Model::Rigid, &rule).unwrap();
    let centroid = corrs.iter().map(|c| c.moving).sum::<Vector3<f64>>() / 400.0;
    let t = parameters(&step.update, &centroid);
    assert!(t[0].abs() < 1e-9 && t[1].abs() < 1e-9, "x, y held: {t:?}");
    assert!((t[2] + 0.2).abs() < 0.01, "z fitted: {t:?}");
    assert!(
        step.update.rotation.scaled_axis().z.abs() < 1e-12,
        "yaw held"
    );
    let moved: Vec<Correspondence> = corrs
        .iter()
        .map(|c| Correspondence {
            moving: step.update.transform_point(&Point3::from(c.moving)).coords,
            ..*c
        })
        .collect();
    let info = fit_information(&moved, Model::Rigid, &rule).unwrap();
    assert_eq!(info.degenerate, vec![Axis::X, Axis::Y, Axis::Yaw]);
    for axis in [Axis::X, Axis::Y, Axis::Yaw] {
        assert_eq!(info.sigma_of(axis), None);
        assert!(info.info_6x6[(axis.index(), axis.index())].abs() < 1e-9);
    }
    for axis in [Axis::Z, Axis::Roll, Axis::Pitch] {
        let s = info.sigma_of(axis).unwrap();
        assert!(s > 0.0 && s.is_finite(), "{axis:?}: {s}");
    }
    // about 0.01 m / sqrt(400) in z
    let sz = info.sigma_of(Axis::Z).unwrap();
    assert!(sz > 0.0003 && sz < 0.001, "{sz}");
}

#[test]
fn a_ridge_holds_the_direction_along_it() {
    // z = 3 sin(x / 3): extruded along y, nothing fixes y.
    let pts = surface(30, |x, _| ((x / 3.0).sin() * 3.0, (x / 3.0).cos(), 0.0));
    let mut rng = SplitMix64::new(2);
    let corrs = correspondences(&pts, |_, p| p + Vector3::z() * 0.02 * rng.normal());
    let info = fit_information(&corrs, Model::Rigid, &DegeneracyRule::default()).unwrap();
    assert_eq!(info.degenerate, vec![Axis::Y]);
    assert!(info.sigma_of(Axis::X).is_some() && info.sigma_of(Axis::Yaw).is_some());
    let step = point_to_plane_with(
        &correspondences(&pts, |_, p| p + Vector3::new(0.1, 0.5, 0.0)),
        Model::Rigid,
        &DegeneracyRule::default(),
    )
    .unwrap();
    let t = step.update.translation.vector;
    assert!(t.y.abs() < 1e-9 && (t.x + 0.1).abs() < 0.02, "{t:?}");
}

#[test]
fn a_rough_surface_has_no_degenerate_direction() {
    let pts = surface(30, wavy);
    let mut rng = SplitMix64::new(3);
    let corrs = correspondences(&pts, |_, p| p + Vector3::z() * 0.05 * rng.normal());
    let info = fit_information(&corrs, Model::Rigid, &DegeneracyRule::default()).unwrap();
    assert!(info.degenerate.is_empty(), "{:?}", info.degenerate);
    assert!(info.sigma.iter().all(|s| s.is_some()));
    // the translation model estimates no rotation: no sigma, not degenerate
    let info = fit_information(&corrs, Model::Translation, &DegeneracyRule::default()).unwrap();
    assert!(info.degenerate.is_empty());
    assert_eq!(&info.sigma[3..], &[None, None, None]);
}

/// Parameters (x, y, z at the centroid in metres, roll, pitch, yaw in degrees)
/// of an update.
fn parameters(update: &Isometry3<f64>, centroid: &Vector3<f64>) -> [f64; 6] {
    let t = update.transform_point(&Point3::from(*centroid)).coords - centroid;
    let r = update.rotation.scaled_axis().map(f64::to_degrees);
    [t.x, t.y, t.z, r.x, r.y, r.z]
}

/// Over noise draws with spatially correlated residuals (a common offset per
/// 2 m x 2 m block plus independent noise), |error| / sigma <= 3 on >= 99 % of
/// draws for every axis; the independent sandwich ([`FitSigma`]) does not cover.
#[test]
fn sigmas_cover_the_truth_under_correlated_noise() {
    let pts = surface(32, wavy);
    let mut rng = SplitMix64::new(11);
    let draws = 400;
    let mut within = [[0usize; 3]; 6];
    let mut independent_within3 = [0usize; 6];
    for _ in 0..draws {
        let block: Vec<f64> = (0..256).map(|_| rng.normal() * 0.2).collect();
        let noise: Vec<f64> = pts
            .iter()
            .map(|(p, _)| {
                let (bx, by) = (((p.x + 16.0) / 2.0) as usize, ((p.y + 16.0) / 2.0) as usize);
                block[bx * 16 + by] + 0.05 * rng.normal()
            })
            .collect();
        let corrs = correspondences(&pts, |k, p| p + Vector3::z() * noise[k]);
        let rule = DegeneracyRule::default();
        let step = point_to_plane_with(&corrs, Model::Rigid, &rule).unwrap();
        let moved: Vec<Correspondence> = corrs
            .iter()
            .map(|c| Correspondence {
                moving: step.update.transform_point(&Point3::from(c.moving)).coords,
                ..*c
            })
            .collect();
        let info = fit_information(&moved, Model::Rigid, &rule).unwrap();
        assert!(info.degenerate.is_empty());
        let centroid = corrs.iter().map(|c| c.moving).sum::<Vector3<f64>>() / corrs.len() as f64;
        // truth: the update is the identity; the error is the estimate itself
        let error = parameters(&step.update, &centroid);
        let independent: FitSigma = step.sigma;
        for k in 0..6 {
            let z = error[k].abs() / info.sigma[k].unwrap();
            for (m, count) in within[k].iter_mut().enumerate() {
                *count += usize::from(z <= (m + 1) as f64);
            }
            let s = if k < 3 {
                independent.trans_m[k]
            } else {
                independent.rot_deg[k - 3]
            };
            independent_within3[k] += usize::from(error[k].abs() <= 3.0 * s);
        }
    }
    let fraction = |c: usize| c as f64 / draws as f64;
    for k in 0..6 {
        let f = within[k].map(fraction);
        eprintln!(
            "axis {k}: within 1/2/3 sigma {f:?}, independent sandwich within 3: {}",
            fraction(independent_within3[k])
        );
        assert!(f[2] >= 0.99, "axis {k}: {f:?}");
        // not grossly conservative either: fewer than all within 1 sigma
        assert!(f[0] < 0.95, "axis {k}: {f:?}");
    }
    assert!((0..6).any(|k| fraction(independent_within3[k]) < 0.9));
}

/// A rotation prior pulls only what the data do not see: on a narrow noisy
/// strip (weak yaw) the fitted yaw moves toward the start and its sigma stays
/// near the prior's; on the wavy surface (strong yaw) the step moves by the
/// prior's share of the information (about 1 %) and the sigmas are the data's; and with the estimate already rotated, the
/// prior's pull is toward the start, not toward the current rotation.
#[test]
fn a_rotation_prior_holds_only_what_the_data_do_not_see() {
    let prior_deg = 0.05_f64;
    let prior = |current: Vector3<f64>| RotationPrior {
        sigma_rad: prior_deg.to_radians(),
        current,
    };
    // A 40 x 4 m strip of gentle terrain with 0.3 m noise: yaw barely seen.
    let mut strip = Vec::new();
    for i in 0..80 {
        for j in 0..8 {
            let (x, y) = (i as f64 * 0.5 - 20.0, j as f64 * 0.5 - 2.0);
            let (z, dzdx, dzdy) = (0.02 * x + 0.05 * y, 0.02, 0.05);
            strip.push((
                Vector3::new(x, y, z),
                Vector3::new(-dzdx, -dzdy, 1.0).normalize(),
            ));
        }
    }
    let mut rng = SplitMix64::new(5);
    let corrs = correspondences(&strip, |_, p| {
        p + Vector3::new(0.0, 0.0, 0.3 * rng.normal())
    });
    let rule = DegeneracyRule::NUMERICAL;
    let free = point_to_plane_with(&corrs, Model::Rigid, &rule).unwrap();
    let held =
        point_to_plane_prior(&corrs, Model::Rigid, &rule, Some(&prior(Vector3::zeros()))).unwrap();
    let yaw = |u: &crate::fit::FitUpdate| u.update.rotation.scaled_axis().z.to_degrees().abs();
    assert!(
        yaw(&held) < yaw(&free) / 3.0,
        "held {} free {}",
        yaw(&held),
        yaw(&free)
    );
    assert!(
        held.sigma.rot_deg[2] <= prior_deg * 1.01,
        "{:?}",
        held.sigma
    );
    assert!(held.sigma.rot_deg[2] > prior_deg * 0.5, "{:?}", held.sigma);
    // Already turned by 0.2 deg from the start: the step turns back.
    let turned = point_to_plane_prior(
        &corrs,
        Model::Rigid,
        &rule,
        Some(&prior(Vector3::new(0.0, 0.0, 0.2_f64.to_radians()))),
    )
    .unwrap();
    assert!(turned.update.rotation.scaled_axis().z.to_degrees() < -0.1);
    // The wavy surface sees its yaw to a few thousandths of a degree: near its
    // solution the prior changes neither the step nor the sigmas by more than 1 %.
    let pts = surface(32, wavy);
    let turn = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.0005);
    let mut rng = SplitMix64::new(6);
    let corrs = correspondences(&pts, |_, p| {
        turn * p + Vector3::new(0.0, 0.0, 0.01 * rng.normal())
    });
    let free = point_to_plane_with(&corrs, Model::Rigid, &rule).unwrap();
    let with =
        point_to_plane_prior(&corrs, Model::Rigid, &rule, Some(&prior(Vector3::zeros()))).unwrap();
    let (a, b) = (
        free.update.rotation.scaled_axis().z,
        with.update.rotation.scaled_axis().z,
    );
    // The prior's share of the yaw information, with the data's worth their
    // sandwich (the small-sample factor doubles the variance of this 32 x 32
    // patch): about 2 %.
    let data = fit_information(&corrs, Model::Rigid, &rule).unwrap();
    let s = data.sigma_of(Axis::Yaw).unwrap().powi(2);
    let share = s / (s + prior_deg.powi(2));
    eprintln!("{a} {b} prior share {share}");
    assert!(share < 0.05, "{share}");
    assert!((a - b).abs() < 1.5 * share * a.abs(), "{a} {b}");
    for k in 0..3 {
        let (s, t) = (free.sigma.rot_deg[k], with.sigma.rot_deg[k]);
        assert!((s - t).abs() <= share * s, "axis {k}: {s} {t}");
    }
}

/// A surface that barely varies along x (true slopes 0.03) fitted with normals
/// carrying 0.05 of noise, as a ring plane over noisy 0.5 m pixels does, and
/// 0.3 m of height noise: the noisy normals pass for x information. With their
/// variance given (errors in variables) the x standard error is the one the
/// exact normals give; without, it is less than half.
#[test]
fn noisy_normals_are_not_information() {
    let truth = surface(40, |x, y| {
        (
            0.15 * (x / 5.0).sin() + 0.02 * y,
            0.03 * (x / 5.0).cos(),
            0.02,
        )
    });
    let mut rng = SplitMix64::new(7);
    let heights: Vec<f64> = truth.iter().map(|_| 0.3 * rng.normal()).collect();
    let var = 0.05f64.powi(2);
    let fitted = |noisy: bool, given: f64, rng: &mut SplitMix64| -> f64 {
        let corrs: Vec<Correspondence> = truth
            .iter()
            .zip(&heights)
            .map(|((p, n), dz)| {
                let mut normal = *n;
                if noisy {
                    normal +=
                        Vector3::new(var.sqrt() * rng.normal(), var.sqrt() * rng.normal(), 0.0);
                }
                Correspondence {
                    moving: p + Vector3::new(0.0, 0.0, *dz),
                    reference: *p,
                    normal: normal.normalize(),
                    weight: 1.0,
                    normal_var: given,
                }
            })
            .collect();
        let info = fit_information(&corrs, Model::Rigid, &DegeneracyRule::NUMERICAL).unwrap();
        info.sigma_of(Axis::X).unwrap()
    };
    let exact = fitted(false, 0.0, &mut rng);
    let naive = fitted(true, 0.0, &mut SplitMix64::new(8));
    let corrected = fitted(true, var, &mut SplitMix64::new(8));
    assert!(
        naive < exact / 2.0,
        "noise counted as information: {naive} vs {exact}"
    );
    assert!(
        corrected > exact / 1.5 && corrected < exact * 1.5,
        "corrected {corrected} vs exact normals {exact}"
    );
}

/// Wavy ground plus one short wall facing +x (one segment): the ground pins
/// x to millimetres, but the wall's matches, which carry most of the x
/// information when the ground is smooth, share one snapping error; with the
/// wall model x is known no better than the wall's placement allows.
#[test]
fn a_wall_shares_one_placement_error() {
    let mut rng = SplitMix64::new(11);
    let mut pts: Vec<(Vector3<f64>, Vector3<f64>)> =
        surface(30, |x, y| (0.01 * x + 0.02 * y, 0.01, 0.02))
            .into_iter()
            .chain(
                surface(30, wavy)
                    .into_iter()
                    .map(|(p, n)| (p + Vector3::new(0.0, 40.0, 0.0), n)),
            )
            .collect();
    for k in 0..60 {
        let (y, z) = ((k % 12) as f64 * 0.5 - 3.0, (k / 12) as f64 + 1.0);
        pts.push((Vector3::new(2.0, y, z), Vector3::new(1.0, 0.0, 0.0)));
    }
    let corrs = correspondences(&pts, |_, p| {
        p + Vector3::new(0.0, 0.0, 0.01 * (rng.next_f64() - 0.5))
    });
    let plain = fit_information(&corrs, Model::Rigid, &DegeneracyRule::NUMERICAL).unwrap();
    let rule = DegeneracyRule {
        walls: Some(WallSnap::of_pixel(0.5)),
        ..DegeneracyRule::NUMERICAL
    };
    let walled = fit_information(&corrs, Model::Rigid, &rule).unwrap();
    let (sx0, sx1) = (plain.sigma[0].unwrap(), walled.sigma[0].unwrap());
    assert!(sx0 < 0.01, "without the model {sx0}");
    assert!(
        sx1 > 5.0 * sx0 && sx1 < 0.5,
        "with the model {sx1} (plain {sx0})"
    );
    // no wall (the plane; the wavy patch reaches 45 degrees): nothing changes
    let ground: Vec<Correspondence> = corrs[..900].to_vec();
    let a = fit_information(&ground, Model::Rigid, &DegeneracyRule::NUMERICAL).unwrap();
    let b = fit_information(&ground, Model::Rigid, &rule).unwrap();
    assert_eq!(a.covariance_6x6, b.covariance_6x6);
}

/// Heights whose noise is shared by 4 x 4 m blocks (as a tree, a roof or a
/// matching window shares it): the data see yaw worse than their H says. The
/// prior is combined with what they are worth (their sandwich), so the
/// reported yaw error is the generalised-least-squares combination of the
/// data's and the prior's, below the prior's; weighed by H alone it was above.
#[test]
fn a_rotation_prior_is_weighed_against_what_correlated_data_are_worth() {
    let prior_deg = 0.05_f64;
    let pts = surface(40, |x, y| {
        (
            0.4 * (x / 2.0).sin() * (y / 3.0).cos(),
            0.2 * (x / 2.0).cos() * (y / 3.0).cos(),
            -0.4 / 3.0 * (x / 2.0).sin() * (y / 3.0).sin(),
        )
    });
    let mut rng = SplitMix64::new(21);
    let blocks: Vec<f64> = (0..100).map(|_| 0.015 * rng.normal()).collect();
    let block = |p: &Vector3<f64>| {
        let (i, j) = (((p.x + 20.0) / 4.0) as usize, ((p.y + 20.0) / 4.0) as usize);
        blocks[(i.min(9)) * 10 + j.min(9)]
    };
    let corrs = correspondences(&pts, |_, p| p + Vector3::new(0.0, 0.0, block(p)));
    let rule = DegeneracyRule {
        cluster_cell_m: Some(8.0),
        ..DegeneracyRule::NUMERICAL
    };
    let data = fit_information(&corrs, Model::Rigid, &rule).unwrap();
    let prior = RotationPrior {
        sigma_rad: prior_deg.to_radians(),
        current: Vector3::zeros(),
    };
    let both = fit_information_with(&corrs, Model::Rigid, &rule, Some(&prior)).unwrap();
    let yaw = |i: &FitInformation| i.sigma_of(Axis::Yaw).unwrap();
    let gls = 1.0 / (yaw(&data).powi(-2) + prior_deg.powi(-2)).sqrt();
    eprintln!("data {} with prior {} gls {gls}", yaw(&data), yaw(&both));
    assert!(yaw(&data) > prior_deg / 3.0, "the prior matters here");
    assert!(yaw(&both) < prior_deg, "{} vs {prior_deg}", yaw(&both));
    assert!(
        (yaw(&both) / gls - 1.0).abs() < 0.1,
        "{} vs {gls}",
        yaw(&both)
    );
}
