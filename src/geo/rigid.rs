//! Rigid transforms: the ICP's `Isometry3<f64>` and the 4x4 matrices of poses
//! (`matrix_world` and relative poses). Parts, application to points, inversion,
//! rotation angles, projection onto SO(3), the change between world coordinates
//! (UTM, ~10^6 m) and a local frame shifted by a common origin, and the one
//! row-major `[[f64; 4]; 4]` form every file uses ([`Rows`], serde adapter [`rows`]).
//!
//! Convention (DESIGN.md): a pose M maps a point of its DSM to the corrected frame,
//! p_corrected = M p; the relative pose of an edge is M_ij = M_i^-1 M_j.

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3};

/// The rotation block R of a rigid transform.
pub fn rotation(m: &Matrix4<f64>) -> Matrix3<f64> {
    m.fixed_view::<3, 3>(0, 0).into_owned()
}

/// The translation column t of a rigid transform.
pub fn translation(m: &Matrix4<f64>) -> Vector3<f64> {
    m.fixed_view::<3, 1>(0, 3).into_owned()
}

/// The rigid transform [R t; 0 0 0 1].
pub fn from_parts(r: &Matrix3<f64>, t: &Vector3<f64>) -> Matrix4<f64> {
    let mut m = Matrix4::identity();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    m.fixed_view_mut::<3, 1>(0, 3).copy_from(t);
    m
}

/// Applies a rigid transform to a point: R p + t.
pub fn apply(m: &Matrix4<f64>, p: &Vector3<f64>) -> Vector3<f64> {
    rotation(m) * p + translation(m)
}

/// Inverse of a rigid transform: [R^T, -R^T t].
pub fn inverse_rigid(m: &Matrix4<f64>) -> Matrix4<f64> {
    let rt = rotation(m).transpose();
    from_parts(&rt, &(-(rt * translation(m))))
}

/// Rotation angle of a rotation matrix in degrees, accurate for tiny angles
/// (atan2 of the skew part against the trace, not acos of the trace).
pub fn rotation_angle_deg(r: &Matrix3<f64>) -> f64 {
    let sin_part = Vector3::new(
        r[(2, 1)] - r[(1, 2)],
        r[(0, 2)] - r[(2, 0)],
        r[(1, 0)] - r[(0, 1)],
    )
    .norm()
        * 0.5;
    let cos_part = (r.trace() - 1.0) * 0.5;
    sin_part.atan2(cos_part).to_degrees()
}

/// The rotation angle (degrees) of the rigid transform `a^-1 b`, i.e. between two poses.
pub fn rotation_between_deg(a: &Matrix3<f64>, b: &Matrix3<f64>) -> f64 {
    rotation_angle_deg(&(a.transpose() * b))
}

/// The nearest rotation (Frobenius norm) to a 3x3 matrix: U diag(1, 1, det(U V^T)) V^T.
/// A degenerate (rank < 2) input yields some rotation; callers check their inputs.
pub fn project_to_so3(m: &Matrix3<f64>) -> Matrix3<f64> {
    let svd = m.svd(true, true);
    let (u, v_t) = (svd.u.expect("svd u"), svd.v_t.expect("svd v_t"));
    let mut r = u * v_t;
    if r.determinant() < 0.0 {
        // Flip the axis of the smallest singular value (nalgebra sorts them descending).
        let min_axis = (0..3)
            .min_by(|&a, &b| svd.singular_values[a].total_cmp(&svd.singular_values[b]))
            .unwrap_or(2);
        let mut d = Matrix3::identity();
        d[(min_axis, min_axis)] = -1.0;
        r = u * d * v_t;
    }
    r
}

/// The rotation exp([axis * angle]x) (Rodrigues), angle in radians.
pub fn rotation_from_axis_angle(axis_angle_rad: &Vector3<f64>) -> Matrix3<f64> {
    nalgebra::Rotation3::new(*axis_angle_rad).into_inner()
}

/// How far the rotation block of `m` is from a rotation: the largest entry of
/// |R^T R - I| and det(R).
pub fn rigidity(m: &Matrix4<f64>) -> Rigidity {
    let r = rotation(m);
    let orthonormality_error = (r.transpose() * r - Matrix3::identity()).abs().max();
    Rigidity {
        orthonormality_error,
        det: r.determinant(),
    }
}

/// See [`rigidity`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rigidity {
    pub orthonormality_error: f64,
    pub det: f64,
}

