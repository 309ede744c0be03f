//! How far a set of poses is from truth.json, up to the common gauge (a rigid
//! motion applied to every pose changes no relative pose, so no estimate can be
//! judged without removing it first): pairwise, from the relative poses
//! M_i^-1 M_j, and per DSM, after the best rigid alignment of the estimated
//! corrections onto the true ones.

use nalgebra::{Matrix4, Vector3, Vector4};

use super::output::{Truth, TruthTile};
use crate::fit::{point_to_point, Correspondence, Model};
use crate::geo::rigid::{from_rows, rotation, rotation_angle_deg};
use crate::geo::GeoTransform;
use crate::poses::PosesFile;

/// Over every pair of tiles, the disagreement of M_i^-1 M_j with the truth's,
/// measured as the displacement of the second tile's centre (at the pivot
/// height, `pivot_z_m`, else 200 m) and as an angle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PairwiseError {
    pub mean_m: f64,
    pub worst_m: f64,
    pub worst_deg: f64,
}

/// Per DSM: the gauge G is the rigid motion that best maps the true corrected
/// tile corners (T_i c) onto the estimated ones (E_i c), least squares over
/// every corner of every tile; each DSM's error is then T_i^-1 G^-1 E_i, as the
/// displacement of its centre (at the pivot height) and an angle.
#[derive(Clone, Debug, PartialEq)]
pub struct PerDsmError {
    /// (id, displacement m, angle deg), in truth.json order.
    pub tiles: Vec<(String, f64, f64)>,
    pub worst_m: f64,
    pub worst_deg: f64,
}

fn matrix(rows: &[[f64; 4]; 4]) -> Matrix4<f64> {
    from_rows(rows)
}

fn inverse(m: &Matrix4<f64>) -> Matrix4<f64> {
    m.try_inverse().unwrap_or_else(Matrix4::identity)
}

fn angle_deg(m: &Matrix4<f64>) -> f64 {
    rotation_angle_deg(&rotation(m))
}

/// A posed tile of [`Truth::posed`].
struct Posed<'a> {
    left: Matrix4<f64>,
    truth_inv: Matrix4<f64>,
    est: Matrix4<f64>,
    tile: &'a TruthTile,
}

/// Sums of pairwise errors.
#[derive(Default)]
struct Tally {
    sum: f64,
    n: usize,
    worst_m: f64,
    worst_deg: f64,
}

impl Tally {
    fn add(&mut self, disp: f64, d: &Matrix4<f64>) {
        self.sum += disp;
        self.n += 1;
        self.worst_m = self.worst_m.max(disp);
        self.worst_deg = self.worst_deg.max(angle_deg(d));
    }
}

impl From<Tally> for PairwiseError {
    fn from(t: Tally) -> Self {
        PairwiseError {
            mean_m: t.sum / t.n.max(1) as f64,
            worst_m: t.worst_m,
            worst_deg: t.worst_deg,
        }
    }
}

impl Truth {
    fn pivot_z(&self) -> f64 {
        self.pivot_z_m.unwrap_or(200.0)
    }

    /// Tile centre at the pivot height, homogeneous.
    fn centre(&self, t: &TruthTile) -> Vector4<f64> {
        let g = t.geotransform;
        Vector4::new(
            g[0] + g[1] * t.width as f64 / 2.0,
            g[3] + g[5] * t.height as f64 / 2.0,
            self.pivot_z(),
            1.0,
        )
    }

