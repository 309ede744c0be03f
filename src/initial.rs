//! Initial poses (`--initial poses.json`, pc_align's `--initial-transform`):
//! where each DSM starts. Any file with `{"poses": [{"id", "matrix_world"}]}`
//! (a poses.json of an earlier run, or written by hand or by another tool);
//! DSMs it does not list start at the identity.
//!
//! Each DSM starts moved by the motion its initial pose A gives its centre c
//! (s = A c - c, a translation: see [`crate::view`]); the pairs are then
//! measured in the DSMs' own coordinates and averaged as usual, so the poses
//! written are full corrections. [`InitialPoses::regauge`] then moves every
//! pose of a connected component by one rigid motion (which changes no
//! relative pose) so that the component sits where its initial poses put it:
//! on the anchor's initial pose, or on their mean.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Matrix4, Vector3};

use crate::geo::rigid::{apply, from_parts, inverse_rigid, project_to_so3, rotation};
use crate::poses::{PoseList, PosesFile};
use crate::store::Store;

/// The initial poses, by DSM id.
#[derive(Clone, Debug)]
pub struct InitialPoses {
    pub path: PathBuf,
    /// FNV-1a of the file's bytes (recorded in the journal's settings).
    pub content_hash: u64,
    /// The CRS the file names, if any.
    pub crs: Option<String>,
    poses: HashMap<String, Matrix4<f64>>,
}

impl InitialPoses {
    /// Reads and checks the file (every pose rigid, ids unique); the error
    /// names the file.
    pub fn read(path: &Path) -> Result<InitialPoses, String> {
        let bytes = std::fs::read(path)
            .map_err(|e| format!("{}: cannot read the initial poses: {e}", path.display()))?;
        let list = PoseList::read(path).map_err(|e| e.to_string())?;
        Ok(InitialPoses {
            path: path.to_path_buf(),
            content_hash: crate::view::content_hash(&bytes),
            crs: list.crs,
            poses: list
                .poses
                .into_iter()
                .map(|p| (p.id, p.matrix_world))
                .collect(),
        })
    }

    /// The initial pose of DSM `id` (the identity when not listed).
    pub fn matrix(&self, id: &str) -> Matrix4<f64> {
        self.poses
            .get(id)
            .copied()
            .unwrap_or_else(Matrix4::identity)
    }

    /// Checks the file against the store (same CRS when it names one) and
    /// returns the ids it lists that the store does not hold (ignored).
    pub fn check(&self, store: &Store) -> Result<Vec<String>, String> {
        if let (Some(crs), Some(named)) = (store.crs(), &self.crs) {
            if *named != crs.label() {
                return Err(format!(
                    "{}: the initial poses are for CRS {named} but the store {} is {}",
                    self.path.display(),
                    store.root().display(),
                    crs.label()
                ));
            }
        }
        let mut unknown: Vec<String> = self
            .poses
            .keys()
            .filter(|id| store.find(id).is_none())
            .cloned()
            .collect();
        unknown.sort();
        Ok(unknown)
    }

    /// Per DSM of the store (by index), the motion of its centre under its
    /// initial pose: the shift it starts from.
    pub fn shifts_m(&self, store: &Store) -> Vec<Vector3<f64>> {
        store
            .dsms()
            .iter()
            .map(|d| {
                let (x, y) = d.footprint.centre();
                let c = Vector3::new(x, y, d.height_stats.mean);
                apply(&self.matrix(&d.id), &c) - c
            })
            .collect()
    }