impl Rigidity {
    /// A proper rotation within `tolerance` (orthonormal, det > 0).
    pub fn is_rigid(&self, tolerance: f64) -> bool {
        self.orthonormality_error < tolerance && self.det > 0.0
    }
}

/// World pose -> local pose for a frame shifted by `origin_world` (p_local = p_world - o):
/// M_local = T(-o) M_world T(o), so R is unchanged and t_local = t + (R - I) o.
/// Relative poses M_ij transform the same way (conjugation commutes with products).
pub fn to_local(m_world: &Matrix4<f64>, origin_world: &Vector3<f64>) -> Matrix4<f64> {
    let r = rotation(m_world);
    let t_local = translation(m_world) + (r - Matrix3::identity()) * origin_world;
    from_parts(&r, &t_local)
}

/// Local pose -> world pose: the inverse of [`to_local`], M_world = T(o) M_local T(-o).
pub fn to_world(m_local: &Matrix4<f64>, origin_world: &Vector3<f64>) -> Matrix4<f64> {
    let r = rotation(m_local);
    let t_world = translation(m_local) - (r - Matrix3::identity()) * origin_world;
    from_parts(&r, &t_world)
}

/// Local isometry -> world isometry for a frame shifted by `origin_world`:
/// T(o) t_local T(-o), the [`to_world`] of the ICP's own type (R unchanged,
/// t_world = t + o - R o). The translation is taken from the product of the
/// homogeneous matrices, so it is bit-identical to the 4x4 form of the same
/// product (the rotation keeps its quaternion).
pub fn isometry_to_world(t_local: &Isometry3<f64>, origin_world: &Vector3<f64>) -> Isometry3<f64> {
    let m_world = Translation3::from(*origin_world).to_homogeneous()
        * t_local.to_homogeneous()
        * Translation3::from(-origin_world).to_homogeneous();
    Isometry3::from_parts(Translation3::from(translation(&m_world)), t_local.rotation)
}

/// A rigid transform written as a row-major 4x4 `[[f64; 4]; 4]` (poses.json,
/// the journal, truth.json, `pair --json`): `rows[r][c]` is entry (r, c).
pub trait Rows: Sized {
    fn to_row_major(&self) -> [[f64; 4]; 4];
    /// The transform of `rows`; the caller validates rigidity where it matters.
    fn from_row_major(rows: &[[f64; 4]; 4]) -> Self;
}

impl Rows for Matrix4<f64> {
    fn to_row_major(&self) -> [[f64; 4]; 4] {
        let mut rows = [[0.0; 4]; 4];
        for (r, row) in rows.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = self[(r, c)];
            }
        }
        rows
    }

    fn from_row_major(rows: &[[f64; 4]; 4]) -> Self {
        Matrix4::from_fn(|r, c| rows[r][c])
    }
}

impl Rows for Isometry3<f64> {
    fn to_row_major(&self) -> [[f64; 4]; 4] {
        self.to_homogeneous().to_row_major()
    }

    /// Reads R and t; R is taken as a rotation without re-projection.
    fn from_row_major(rows: &[[f64; 4]; 4]) -> Self {
        let m = Matrix4::from_row_major(rows);
        let r = Rotation3::from_matrix_unchecked(rotation(&m));
        Isometry3::from_parts(
            Translation3::from(translation(&m)),
            UnitQuaternion::from_rotation_matrix(&r),
        )
    }
}

/// Row-major 4x4 of a transform (see [`Rows`]).
pub fn to_rows<T: Rows>(t: &T) -> [[f64; 4]; 4] {
    t.to_row_major()
}

/// The transform of a row-major 4x4 (see [`Rows`]).
pub fn from_rows<T: Rows>(rows: &[[f64; 4]; 4]) -> T {
    T::from_row_major(rows)
}

/// The serde adapter for a transform field kept as rows on disk:
/// `#[serde(with = "crate::geo::rigid::rows")]`.
pub mod rows {
    use super::Rows;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    pub fn serialize<T: Rows, S: Serializer>(t: &T, s: S) -> Result<S::Ok, S::Error> {
        t.to_row_major().serialize(s)
    }

