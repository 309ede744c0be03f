//! Reading, validating and writing poses.json (see [`super`] for the layout): one
//! pose and one edge per line, atomic replacement, shortest round-trip digits.

use super::{
    rigid, EdgeEntry, GaugeLabel, GraphKind, PoseEntry, PoseList, PosesError, PosesFile,
    PosesSummary, RIGIDITY_TOLERANCE,
};
use nalgebra::Matrix4;
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::io::Write;
use std::path::Path;

/// Mirror of the file for reading: matrices as nested lists so their shape can be
/// checked with a message naming the pose.
#[derive(Deserialize)]
struct RawFile {
    crs: String,
    poses: Vec<RawPose>,
    edges: Vec<EdgeEntry>,
    graph: GraphKind,
    gauge: String,
    #[serde(default)]
    components: Option<Vec<Vec<String>>>,
    #[serde(default)]
    summary: Option<PosesSummary>,
}

/// The lenient mirror: only the poses are required; unknown fields are ignored.
#[derive(Deserialize)]
struct RawPoseList {
    #[serde(default)]
    crs: Option<String>,
    poses: Vec<RawPose>,
}

#[derive(Serialize, Deserialize)]
struct RawPose {
    id: String,
    matrix_world: Vec<Vec<f64>>,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "lenient"
    )]
    sigma: Option<crate::averaging::NodeSigma>,
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "lenient"
    )]
    status: Option<crate::averaging::NodeStatus>,
}

/// An optional field another tool may write in its own form: read when it is
/// ours, ignored (None) when it is not, like an unknown field.
fn lenient<'de, D, T>(deserializer: D) -> Result<Option<T>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: serde::de::DeserializeOwned,
{
    let value = serde_json::Value::deserialize(deserializer)?;
    Ok(serde_json::from_value(value).ok())
}

