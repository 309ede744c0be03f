//! [`PoseList`]: what applying poses needs from a poses file, `{"poses": [{"id",
//! "matrix_world"}]}`, so a file written by another tool can be fused and
//! evaluated. Every other field is optional and unknown fields are ignored; the
//! poses themselves are checked as strictly as in poses.json (4x4, last row
//! 0 0 0 1, rigid, unique ids).

use super::{PoseEntry, PosesError, PosesFile};
use std::path::Path;

/// The poses of a file, with the whole poses.json when the file is one.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseList {
    /// CRS label, when the file gives a non-empty one.
    pub crs: Option<String>,
    pub poses: Vec<PoseEntry>,
    /// The complete file (edges, graph, gauge) when it parses and validates as
    /// poses.json; None for a lean file from elsewhere.
    pub full: Option<PosesFile>,
}

impl PoseList {
    /// Reads `path`, requiring only `poses` with `id` and `matrix_world` each.
    pub fn read(path: &Path) -> Result<PoseList, PosesError> {
        super::json::read_pose_list(path)
    }
}

impl From<PosesFile> for PoseList {
    fn from(file: PosesFile) -> PoseList {
        PoseList {
            crs: Some(file.crs.clone()).filter(|c| !c.is_empty()),
            poses: file.poses.clone(),
            full: Some(file),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, text: &str) -> std::path::PathBuf {
        let path = dir.join("other.json");
        std::fs::write(&path, text).unwrap();
        path
    }

    const SHIFTED: &str = "[[1,0,0,2.5],[0,1,0,-1],[0,0,1,0.25],[0,0,0,1]]";

    #[test]
    fn a_lean_file_with_unknown_fields_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let text = format!(
            r#"{{"producer": "elsewhere", "poses": [{{"id": "a", "matrix_world": {SHIFTED}, "sigma": [1, 2]}}],
               "edges": [{{"i": "a", "j": "a"}}]}}"#
        );
        let list = PoseList::read(&write(dir.path(), &text)).unwrap();
        assert_eq!(list.crs, None);
        assert!(list.full.is_none());
        assert_eq!(list.poses.len(), 1);
        assert_eq!(list.poses[0].id, "a");
        assert_eq!(list.poses[0].matrix_world[(0, 3)], 2.5);
        assert_eq!(list.poses[0].matrix_world[(2, 3)], 0.25);
    }

    #[test]
    fn the_poses_are_still_checked() {
        let dir = tempfile::tempdir().unwrap();
        let scaled = r#"{"poses": [{"id": "a", "matrix_world": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}"#;
        let err = PoseList::read(&write(dir.path(), scaled)).unwrap_err();
        assert!(err.is_bad_input());
        assert!(
            err.to_string().contains("pose a: matrix is not rigid"),
            "{err}"
        );
        let twice = format!(
            r#"{{"poses": [{{"id": "a", "matrix_world": {SHIFTED}}}, {{"id": "a", "matrix_world": {SHIFTED}}}]}}"#
        );
        let err = PoseList::read(&write(dir.path(), &twice)).unwrap_err();
        assert!(err.to_string().ends_with("duplicate pose id a"), "{err}");
        let none = PoseList::read(&write(dir.path(), r#"{"crs": "EPSG:32617"}"#)).unwrap_err();
        assert!(none.to_string().contains("missing field `poses`"), "{none}");
    }

    #[test]
    fn a_complete_file_keeps_its_edges() {
        let dir = tempfile::tempdir().unwrap();
        let text = format!(
            r#"{{"crs": "EPSG:32617", "poses": [{{"id": "a", "matrix_world": {SHIFTED}}}],
               "edges": [], "graph": "mst", "gauge": "anchor:a"}}"#
        );
        let list = PoseList::read(&write(dir.path(), &text)).unwrap();
        assert_eq!(list.crs.as_deref(), Some("EPSG:32617"));
        let full = list.full.expect("a complete poses.json");
        assert_eq!(full.graph, super::super::GraphKind::Mst);
        assert_eq!(full.poses, list.poses);
    }
}