    pub fn deserialize<'de, T: Rows, D: Deserializer<'de>>(d: D) -> Result<T, D::Error> {
        let rows = <[[f64; 4]; 4]>::deserialize(d)?;
        Ok(T::from_row_major(&rows))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_pose() -> Matrix4<f64> {
        let r = rotation_from_axis_angle(&Vector3::new(1e-4, -3e-4, 2e-4));
        from_parts(&r, &Vector3::new(1.5, -0.7, 0.3))
    }

    #[test]
    fn inverse_and_apply_agree() {
        let m = sample_pose();
        let p = Vector3::new(10.0, 20.0, 30.0);
        let q = apply(&m, &p);
        let back = apply(&inverse_rigid(&m), &q);
        assert!((back - p).norm() < 1e-12);
        assert!((m * inverse_rigid(&m) - Matrix4::identity()).abs().max() < 1e-15);
    }

    #[test]
    fn tiny_angles_are_accurate() {
        for angle_deg in [1e-7f64, 1e-4, 0.01, 1.0, 90.0, 179.0] {
            let r = rotation_from_axis_angle(
                &(Vector3::new(0.3, -0.5, 0.8).normalize() * angle_deg.to_radians()),
            );
            let got = rotation_angle_deg(&r);
            assert!(
                (got - angle_deg).abs() < 1e-9 * angle_deg.max(1.0),
                "{angle_deg} -> {got}"
            );
        }
    }

    #[test]
    fn projection_recovers_a_perturbed_rotation_and_guards_the_determinant() {
        let r = rotation(&sample_pose());
        let noisy = r + Matrix3::new(1e-6, 0.0, 2e-6, 0.0, -1e-6, 0.0, 3e-7, 0.0, 0.0);
        let p = project_to_so3(&noisy);
        assert!((p.determinant() - 1.0).abs() < 1e-12);
        assert!((p - r).abs().max() < 1e-5);
        let reflection = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let p = project_to_so3(&reflection);
        assert!((p.determinant() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn local_frame_round_trip_and_meaning() {
        let m_world = sample_pose();
        let origin = Vector3::new(500_000.0, 4_000_000.0, 100.0);
        let m_local = to_local(&m_world, &origin);
        let p_world = Vector3::new(500_123.0, 4_000_456.0, 120.0);
        let via_local = apply(&m_local, &(p_world - origin)) + origin;
        assert!((via_local - apply(&m_world, &p_world)).norm() < 1e-8);
        let back = to_world(&m_local, &origin);
        assert!((back - m_world).abs().max() < 1e-9);
    }

    #[test]
    fn isometry_to_world_matches_the_matrix_form() {
        let t_local = Isometry3::from_parts(
            Translation3::new(1.5, -0.7, 0.3),
            UnitQuaternion::from_scaled_axis(Vector3::new(1e-4, -3e-4, 2e-4)),
        );
        let origin = Vector3::new(500_000.0, 4_000_000.0, 100.0);
        let via_matrix = to_world(&t_local.to_homogeneous(), &origin);
        let via_iso = isometry_to_world(&t_local, &origin).to_homogeneous();
        assert!((via_matrix - via_iso).abs().max() < 1e-8);
        let conj = Translation3::from(origin).to_homogeneous()
            * t_local.to_homogeneous()
            * Translation3::from(-origin).to_homogeneous();
        assert!((conj - via_iso).abs().max() < 1e-8);
    }

    #[test]
    fn rows_are_row_major_and_round_trip_through_serde() {
        let m = sample_pose();
        let rows = to_rows(&m);
        assert_eq!(rows[0][3], 1.5);
        assert_eq!(rows[3], [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(from_rows::<Matrix4<f64>>(&rows), m);
        let iso: Isometry3<f64> = from_rows(&rows);
        assert!((iso.to_homogeneous() - m).abs().max() < 1e-15);

        #[derive(serde::Serialize, serde::Deserialize)]
        struct Doc {
            #[serde(with = "rows")]
            t_ref_moving: Isometry3<f64>,
            #[serde(with = "rows")]
            matrix_world: Matrix4<f64>,
        }
        let doc = Doc {
            t_ref_moving: iso,
            matrix_world: m,
        };
        let text = serde_json::to_string(&doc).unwrap();
        assert!(text.starts_with("{\"t_ref_moving\":[["), "{text}");
        let back: Doc = serde_json::from_str(&text).unwrap();
        assert_eq!(back.matrix_world, m);
        assert!((back.t_ref_moving.to_homogeneous() - m).abs().max() < 1e-15);
    }

    #[test]
    fn rigidity_flags_scaled_matrices() {
        assert!(rigidity(&sample_pose()).is_rigid(1e-6));
        let mut m = sample_pose();
        m.fixed_view_mut::<3, 3>(0, 0).scale_mut(0.976);
        let r = rigidity(&m);
        assert!(!r.is_rigid(1e-6));
        assert!((r.det - 0.976f64.powi(3)).abs() < 1e-3);
    }
}
