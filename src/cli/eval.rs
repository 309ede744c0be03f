//! `dsmstream eval <store> [--poses poses.json] [--reference ref.tif|lidar.laz]`:
//! rmse_tau and robust figures over every overlapping pair before/after the
//! poses, and against a reference; a table (or `--json`) on stdout and, with
//! `--plots DIR`, the scene graph, histograms and difference map as PNG.

use std::path::{Path, PathBuf};

use anyhow::Context;
use dsmstream::cache::ChunkCache;
use dsmstream::eval::{evaluate, DiffStats, EvalConfig, EvalError, EvalReport, PlotData};
use dsmstream::fuse::{FuseError, PlacedDsm, PoseSet};
use dsmstream::plots::{
    diff_map_png, histogram_png, scene_graph_png, GraphEdge, GraphNode, MapGrid, Series,
};
use dsmstream::store::Store;
use dsmstream::InputError;

use super::pair::open_store;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The store directory.
    pub store: PathBuf,
    /// poses.json from `dsmstream align` (omit to evaluate the raw collection).
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// Inlier threshold of rmse_tau, metres (paper: 10).
    #[arg(long, default_value_t = 10.0)]
    pub tau: f64,
    /// Reference surface: a GeoTIFF DSM, or a LAS/LAZ point cloud, in the store's CRS.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Print the report as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Write PNG pictures into this folder.
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Most sample locations per pair and for the reference.
    #[arg(long, default_value_t = 1_000_000)]
    pub max_samples: u64,
    /// Use every lidar return (default: first returns only).
    #[arg(long)]
    pub all_returns: bool,
    /// Chunk cache budget in MiB, shared by all workers.
    #[arg(long, default_value_t = 256)]
    pub cache_mb: usize,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let threads = super::threads_or_all(args.threads);
    if threads == 0 || args.max_samples == 0 {
        return Err(InputError::new("--threads and --max-samples must be at least 1").into());
    }
    let store = open_store(&args.store)?;
    let poses = match &args.poses {
        Some(p) => Some(PoseSet::from_file(&store, p).map_err(fuse_err)?),
        None => None,
    };
    let config = EvalConfig {
        tau_m: args.tau,
        max_samples: args.max_samples,
        threads,
        all_returns: args.all_returns,
    };
    let cache = ChunkCache::new(args.cache_mb.max(1) << 20);
    let (report, plot_data) = evaluate(
        &store,
        &cache,
        poses.as_ref(),
        args.reference.as_deref(),
        &config,
    )
    .map_err(eval_err)?;
    cache.log_stats();
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", report.to_table());
    }
    if let Some(dir) = &args.plots {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let written = write_plots(dir, &store, poses.as_ref(), &report, &plot_data)?;
        if !args.json {
            for p in written {
                println!("plot written: {}", p.display());
            }
        }
    }
    Ok(())
}

const BEFORE: [u8; 3] = [230, 120, 30];
const AFTER: [u8; 3] = [30, 90, 200];

/// The scene graph, pair histogram, and (with a reference) its histogram and map.
fn write_plots(
    dir: &Path,
    store: &Store,
    poses: Option<&PoseSet>,
    report: &EvalReport,
    data: &PlotData,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
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
            bounds: PlacedDsm::new(i, m, &placed_by.poses[i]).corrected_bounds,
        })
        .collect();
    let file_edges = poses.and_then(|p| p.file.as_ref()).map(|f| &f.edges);
    let (edges, label, title) = match file_edges.filter(|e| !e.is_empty()) {
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
                .collect::<Vec<_>>(),
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
                .collect::<Vec<_>>(),
            "pair rmse_tau (m)",
            "scene graph: overlapping pairs coloured by rmse_tau",
        ),
    };
    let path = dir.join("scene_graph.png");
    scene_graph_png(&path, &nodes, &edges, label, title)?;
    written.push(path);
    if !data.pairs_before.is_empty() {
        let path = dir.join("hist_pairs.png");
        let mut series = vec![Series {
            label: legend("before (mean over pairs)", report.mean_before),
            values: &data.pairs_before,
            colour: BEFORE,
        }];
        if poses.is_some() {
            series.push(Series {
                label: legend("after (mean over pairs)", report.mean_after),
                values: &data.pairs_after,
                colour: AFTER,
            });
        }
        histogram_png(
            &path,
            &series,
            "dh = z_j - z_i, inliers of all pairs (m)",
            "pairwise height differences",
        )?;
        written.push(path);
    }
    if let (Some(r), false) = (&report.reference, data.reference.is_empty()) {
        let before: Vec<f32> = data.reference.iter().map(|s| s.dh_before).collect();
        let after: Vec<f32> = data.reference.iter().map(|s| s.dh_after).collect();
        let tau = report.tau_m as f32;
        let inl = |v: &[f32]| -> Vec<f32> { v.iter().copied().filter(|d| d.abs() < tau).collect() };
        let (before_in, after_in) = (inl(&before), inl(&after));
        let path = dir.join("hist_reference.png");
        let mut series = vec![Series {
            label: legend("before", Some(r.before)),
            values: &before_in,
            colour: BEFORE,
        }];
        if let Some(a) = &r.after {
            series.push(Series {
                label: legend("after", Some(*a)),
                values: &after_in,
                colour: AFTER,
            });
        }
        histogram_png(
            &path,
            &series,
            "dh = fused - reference, inliers (m)",
            "height differences against the reference",
        )?;
        written.push(path);
        let bounds = data.reference.iter().fold(
            [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ],
            |b, s| [b[0].min(s.x), b[1].min(s.y), b[2].max(s.x), b[3].max(s.y)],
        );
        let grid = |after: bool| {
            MapGrid::bin(
                data.reference.iter().map(|s| {
                    let d = if after { s.dh_after } else { s.dh_before };
                    (s.x, s.y, if d.abs() < tau { d } else { f32::NAN })
                }),
                bounds,
                240,
            )
        };
        let (g_before, g_after) = (grid(false), grid(true));
        let mut panels = vec![("before", &g_before)];
        if r.after.is_some() {
            panels.push(("after", &g_after));
        }
        let path = dir.join("diff_map_reference.png");
        diff_map_png(
            &path,
            &panels,
            "dh = fused - reference (m)",
            "fused DSM minus reference (inliers, cell means)",
        )?;
        written.push(path);
    }
    Ok(written)
}

fn legend(set: &str, stats: Option<DiffStats>) -> String {
    match stats {
        Some(s) if s.inliers > 0 => format!(
            "{set}: rmse_tau {:.3} m, median {:.3} m, NMAD {:.3} m",
            s.rmse_tau_m, s.median_m, s.nmad_m
        ),
        _ => set.to_string(),
    }
}

fn fuse_err(e: FuseError) -> anyhow::Error {
    if e.is_bad_input() {
        anyhow::Error::new(InputError::new(e.to_string()))
    } else {
        anyhow::Error::new(e)
    }
}

fn eval_err(e: EvalError) -> anyhow::Error {
    if e.is_bad_input() {
        anyhow::Error::new(InputError::new(e.to_string()))
    } else {
        anyhow::Error::new(e)
    }
}