    /// Each posed tile once, in truth.json order, as (T_a E_a^-1, T_a^-1, E_a,
    /// tile): the relative error of a pair is then d = truth_ab^-1 E_a^-1 E_b
    /// = T_b^-1 (T_a E_a^-1) E_b (a lookup per pair made 10^4 tiles take over
    /// 10 min).
    fn posed<'a>(&'a self, poses: &PosesFile) -> Vec<Posed<'a>> {
        let index: std::collections::HashMap<&str, &Matrix4<f64>> = poses
            .poses
            .iter()
            .map(|p| (p.id.as_str(), &p.matrix_world))
            .collect();
        self.tiles
            .iter()
            .filter_map(|t| {
                let e = *index.get(t.id.as_str())?;
                let m = matrix(&t.matrix_world);
                Some(Posed {
                    left: m * inverse(e),
                    truth_inv: inverse(&m),
                    est: *e,
                    tile: t,
                })
            })
            .collect()
    }

    /// See [`PairwiseError`]; tiles without a pose are skipped.
    pub fn pairwise_error(&self, poses: &PosesFile) -> PairwiseError {
        let posed = self.posed(poses);
        let centres: Vec<_> = posed.iter().map(|p| self.centre(p.tile)).collect();
        let mut tally = Tally::default();
        for (k, a) in posed.iter().enumerate() {
            for (b, centre) in posed[k + 1..].iter().zip(&centres[k + 1..]) {
                let d = b.truth_inv * a.left * b.est;
                tally.add((d * centre - centre).xyz().norm(), &d);
            }
        }
        tally.into()
    }

    /// Like [`Truth::pairwise_error`], over the pairs of tiles whose rasters
    /// overlap only, each measured at the worst corner of the overlap
    /// rectangle (at the pivot height): how far apart two corrected DSMs are
    /// where they meet, the seams of a mosaic. All pairs also count DSMs
    /// kilometres apart, where one DSM's rotation error, extrapolated over the
    /// distance, dominates.
    pub fn overlap_error(&self, poses: &PosesFile) -> PairwiseError {
        let posed = self.posed(poses);
        let bounds: Vec<[f64; 4]> = posed
            .iter()
            .map(|p| GeoTransform(p.tile.geotransform).bounds(p.tile.width, p.tile.height))
            .collect();
        let z = self.pivot_z();
        let mut tally = Tally::default();
        for (k, (a, ba)) in posed.iter().zip(&bounds).enumerate() {
            for (b, bb) in posed[k + 1..].iter().zip(&bounds[k + 1..]) {
                let (x0, y0) = (ba[0].max(bb[0]), ba[1].max(bb[1]));
                let (x1, y1) = (ba[2].min(bb[2]), ba[3].min(bb[3]));
                if x0 >= x1 || y0 >= y1 {
                    continue;
                }
                let d = b.truth_inv * a.left * b.est;
                let disp = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
                    .iter()
                    .map(|&(x, y)| {
                        let c = Vector4::new(x, y, z, 1.0);
                        (d * c - c).xyz().norm()
                    })
                    .fold(0.0f64, f64::max);
                tally.add(disp, &d);
            }
        }
        tally.into()
    }

    /// See [`PerDsmError`]; tiles without a pose are skipped. None with fewer
    /// than one posed tile.
    pub fn per_dsm_error(&self, poses: &PosesFile) -> Option<PerDsmError> {
        let posed: Vec<(&TruthTile, Matrix4<f64>, Matrix4<f64>)> = self
            .tiles
            .iter()
            .filter_map(|t| Some((t, matrix(&t.matrix_world), *poses.pose(&t.id)?)))
            .collect();
        let first = posed.first()?;
        // a local origin keeps the fit's sums far from 10^6 m coordinates
        let origin = self.centre(first.0).xyz();
        let mut corrs = Vec::with_capacity(posed.len() * 4);
        for (t, truth, est) in &posed {
            let g = t.geotransform;
            for (fx, fy) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
                let c = Vector4::new(
                    g[0] + g[1] * t.width as f64 * fx,
                    g[3] + g[5] * t.height as f64 * fy,
                    self.pivot_z(),
                    1.0,
                );
                corrs.push(Correspondence {
                    moving: (truth * c).xyz() - origin,
                    reference: (est * c).xyz() - origin,
                    normal: Vector3::z(),
                    weight: 1.0,
                    normal_var: 0.0,
                });
            }
        }
        // G in the local frame, then in world coordinates
        let local = point_to_point(&corrs, Model::Rigid)?.to_homogeneous();
        let shift = Matrix4::new_translation(&origin);
        let gauge = shift * local * inverse(&shift);
        let gauge_inv = inverse(&gauge);
        let mut out = PerDsmError {
            tiles: Vec::with_capacity(posed.len()),
            worst_m: 0.0,
            worst_deg: 0.0,
        };
        for (t, truth, est) in &posed {
            let d = inverse(truth) * gauge_inv * est;
            let centre = self.centre(t);
            let disp = (d * centre - centre).xyz().norm();
            let deg = angle_deg(&d);
            out.worst_m = out.worst_m.max(disp);
            out.worst_deg = out.worst_deg.max(deg);
            out.tiles.push((t.id.clone(), disp, deg));
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::poses::{GaugeLabel, GraphKind, PoseEntry};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn tile(id: &str, x0: f64, m: &Matrix4<f64>) -> TruthTile {
        TruthTile {
            id: id.into(),
            file: format!("{id}.tif"),
            matrix_world: crate::geo::rigid::to_rows(m),
            width: 1000,
            height: 1000,
            geotransform: [x0, 0.5, 0.0, 5_000_500.0, 0.0, -0.5],
            shift_m: [0.0; 3],
            rot_deg: [0.0; 3],
        }
    }

    fn rigid(t: [f64; 3], yaw_deg: f64) -> Matrix4<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians()),
        )
        .to_homogeneous()
    }

    fn truth(ms: &[Matrix4<f64>]) -> Truth {
        let tiles = ms
            .iter()
            .enumerate()
            .map(|(k, m)| tile(&format!("t{k}"), 400_000.0 + 300.0 * k as f64, m))
            .collect();
        serde_json::from_value::<Truth>(serde_json::json!({
            "crs": "EPSG:32617", "gsd": 0.5, "layout": "chain", "seed": 1, "tiles": []
        }))
        .map(|mut t| {
            t.tiles = tiles;
            t
        })
        .unwrap()
    }

    fn poses(entries: &[(&str, Matrix4<f64>)]) -> PosesFile {
        PosesFile {
            crs: "EPSG:32617".into(),
            poses: entries
                .iter()
                .map(|(id, m)| PoseEntry {
                    id: id.to_string(),
                    matrix_world: *m,
                    sigma: None,
                    status: None,
                })
                .collect(),
            edges: Vec::new(),
            graph: GraphKind::Full,
            gauge: GaugeLabel::Mean,
            components: None,
            summary: None,
        }
    }

    #[test]
    fn a_common_motion_is_no_error_but_one_moved_tile_is() {
        let ms = [
            rigid([1.0, -2.0, 0.5], 0.01),
            rigid([-0.5, 0.3, 0.1], -0.02),
            rigid([0.2, 0.2, -0.3], 0.005),
        ];
        let t = truth(&ms);
        // the truth moved by one rigid gauge motion (about a far-away point)
        let gauge = rigid([3.0, -4.0, 1.0], 0.03);
        let est: Vec<(&str, Matrix4<f64>)> = ["t0", "t1", "t2"]
            .into_iter()
            .zip(ms.iter().map(|m| gauge * m))
            .collect();
        let e = t.per_dsm_error(&poses(&est)).unwrap();
        assert!(e.worst_m < 1e-6 && e.worst_deg < 1e-6, "{e:?}");
        assert!(t.pairwise_error(&poses(&est)).worst_m < 1e-6);
        // one tile off by 10 cm: it carries most of the error
        let mut off = est.clone();
        off[1].1 = rigid([0.1, 0.0, 0.0], 0.0) * off[1].1;
        let e = t.per_dsm_error(&poses(&off)).unwrap();
        assert!(e.tiles[1].1 > 0.05 && e.tiles[1].1 < 0.1, "{e:?}");
        assert!(e.tiles[0].1 < 0.05 && e.tiles[2].1 < 0.05, "{e:?}");
        assert!((e.worst_m - e.tiles[1].1).abs() < 1e-12);
        // t0 and t2 (600 m apart) do not overlap: both pairs that do hold t1
        let seams = t.overlap_error(&poses(&off));
        assert!((seams.mean_m - 0.1).abs() < 1e-6, "{seams:?}");
        assert!((seams.worst_m - 0.1).abs() < 1e-6, "{seams:?}");
        assert!(t.overlap_error(&poses(&est)).worst_m < 1e-6);
    }

    /// A rotation error of one DSM, extrapolated to a DSM a kilometre away,
    /// weighs more in all pairs than at the seams: t0 turned 0.05 deg about
    /// its centre moves t2's centre (600 m off) 0.52 m, its seam with t1 (a
    /// corner 354 m off) 0.31 m.
    #[test]
    fn overlapping_pairs_measure_the_seams_only() {
        let ms = [rigid([0.0; 3], 0.0); 3];
        let t = truth(&ms);
        let c = t.centre(&t.tiles[0]).xyz();
        let turn = Isometry3::rotation_wrt_point(
            UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05f64.to_radians()),
            c.into(),
        )
        .to_homogeneous();
        let est = poses(&[("t0", turn), ("t1", ms[1]), ("t2", ms[2])]);
        let all = t.pairwise_error(&est);
        let seams = t.overlap_error(&est);
        let arc = |r: f64| r * 0.05f64.to_radians();
        assert!((all.worst_m - arc(600.0)).abs() < 1e-3, "{all:?}");
        let corner = (250.0f64.powi(2) + 250.0f64.powi(2)).sqrt();
        assert!((seams.worst_m - arc(corner)).abs() < 1e-3, "{seams:?}");
    }
}