    /// Moves each connected component of `poses` (its `components`, else one)
    /// by one rigid motion G so it sits where the initial poses put it: G =
    /// A_anchor M_anchor^-1 when the anchor is in it, else the mean of A_i
    /// M_i^-1 over its DSMs (taken about their centre).
    pub fn regauge(&self, store: &Store, poses: &mut PosesFile, anchor: Option<&str>) {
        let mut groups: Vec<Vec<String>> = match &poses.components {
            Some(c) if !c.is_empty() => c.clone(),
            _ => vec![poses.poses.iter().map(|p| p.id.clone()).collect()],
        };
        // a pose in no listed component is a component of its own
        let listed: std::collections::HashSet<String> = groups.iter().flatten().cloned().collect();
        let alone: Vec<Vec<String>> = poses
            .poses
            .iter()
            .filter(|p| !listed.contains(&p.id))
            .map(|p| vec![p.id.clone()])
            .collect();
        groups.extend(alone);
        for group in groups {
            let members: Vec<usize> = poses
                .poses
                .iter()
                .enumerate()
                .filter(|(_, p)| group.contains(&p.id))
                .map(|(k, _)| k)
                .collect();
            let offsets: Vec<(Matrix4<f64>, Vector3<f64>)> = members
                .iter()
                .map(|&k| {
                    let p = &poses.poses[k];
                    let x = self.matrix(&p.id) * inverse_rigid(&p.matrix_world);
                    (x, centre_of(store, &p.id))
                })
                .collect();
            let anchored =
                anchor.and_then(|a| members.iter().position(|&k| poses.poses[k].id == a));
            let g = match anchored {
                Some(at) => offsets[at].0,
                None => mean_motion(&offsets),
            };
            for &k in &members {
                poses.poses[k].matrix_world = g * poses.poses[k].matrix_world;
            }
        }
    }
}

/// A DSM's centre (footprint centre, mean height); the origin when unknown.
fn centre_of(store: &Store, id: &str) -> Vector3<f64> {
    store.find(id).map_or_else(Vector3::zeros, |k| {
        let d = &store.dsms()[k];
        let (x, y) = d.footprint.centre();
        Vector3::new(x, y, d.height_stats.mean)
    })
}

/// The mean of rigid motions X_i, each taken at its point c_i: the rotation
/// is the projection of the mean rotation onto SO(3), about the mean point o;
/// the translation the mean of X_i o - o.
fn mean_motion(motions: &[(Matrix4<f64>, Vector3<f64>)]) -> Matrix4<f64> {
    if motions.is_empty() {
        return Matrix4::identity();
    }
    let n = motions.len() as f64;
    let o = motions.iter().map(|(_, c)| c).sum::<Vector3<f64>>() / n;
    let r_sum: Matrix3<f64> = motions.iter().map(|(x, _)| rotation(x)).sum();
    let r = project_to_so3(&(r_sum / n));
    let moved = motions
        .iter()
        .map(|(x, _)| apply(x, &o) - o)
        .sum::<Vector3<f64>>()
        / n;
    // G p = R (p - o) + o + moved
    from_parts(&r, &(o + moved - r * o))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::rigid::rotation_from_axis_angle;

    #[test]
    fn the_mean_motion_of_equal_motions_is_that_motion() {
        let r = rotation_from_axis_angle(&Vector3::new(0.0, 0.0, 1e-4));
        let x = from_parts(&r, &Vector3::new(5.0, -2.0, 1.0));
        let c = Vector3::new(500_000.0, 4_800_000.0, 200.0);
        let g = mean_motion(&[(x, c), (x, c + Vector3::new(100.0, 0.0, 0.0))]);
        assert!((g - x).amax() < 1e-6, "{g}");
        let t = |v: f64| from_parts(&Matrix3::identity(), &Vector3::new(v, 0.0, 0.0));
        let g = mean_motion(&[(t(1.0), c), (t(3.0), c)]);
        assert!((g - t(2.0)).amax() < 1e-12);
        assert_eq!(mean_motion(&[]), Matrix4::identity());
    }

    #[test]
    fn unlisted_dsms_start_at_the_identity() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("i.json");
        let text = r#"{"poses": [{"id": "b", "matrix_world": [[1,0,0,-20],[0,1,0,16],[0,0,1,0],[0,0,0,1]]}]}"#;
        std::fs::write(&path, text).unwrap();
        let initial = InitialPoses::read(&path).unwrap();
        assert_eq!(initial.matrix("a"), Matrix4::identity());
        assert_eq!(initial.matrix("b")[(0, 3)], -20.0);
        assert_eq!(
            initial.content_hash,
            crate::view::content_hash(text.as_bytes())
        );
        let missing = InitialPoses::read(&dir.path().join("none.json")).unwrap_err();
        assert!(missing.contains("none.json"), "{missing}");
    }
}
