//! How far each journaled pair is from the truth, axis by axis, and whether the
//! standard errors the pair reported cover it: the calibration of the sigmas
//! (issue 11: |error| / sigma <= 3 for 99 % of pairs on every axis).
//!
//! The error of a pair (reference i, moving j) is the left perturbation D with
//! M_est = D M_true, M_true = T_i^-1 T_j from truth.json, written like the
//! pair's information: the translation D(c) - c at the fit's centroid c and
//! the rotation vector of D (roll, pitch, yaw about the CRS axes). Axes the
//! fit held (zero variance) have no sigma and are counted apart.

use nalgebra::{Matrix4, Point3, Rotation3, Vector3};
use serde::Serialize;

use super::output::Truth;
use crate::fit::information::standard_error;
use crate::geo::rigid::from_rows;
use crate::icp::IcpStatus;
use crate::journal::EdgeRecord;

/// Axis names in the information's order.
pub const AXES: [&str; 6] = ["x", "y", "z", "roll", "pitch", "yaw"];

/// One journaled pair against the truth.
#[derive(Clone, Debug, Serialize)]
pub struct EdgeError {
    pub reference: String,
    pub moving: String,
    pub status: Option<IcpStatus>,
    /// The pair's overlap score s_ij, final RMSE (m) and ICP iterations.
    pub overlap: f64,
    pub rmse_m: f64,
    pub iterations: usize,
    /// Error per axis: metres for x, y, z at the centroid, degrees for roll, pitch, yaw.
    pub error: [f64; 6],
    /// Reported one-sigma per axis (same units); None where the fit held the axis
    /// or reported no covariance.
    pub sigma: [Option<f64>; 6],
    /// The shift error's Mahalanobis distance in the reported shift covariance
    /// (x, y, z jointly); None where the fit held a shift axis or reported none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shift_mahalanobis: Option<f64>,
}

impl EdgeError {
    /// |error| / sigma per axis (None where there is no sigma).
    pub fn ratios(&self) -> [Option<f64>; 6] {
        std::array::from_fn(|k| self.sigma[k].map(|s| self.error[k].abs() / s.max(1e-12)))
    }

    /// Displacement at the centroid, metres.
    pub fn shift_error_m(&self) -> f64 {
        self.error[..3].iter().map(|e| e * e).sum::<f64>().sqrt()
    }
}

/// Variance below which an axis counts as held (nothing measured).
const HELD_VARIANCE: f64 = 1e-18;

impl Truth {
    /// The error of one journaled pair; None when the record has no transform or
    /// names a tile the truth does not have.
    pub fn edge_error(&self, record: &EdgeRecord) -> Option<EdgeError> {
        let rows = record.m_world.as_ref()?;
        let tile = |id: &str| self.tiles.iter().find(|t| t.id == id);
        let (ti, tj) = (tile(&record.reference)?, tile(&record.moving)?);
        let m_true: Matrix4<f64> = from_rows::<Matrix4<f64>>(&ti.matrix_world).try_inverse()?
            * from_rows::<Matrix4<f64>>(&tj.matrix_world);
        let d: Matrix4<f64> = from_rows::<Matrix4<f64>>(rows) * m_true.try_inverse()?;
        let centroid = match &record.information {
            Some(info) => Point3::from(info.centroid_world),
            None => self.centre_of(&record.moving),
        };
        let moved = d.transform_point(&centroid);
        let rotation = Rotation3::from_matrix(&d.fixed_view::<3, 3>(0, 0).into_owned());
        let rv = rotation.scaled_axis();
        let error = [
            moved.x - centroid.x,
            moved.y - centroid.y,
            moved.z - centroid.z,
            rv.x.to_degrees(),
            rv.y.to_degrees(),
            rv.z.to_degrees(),
        ];
        // as reported (with the gridding floor), None where the fit held the axis
        let reported = record
            .information
            .as_ref()
            .map(|info| info.reported_covariance_6x6());
        let sigma = std::array::from_fn(|k| {
            let info = record.information.as_ref()?;
            // a held axis may keep a trace of variance where the measured
            // directions mix it with another (x with pitch on a strip): the
            // fit's list says what it held, as `pair` reports it (no sigma)
            if info.covariance[k][k] <= HELD_VARIANCE
                || info.degenerate.iter().any(|a| a.index() == k)
            {
                return None;
            }
            Some(standard_error(&reported?, k))
        });
        let shift_mahalanobis = match (&reported, sigma[..3].iter().all(Option::is_some)) {
            (Some(c), true) => {
                let e = Vector3::new(error[0], error[1], error[2]);
                let block = c.fixed_view::<3, 3>(0, 0).into_owned();
                block
                    .cholesky()
                    .map(|l| e.dot(&l.solve(&e)).max(0.0).sqrt())
            }
            _ => None,
        };
        Some(EdgeError {
            shift_mahalanobis,
            reference: record.reference.clone(),
            moving: record.moving.clone(),
            status: record.status,
            overlap: record.overlap,
            rmse_m: record.rmse_m,
            iterations: record.iterations,
            error,
            sigma,
        })
    }