impl PosesFile {
    /// Reads and validates a poses file.
    pub fn read(path: &Path) -> Result<PosesFile, PosesError> {
        let file = std::fs::File::open(path).map_err(|source| PosesError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let raw: RawFile = serde_json::from_reader(std::io::BufReader::new(file)).map_err(|e| {
            PosesError::Parse {
                path: path.to_path_buf(),
                message: e.to_string(),
            }
        })?;
        from_raw(raw).map_err(|message| PosesError::Invalid {
            path: path.to_path_buf(),
            message,
        })
    }

    /// Checks what [`PosesFile::read`] checks, plus that every number is finite.
    pub fn validate(&self) -> Result<(), String> {
        let mut ids = HashSet::with_capacity(self.poses.len());
        for p in &self.poses {
            check_matrix(&p.id, &p.matrix_world)?;
            let sigma_ok = p.sigma.is_none_or(|s| {
                s.shift_m
                    .iter()
                    .chain(&s.rotation_deg)
                    .all(|v| v.is_finite() && *v >= 0.0)
            });
            if !sigma_ok {
                return Err(format!("pose {}: sigma must be finite and >= 0", p.id));
            }
            if !ids.insert(p.id.as_str()) {
                return Err(format!("duplicate pose id {}", p.id));
            }
        }
        for (k, e) in self.edges.iter().enumerate() {
            for id in [&e.i, &e.j] {
                if !ids.contains(id.as_str()) {
                    return Err(format!(
                        "edge {k} ({} - {}): unknown pose id {id}",
                        e.i, e.j
                    ));
                }
            }
            let numbers = [
                ("overlap", e.overlap),
                ("rmse", e.rmse_m),
                ("weight", e.weight),
                ("residual_m", e.residual_m),
                ("residual_deg", e.residual_deg),
            ];
            if let Some((name, _)) = numbers.iter().find(|(_, v)| !v.is_finite()) {
                return Err(format!(
                    "edge {k} ({} - {}): {name} is not finite",
                    e.i, e.j
                ));
            }
        }
        if let GaugeLabel::Anchor(id) = &self.gauge {
            if !ids.contains(id.as_str()) {
                return Err(format!("gauge anchor:{id} names an unknown pose"));
            }
        }
        for id in self.components.iter().flatten().flatten() {
            if !ids.contains(id.as_str()) {
                return Err(format!("components: unknown pose id {id}"));
            }
        }
        Ok(())
    }

    /// Validates, then writes atomically: a temporary file in the same folder,
    /// renamed (the temporaries of killed runs go first).
    pub fn write(&self, path: &Path) -> Result<(), PosesError> {
        self.validate().map_err(|message| PosesError::Invalid {
            path: path.to_path_buf(),
            message,
        })?;
        crate::atomic::remove_stale_temporaries(path);
        crate::atomic::write_atomically(path, |out| self.write_json(out)).map_err(|source| {
            PosesError::Io {
                path: path.to_path_buf(),
                source,
            }
        })
    }

    /// The JSON text, one pose and one edge per line.
    pub fn write_json(&self, out: &mut impl Write) -> std::io::Result<()> {
        writeln!(out, "{{")?;
        writeln!(out, "  \"crs\": {},", serde_json::to_string(&self.crs)?)?;
        let poses = self.poses.iter().map(|p| RawPose {
            id: p.id.clone(),
            matrix_world: (0..4)
                .map(|r| (0..4).map(|c| p.matrix_world[(r, c)]).collect())
                .collect(),
            sigma: p.sigma,
            status: p.status,
        });
        write_list(out, "poses", poses)?;
        write_list(out, "edges", self.edges.iter())?;
        writeln!(out, "  \"graph\": {},", serde_json::to_string(&self.graph)?)?;
        write!(
            out,
            "  \"gauge\": {}",
            serde_json::to_string(&self.gauge.label())?
        )?;
        if let Some(components) = &self.components {
            write!(
                out,
                ",\n  \"components\": {}",
                serde_json::to_string(components)?
            )?;
        }
        if let Some(summary) = &self.summary {
            write!(out, ",\n  \"summary\": {}", serde_json::to_string(summary)?)?;
        }
        writeln!(out, "\n}}")
    }
}

fn write_list<T: Serialize>(
    out: &mut impl Write,
    key: &str,
    items: impl Iterator<Item = T>,
) -> std::io::Result<()> {
    write!(out, "  \"{key}\": [")?;
    let mut first = true;
    for item in items {
        out.write_all(if first { b"\n    " } else { b",\n    " })?;
        serde_json::to_writer(&mut *out, &item)?;
        first = false;
    }
    writeln!(out, "{}],", if first { "" } else { "\n  " })
}

fn from_raw(raw: RawFile) -> Result<PosesFile, String> {
    let poses = poses_from_raw(raw.poses)?;
    let gauge = GaugeLabel::parse(&raw.gauge).ok_or_else(|| {
        format!(
            "gauge must be \"mean\" or \"anchor:<id>\", not {:?}",
            raw.gauge
        )
    })?;
    let file = PosesFile {
        crs: raw.crs,
        poses,
        edges: raw.edges,
        graph: raw.graph,
        gauge,
        components: raw.components,
        summary: raw.summary,
    };
    file.validate()?;
    Ok(file)
}

/// The poses as matrices, each checked for its 4x4 shape (not yet for rigidity).
fn poses_from_raw(raw: Vec<RawPose>) -> Result<Vec<PoseEntry>, String> {
    let mut poses = Vec::with_capacity(raw.len());
    for p in raw {
        let rows = &p.matrix_world;
        if rows.len() != 4 || rows.iter().any(|r| r.len() != 4) {
            let shape: Vec<String> = rows.iter().map(|r| r.len().to_string()).collect();
            return Err(format!(
                "pose {}: matrix_world must be 4x4 (rows of {} values)",
                p.id,
                shape.join(", ")
            ));
        }
        let matrix_world = Matrix4::from_fn(|r, c| rows[r][c]);
        poses.push(PoseEntry {
            id: p.id,
            matrix_world,
            sigma: p.sigma,
            status: p.status,
        });
    }
    Ok(poses)
}

/// Reads only what applying poses needs (see [`PoseList`]); when the file is also
/// a complete poses.json, it is returned whole as well.
pub(super) fn read_pose_list(path: &Path) -> Result<PoseList, PosesError> {
    let text = std::fs::read_to_string(path).map_err(|source| PosesError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let parse = |message: String| PosesError::Parse {
        path: path.to_path_buf(),
        message,
    };
    let value: serde_json::Value = serde_json::from_str(&text).map_err(|e| parse(e.to_string()))?;
    let lean: RawPoseList =
        serde_json::from_value(value.clone()).map_err(|e| parse(e.to_string()))?;
    let invalid = |message: String| PosesError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    let poses = poses_from_raw(lean.poses).map_err(invalid)?;
    let mut ids = HashSet::with_capacity(poses.len());
    for p in &poses {
        check_matrix(&p.id, &p.matrix_world).map_err(invalid)?;
        if !ids.insert(p.id.as_str()) {
            return Err(invalid(format!("duplicate pose id {}", p.id)));
        }
    }
    let full = serde_json::from_value::<RawFile>(value)
        .ok()
        .and_then(|raw| from_raw(raw).ok());
    Ok(PoseList {
        crs: lean.crs.filter(|c| !c.is_empty()),
        poses,
        full,
    })
}

fn check_matrix(id: &str, m: &Matrix4<f64>) -> Result<(), String> {
    if !m.iter().all(|v| v.is_finite()) {
        return Err(format!("pose {id}: matrix_world has a non-finite value"));
    }
    let last = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)]];
    if last != [0.0, 0.0, 0.0, 1.0] {
        return Err(format!(
            "pose {id}: matrix_world last row must be 0 0 0 1, not {last:?}"
        ));
    }
    let rigidity = rigid::rigidity(m);
    if !rigidity.is_rigid(RIGIDITY_TOLERANCE) {
        return Err(format!(
            "pose {id}: matrix is not rigid (det {:.4}, |R^T R - I| {:.1e})",
            rigidity.det, rigidity.orthonormality_error
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::rigid::{from_parts, rotation_from_axis_angle};
    use super::*;
    use nalgebra::Vector3;

    /// Poses with awkward digits: UTM-sized translations, tiny rotations.
    fn sample_file(count: usize) -> PosesFile {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let poses: Vec<PoseEntry> = (0..count)
            .map(|k| {
                let axis_angle = Vector3::new(next(), next(), next()) * 1e-3;
                let t = Vector3::new(next() * 1e6, next() * 1e7, next() * 1e3);
                let matrix_world = from_parts(&rotation_from_axis_angle(&axis_angle), &t);
                PoseEntry {
                    id: format!("tile_{k:02}"),
                    matrix_world,
                    sigma: (k == 1).then_some(crate::averaging::NodeSigma {
                        shift_m: [0.012, 0.0305, 0.25],
                        rotation_deg: [1e-4, 2.5e-3, 0.0625],
                    }),
                    status: (k == 2).then_some(crate::averaging::NodeStatus::Unconstrained),
                }
            })
            .collect();
        let edges = (1..count)
            .map(|k| EdgeEntry {
                i: poses[k - 1].id.clone(),
                j: poses[k].id.clone(),
                overlap: next() + 0.5,
                rmse_m: next() + 0.5,
                weight: (next() + 0.5) * 1e-7,
                translation_weight: (k != 3).then(|| next() + 0.5),
                iterations: 12,
                inliers: 18211,
                residual_m: (next() + 0.5) * 1e-3,
                residual_deg: (next() + 0.5) * 1e-4,
                dropped: k == 2,
                downweighted: k == 3,
                converged: true,
            })
            .collect();
        PosesFile {
            crs: "EPSG:32617".into(),
            components: Some(vec![poses.iter().map(|p| p.id.clone()).collect()]),
            poses,
            edges,
            graph: GraphKind::Full,
            gauge: GaugeLabel::Anchor("tile_01".into()),
            summary: None,
        }
    }

    fn bad_file_error(dir: &Path, text: &str) -> String {
        let path = dir.join("poses.json");
        std::fs::write(&path, text).unwrap();
        let err = PosesFile::read(&path).unwrap_err();
        assert!(err.is_bad_input());
        err.to_string()
    }

    #[test]
    fn round_trip_is_bit_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("poses.json");
        let file = sample_file(200);
        file.write(&path).unwrap();
        let back = PosesFile::read(&path).unwrap();
        for (a, b) in file.poses.iter().zip(&back.poses) {
            for (x, y) in a.matrix_world.iter().zip(b.matrix_world.iter()) {
                assert_eq!(x.to_bits(), y.to_bits(), "pose {}", a.id);
            }
        }
        assert_eq!(back, file);
        // Atomic write leaves no temporary file behind.
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("poses.json")]);
    }

    #[test]
    fn layout_matches_the_design_contract() {
        let mut file = sample_file(3);
        file.gauge = GaugeLabel::Mean;
        file.components = None;
        let mut text = Vec::new();
        file.write_json(&mut text).unwrap();
        let value: serde_json::Value = serde_json::from_slice(&text).unwrap();
        assert_eq!(value["crs"], "EPSG:32617");
        assert_eq!(value["graph"], "full");
        assert_eq!(value["gauge"], "mean");
        assert_eq!(value["poses"][1]["id"], "tile_01");
        assert_eq!(
            value["poses"][1]["matrix_world"][3],
            serde_json::json!([0.0, 0.0, 0.0, 1.0])
        );
        let m = &file.poses[1].matrix_world;
        assert_eq!(
            value["poses"][1]["matrix_world"][0][3].as_f64(),
            Some(m[(0, 3)])
        );
        assert_eq!(value["edges"][0]["i"], "tile_00");
        assert_eq!(
            value["edges"][0]["rmse"].as_f64(),
            Some(file.edges[0].rmse_m)
        );
        assert_eq!(value["edges"][1]["dropped"], true);
        assert!(value.get("components").is_none());
        assert_eq!(
            GaugeLabel::parse("anchor:a:b"),
            Some(GaugeLabel::Anchor("a:b".into()))
        );
        assert_eq!(GaugeLabel::parse("anchor:"), None);
    }

    #[test]
    fn validation_errors_name_the_file_and_the_pose() {
        let dir = tempfile::tempdir().unwrap();
        let mut text = Vec::new();
        sample_file(4).write_json(&mut text).unwrap();
        let good = String::from_utf8(text).unwrap();
        let value: serde_json::Value = serde_json::from_str(&good).unwrap();
        let edit = |f: &dyn Fn(&mut serde_json::Value)| {
            let mut v = value.clone();
            f(&mut v);
            v.to_string()
        };
        let scaled = edit(&|v| {
            for c in 0..3 {
                for r in 0..3 {
                    let x = v["poses"][3]["matrix_world"][r][c].as_f64().unwrap();
                    v["poses"][3]["matrix_world"][r][c] = serde_json::json!(x * 0.976);
                }
            }
        });
        let err = bad_file_error(dir.path(), &scaled);
        assert!(
            err.contains("poses.json: pose tile_03: matrix is not rigid (det 0.9297"),
            "{err}"
        );
        let short =
            edit(&|v| v["poses"][2]["matrix_world"][1] = serde_json::json!([1.0, 0.0, 0.0]));
        let err = bad_file_error(dir.path(), &short);
        assert!(
            err.contains("pose tile_02: matrix_world must be 4x4 (rows of 4, 3, 4, 4"),
            "{err}"
        );
        let last = edit(&|v| v["poses"][0]["matrix_world"][3][0] = serde_json::json!(0.5));
        assert!(bad_file_error(dir.path(), &last).contains("pose tile_00: matrix_world last row"));
        let dup = edit(&|v| v["poses"][2]["id"] = serde_json::json!("tile_01"));
        assert!(bad_file_error(dir.path(), &dup).ends_with("poses.json: duplicate pose id tile_01"));
        let unknown = edit(&|v| v["edges"][0]["j"] = serde_json::json!("tile_99"));
        assert!(bad_file_error(dir.path(), &unknown).contains("unknown pose id tile_99"));
        let gauge = edit(&|v| v["gauge"] = serde_json::json!("anchor:nope"));
        assert!(bad_file_error(dir.path(), &gauge).contains("gauge anchor:nope"));
        let graph = edit(&|v| v["graph"] = serde_json::json!("tree"));
        assert!(bad_file_error(dir.path(), &graph).contains("not a valid poses file"));
        let missing = PosesFile::read(&dir.path().join("absent.json")).unwrap_err();
        assert!(!missing.is_bad_input() && missing.to_string().contains("absent.json"));
    }

    #[test]
    fn writing_refuses_non_finite_numbers() {
        let dir = tempfile::tempdir().unwrap();
        let mut file = sample_file(3);
        file.edges[1].residual_m = f64::NAN;
        let err = file
            .write(&dir.path().join("poses.json"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("edge 1 (tile_01 - tile_02): residual_m is not finite"),
            "{err}"
        );
        assert!(!dir.path().join("poses.json").exists());
    }
}
