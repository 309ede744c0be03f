//! The pictures of an `eval` report, assembled from its figures and samples:
//! the scene graph (edges coloured by the averaging residual when the poses
//! file has edges, else by each pair's rmse_tau), the histogram of pairwise
//! height differences before/after, and with a reference its histogram and
//! difference map. `dsmstream eval --plots DIR` writes them.

use std::path::{Path, PathBuf};

use super::{
    diff_map_png, histogram_png, scene_graph_png, GraphEdge, GraphNode, MapGrid, PlotError, Series,
};
use crate::eval::{DiffSample, DiffStats, EvalReport, PlotData};
use crate::fuse::{PlacedDsm, PoseSet};
use crate::geo::Bounds;
use crate::store::Store;

/// Colour of the "before" series (orange).
const BEFORE: [u8; 3] = [230, 120, 30];
/// Colour of the "after" series (blue).
const AFTER: [u8; 3] = [30, 90, 200];
/// Cells across the difference map.
const MAP_CELLS: usize = 240;

/// Writes the report's pictures into `dir` (created if absent) and returns
/// their paths: scene_graph.png, hist_pairs.png (when pairs overlap), and with
/// a reference hist_reference.png and diff_map_reference.png.
pub fn write_eval_plots(
    dir: &Path,
    store: &Store,
    poses: Option<&PoseSet>,
    report: &EvalReport,
    data: &PlotData,
) -> Result<Vec<PathBuf>, PlotError> {
    std::fs::create_dir_all(dir)
        .map_err(|e| PlotError(format!("creating {}: {e}", dir.display())))?;
    let mut written = vec![dir.join("scene_graph.png")];
    scene_graph(&written[0], store, poses, report)?;
    if !data.pairs_before.is_empty() {
        let path = dir.join("hist_pairs.png");
        pair_histogram(&path, poses.is_some(), report, data)?;
        written.push(path);
    }
    if let (Some(r), false) = (&report.reference, data.reference.is_empty()) {
        let after = r.after.is_some();
        let tau = report.tau_m as f32;
        let path = dir.join("hist_reference.png");
        reference_histogram(&path, r.before, r.after, tau, &data.reference)?;
        written.push(path);
        let path = dir.join("diff_map_reference.png");
        reference_map(&path, after, tau, &data.reference)?;
        written.push(path);
    }
    Ok(written)
}

/// Footprints placed by the poses (identity without), and the edges of the
/// poses file or, without edges, the overlapping pairs of the report.
fn scene_graph(
    path: &Path,
    store: &Store,
    poses: Option<&PoseSet>,
    report: &EvalReport,
) -> Result<(), PlotError> {
    let identity;
    let placed_by = match poses {
        Some(p) => p,
        None => {
            identity = PoseSet::identity(store);
            &identity
        }
    };
    let nodes: Vec<GraphNode> = store
        .dsms()
        .iter()
        .enumerate()
        .map(|(i, m)| GraphNode {
            id: m.id.clone(),
            bounds: PlacedDsm::new(i, m, &placed_by.poses[i])
                .corrected_bounds
                .into(),
        })
        .collect();
    let file_edges = poses.and_then(|p| p.file.as_ref()).map(|f| &f.edges);
    let (edges, label, title): (Vec<GraphEdge>, _, _) = match file_edges.filter(|e| !e.is_empty()) {
        Some(edges) => (
            edges
                .iter()
                .filter_map(|e| {
                    Some(GraphEdge {
                        a: store.find(&e.i)?,
                        b: store.find(&e.j)?,
                        value_m: e.residual_m,
                        dropped: e.dropped,
                    })
                })
                .collect(),
            "edge residual after averaging (m)",
            "scene graph: edges coloured by averaging residual",
        ),
        None => (
            report
                .pairs
                .iter()
                .filter_map(|p| {
                    let s = p.after.unwrap_or(p.before);
                    Some(GraphEdge {
                        a: store.find(&p.i)?,
                        b: store.find(&p.j)?,
                        value_m: if s.inliers > 0 {
                            s.rmse_tau_m
                        } else {
                            f64::NAN
                        },
                        dropped: false,
                    })
                })
                .collect(),
            "pair rmse_tau (m)",
            "scene graph: overlapping pairs coloured by rmse_tau",
        ),
    };
    scene_graph_png(path, &nodes, &edges, label, title)
}

/// Pairwise height differences before, and after when poses were given.
fn pair_histogram(
    path: &Path,
    with_poses: bool,
    report: &EvalReport,
    data: &PlotData,
) -> Result<(), PlotError> {
    let mut series = vec![Series {
        label: legend("before (mean over pairs)", report.mean_before),
        values: &data.pairs_before,
        colour: BEFORE,
    }];
    if with_poses {
        series.push(Series {
            label: legend("after (mean over pairs)", report.mean_after),
            values: &data.pairs_after,
            colour: AFTER,
        });
    }
    histogram_png(
        path,
        &series,
        "dh = z_j - z_i, inliers of all pairs (m)",
        "pairwise height differences",
    )
}

/// Inlier differences against the reference, before and (if any) after.
fn reference_histogram(
    path: &Path,
    before: DiffStats,
    after: Option<DiffStats>,
    tau: f32,
    samples: &[DiffSample],
) -> Result<(), PlotError> {
    let inliers = |pick: fn(&DiffSample) -> f32| -> Vec<f32> {
        samples.iter().map(pick).filter(|d| d.abs() < tau).collect()
    };
    let (before_in, after_in) = (inliers(|s| s.dh_before), inliers(|s| s.dh_after));
    let mut series = vec![Series {
        label: legend("before", Some(before)),
        values: &before_in,
        colour: BEFORE,
    }];
    if let Some(a) = after {
        series.push(Series {
            label: legend("after", Some(a)),
            values: &after_in,
            colour: AFTER,
        });
    }
    histogram_png(
        path,
        &series,
        "dh = fused - reference, inliers (m)",
        "height differences against the reference",
    )
}

/// Cell means of the inlier differences against the reference, as a map
/// (before, and after beside it when poses were given).
fn reference_map(
    path: &Path,
    with_after: bool,
    tau: f32,
    samples: &[DiffSample],
) -> Result<(), PlotError> {
    let nothing = Bounds::from([
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ]);
    let bounds = samples.iter().fold(nothing, |b, s| {
        b.union(&Bounds::from_corners((s.x, s.y), (s.x, s.y)))
    });
    let grid = |after: bool| {
        MapGrid::bin(
            samples.iter().map(|s| {
                let d = if after { s.dh_after } else { s.dh_before };
                (s.x, s.y, if d.abs() < tau { d } else { f32::NAN })
            }),
            bounds,
            MAP_CELLS,
        )
    };
    let (g_before, g_after) = (grid(false), grid(true));
    let mut panels = vec![("before", &g_before)];
    if with_after {
        panels.push(("after", &g_after));
    }
    diff_map_png(
        path,
        &panels,
        "dh = fused - reference (m)",
        "fused DSM minus reference (inliers, cell means)",
    )
}

/// A legend entry: the set's name and, when it has inliers, its figures.
fn legend(set: &str, stats: Option<DiffStats>) -> String {
    match stats {
        Some(s) if s.inliers > 0 => format!(
            "{set}: rmse_tau {:.3} m, median {:.3} m, NMAD {:.3} m",
            s.rmse_tau_m, s.median_m, s.nmad_m
        ),
        _ => set.to_string(),
    }
}