    /// A tile's centre at the pivot height (world metres), or the origin.
    fn centre_of(&self, id: &str) -> Point3<f64> {
        self.tiles
            .iter()
            .find(|t| t.id == id)
            .map(|t| {
                let g = t.geotransform;
                Point3::new(
                    g[0] + g[1] * t.width as f64 / 2.0,
                    g[3] + g[5] * t.height as f64 / 2.0,
                    self.pivot_z_m.unwrap_or(200.0),
                )
            })
            .unwrap_or_else(Point3::origin)
    }
}

/// Per axis: how many edges had a sigma, and the fractions within 1, 2, 3 sigma.
#[derive(Clone, Debug, Serialize)]
pub struct AxisCalibration {
    pub axis: &'static str,
    pub with_sigma: usize,
    pub held: usize,
    pub within: [f64; 3],
    pub worst_ratio: f64,
}

/// The calibration table over `edges`.
pub fn calibration(edges: &[EdgeError]) -> Vec<AxisCalibration> {
    (0..6)
        .map(|k| {
            let ratios: Vec<f64> = edges.iter().filter_map(|e| e.ratios()[k]).collect();
            let n = ratios.len();
            let frac = |m: f64| ratios.iter().filter(|&&r| r <= m).count() as f64 / n.max(1) as f64;
            AxisCalibration {
                axis: AXES[k],
                with_sigma: n,
                held: edges.len() - n,
                within: [frac(1.0), frac(2.0), frac(3.0)],
                worst_ratio: ratios.iter().cloned().fold(0.0, f64::max),
            }
        })
        .collect()
}

/// The shift errors' Mahalanobis distances against the chi-square quantiles
/// of 3 degrees of freedom at 1, 2 and 3 sigma's coverage (68.27, 95.45,
/// 99.73 %): where per-axis counts pass an error across a narrow covariance,
/// this does not.
#[derive(Clone, Debug, Serialize)]
pub struct ShiftCalibration {
    pub with_covariance: usize,
    pub within: [f64; 3],
    pub worst: f64,
}

/// Square roots of the chi-square(3) quantiles at 68.27, 95.45 and 99.73 %.
pub const CHI3_SIGMAS: [f64; 3] = [1.878, 2.833, 3.763];

