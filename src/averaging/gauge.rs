//! The gauge: averaging fixes poses only up to one rigid motion A per connected
//! component (M_i -> A M_i leaves every M_i^-1 M_j unchanged). Anchor: A = M_k^-1 so
//! node k becomes the identity. Mean: A_R = proj_SO(3)(sum_i R_i)^T, so that the
//! projected mean of the corrected rotations is the identity, and the translations
//! then sum to zero.

use crate::poses::rigid::{from_parts, inverse_rigid, project_to_so3, rotation, translation};
use nalgebra::{Matrix3, Matrix4, Vector3};

/// Applies the gauge to the poses of one component (`members`); `anchor` must be a member.
pub fn fix_gauge(poses: &mut [Matrix4<f64>], members: &[usize], anchor: Option<usize>) {
    if members.is_empty() {
        return;
    }
    if let Some(k) = anchor {
        let a = inverse_rigid(&poses[k]);
        for &i in members {
            poses[i] = a * poses[i];
        }
        poses[k] = Matrix4::identity();
        return;
    }
    let rotation_sum: Matrix3<f64> = members.iter().map(|&i| rotation(&poses[i])).sum();
    let a_r = project_to_so3(&rotation_sum).transpose();
    let rotated: Vec<(Matrix3<f64>, Vector3<f64>)> = members
        .iter()
        .map(|&i| (a_r * rotation(&poses[i]), a_r * translation(&poses[i])))
        .collect();
    let mean_t = rotated.iter().map(|(_, t)| t).sum::<Vector3<f64>>() / members.len() as f64;
    for (&i, (r, t)) in members.iter().zip(&rotated) {
        poses[i] = from_parts(r, &(t - mean_t));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poses::rigid::rotation_from_axis_angle;

    fn poses() -> Vec<Matrix4<f64>> {
        (0..5)
            .map(|k| {
                let k = k as f64;
                let r = rotation_from_axis_angle(&Vector3::new(0.01 * k, -0.02, 0.005 * k * k));
                from_parts(&r, &Vector3::new(k, -2.0 * k, 3.0))
            })
            .collect()
    }

    #[test]
    fn mean_gauge_centres_rotations_and_translations() {
        let mut p = poses();
        let before: Vec<_> = (1..5).map(|k| inverse_rigid(&p[0]) * p[k]).collect();
        fix_gauge(&mut p, &[0, 1, 2, 3, 4], None);
        let sum: Matrix3<f64> = p.iter().map(rotation).sum();
        assert!((project_to_so3(&sum) - Matrix3::identity()).abs().max() < 1e-14);
        assert!(p.iter().map(translation).sum::<Vector3<f64>>().norm() < 1e-13);
        for k in 1..5 {
            assert!((inverse_rigid(&p[0]) * p[k] - before[k - 1]).abs().max() < 1e-13);
        }
    }

    #[test]
    fn anchor_gauge_touches_only_its_component() {
        let mut p = poses();
        let untouched = p[4];
        fix_gauge(&mut p, &[0, 1, 3], Some(3));
        assert_eq!(p[3], Matrix4::identity());
        assert_eq!(p[4], untouched);
        assert!((p[1] - inverse_rigid(&poses()[3]) * poses()[1]).abs().max() < 1e-14);
    }
}