pub fn shift_calibration(edges: &[EdgeError]) -> ShiftCalibration {
    let d: Vec<f64> = edges.iter().filter_map(|e| e.shift_mahalanobis).collect();
    let frac = |q: f64| d.iter().filter(|&&x| x <= q).count() as f64 / d.len().max(1) as f64;
    ShiftCalibration {
        with_covariance: d.len(),
        within: CHI3_SIGMAS.map(frac),
        worst: d.iter().cloned().fold(0.0, f64::max),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::PairInformation;
    use crate::synth::output::TruthTile;

    fn tile(id: &str, m: Matrix4<f64>) -> TruthTile {
        TruthTile {
            id: id.into(),
            file: format!("{id}.tif"),
            width: 100,
            height: 100,
            geotransform: [1000.0, 1.0, 0.0, 2000.0, 0.0, -1.0],
            matrix_world: rows(&m),
            shift_m: [0.0; 3],
            rot_deg: [0.0; 3],
        }
    }

    fn rows(m: &Matrix4<f64>) -> [[f64; 4]; 4] {
        std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
    }

    #[test]
    fn the_error_is_the_perturbation_at_the_centroid_and_sigmas_divide_it() {
        let t_j = Matrix4::new_translation(&nalgebra::Vector3::new(1.0, 2.0, 3.0));
        let mut truth: Truth = serde_json::from_str(
            r#"{"crs": "EPSG:32617", "gsd": 1.0, "layout": "chain", "seed": 1, "tiles": []}"#,
        )
        .unwrap();
        truth.tiles = vec![tile("a", Matrix4::identity()), tile("b", t_j)];
        // estimate off by 0.3 m in x and 0.01 rad of yaw about the centroid
        let c = nalgebra::Vector3::new(1050.0, 1950.0, 200.0);
        let yaw = Rotation3::from_euler_angles(0.0, 0.0, 0.01).to_homogeneous();
        let about_c = Matrix4::new_translation(&c) * yaw * Matrix4::new_translation(&-c);
        let d = Matrix4::new_translation(&nalgebra::Vector3::new(0.3, 0.0, 0.0)) * about_c;
        let mut covariance = [[0.0; 6]; 6];
        for (k, v) in [0.01, 0.01, 0.0, 1e-6, 1e-6, 1e-4].into_iter().enumerate() {
            covariance[k][k] = v;
        }
        let record = EdgeRecord {
            reference: "a".into(),
            moving: "b".into(),
            overlap: 0.5,
            status: Some(IcpStatus::Converged),
            m_world: Some(rows(&(d * t_j))),
            rmse_m: 0.1,
            inliers: 10,
            iterations: 3,
            sigma: None,
            information: Some(PairInformation {
                covariance,
                centroid_world: [c.x, c.y, c.z],
                degenerate: vec![],
                gridding: None,
            }),
            search: None,
            note: None,
        };
        let e = truth.edge_error(&record).unwrap();
        assert!(
            (e.error[0] - 0.3).abs() < 1e-9 && e.error[1].abs() < 1e-9,
            "{e:?}"
        );
        assert!((e.error[5] - 0.01f64.to_degrees()).abs() < 1e-9, "{e:?}");
        assert_eq!(e.sigma[2], None, "zero variance is a held axis");
        let r = e.ratios();
        assert!((r[0].unwrap() - 3.0).abs() < 1e-9 && (r[5].unwrap() - 1.0).abs() < 1e-6);
        let table = calibration(&[e]);
        assert_eq!((table[2].with_sigma, table[2].held), (0, 1));
        assert_eq!(table[0].within, [0.0, 0.0, 1.0]);
        // x held by the fit, with the trace of variance a mixed direction leaves
        let mut held = record.clone();
        let info = held.information.as_mut().unwrap();
        info.covariance[0][0] = 1e-10;
        info.degenerate = vec![crate::fit::Axis::X];
        let e = truth.edge_error(&held).unwrap();
        assert_eq!(e.sigma[0], None, "{e:?}");
        assert!(e.sigma[1].is_some());
        assert_eq!(e.shift_mahalanobis, None, "a held shift axis");
        // a narrow ellipse along x = y (4.5 cm across, 10 m along): the 0.3 m
        // error in x is within 3 sigma on each axis and 4.7 sigma across it
        let mut narrow = record.clone();
        let info = narrow.information.as_mut().unwrap();
        let (along, across) = (50.0, 0.001);
        info.covariance[0][0] = along + across;
        info.covariance[1][1] = along + across;
        info.covariance[0][1] = along - across;
        info.covariance[1][0] = along - across;
        info.covariance[2][2] = 0.01;
        let e = truth.edge_error(&narrow).unwrap();
        assert!(e.ratios()[0].unwrap() < 3.0, "{e:?}");
        let d = e.shift_mahalanobis.unwrap();
        assert!((d - 0.3 / (2.0 * across.sqrt())).abs() < 0.01, "{d}");
        let joint = shift_calibration(&[e]);
        assert_eq!((joint.with_covariance, joint.within), (1, [0.0, 0.0, 0.0]));
    }
}
