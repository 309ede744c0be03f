//! `dsmstream demo`: ingest → align (motion averaging and the greedy MST
//! baseline) → fuse → eval on a bundled generated collection with known truth,
//! then prints how far each result is from the truth, side by side: relative
//! poses, pairwise agreement, and the fused surface against the true surface
//! (after fixing the gauge, which no registration can observe, to the truth).

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Parser;
use dsmstream::cache::ChunkCache;
use dsmstream::eval::{evaluate, EvalConfig};
use dsmstream::fuse::PoseSet;
use dsmstream::poses::{inverse_rigid, rigid, to_local, to_world, PosesFile};
use dsmstream::store::Store;
use dsmstream::synth::output::{epsg_crs, write_truth_grid, Truth};
use dsmstream::InputError;
use nalgebra::{Matrix3, Matrix4, Vector3};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder of GeoTIFF tiles with a truth.json (made by dsmgen).
    #[arg(long, default_value = "fixtures/synth/chain4")]
    pub data: PathBuf,
    /// Working folder (default: a new folder under the system temp dir).
    #[arg(long)]
    pub work: Option<PathBuf>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let work = args.work.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("dsmstream-demo-{}", std::process::id()))
    });
    std::fs::create_dir_all(&work).with_context(|| format!("creating {}", work.display()))?;
    let store = work.join("collection.zarr");
    let data = args.data.display().to_string();
    let store_s = store.display().to_string();
    super::run(
        super::Cli::try_parse_from(["dsmstream", "ingest", &data, "--store", &store_s])?.command,
    )?;
    let mut rows = Vec::new();
    for graph in ["full", "mst"] {
        let out = work.join(format!("poses_{graph}.json"));
        let out_s = out.display().to_string();
        println!("\n== align --graph {graph}");
        super::run(
            super::Cli::try_parse_from([
                "dsmstream",
                "align",
                &store_s,
                "--out",
                &out_s,
                "--graph",
                graph,
            ])?
            .command,
        )?;
        rows.push((graph, PosesFile::read(&out)?));
    }
    let truth_path = args.data.join("truth.json");
    let truth =
        Truth::load(&truth_path).with_context(|| format!("reading {}", truth_path.display()))?;
    println!(
        "\nagreement with the truth (relative corrections of every pair, at the tile centres):"
    );
    println!(
        "{:<8} {:>14} {:>14} {:>16}",
        "graph", "mean error m", "worst error m", "worst angle deg"
    );
    for (graph, poses) in &rows {
        let e = truth.pairwise_error(poses);
        let (mean, worst, worst_deg) = (e.mean_m, e.worst_m, e.worst_deg);
        println!("{graph:<8} {mean:>14.4} {worst:>14.4} {worst_deg:>16.5}");
    }
    fuse_and_eval(&args, &work, &store, &truth, &rows)?;
    println!("\nfiles in {}", work.display());
    Ok(())
}

/// Fuse the motion-averaging result, evaluate it against the true surface with
/// plots, and print none / mst / full side by side.
fn fuse_and_eval(
    args: &Args,
    work: &Path,
    store_path: &Path,
    truth: &Truth,
    rows: &[(&str, PosesFile)],
) -> anyhow::Result<()> {
    let truth_tif = work.join("truth.tif");
    let Some((generation, surface)) = truth.synthetic() else {
        return Err(InputError::new(format!(
            "{}: truth.json has no synthetic surface (made by dsmgen cut?): the demo needs dsmgen tiles",
            args.data.display()
        ))
        .into());
    };
    write_truth_grid(
        surface,
        truth.bbox(),
        truth.gsd,
        &epsg_crs(generation.epsg),
        &truth_tif,
    )
    .with_context(|| format!("writing {}", truth_tif.display()))?;
    let store = Store::open(store_path)?;
    let mut gauged = Vec::new();
    for (graph, poses) in rows {
        let path = work.join(format!("poses_{graph}_truth_gauge.json"));
        truth_gauge(poses, truth).write(&path)?;
        gauged.push((*graph, path));
    }
    let s = |p: &Path| p.display().to_string();
    let fused = work.join("fused_full.tif");
    println!("\n== fuse --poses poses_full.json");
    super::run(
        super::Cli::try_parse_from([
            "dsmstream",
            "fuse",
            &s(store_path),
            "--poses",
            &s(&work.join("poses_full.json")),
            "--out",
            &s(&fused),
        ])?
        .command,
    )?;
    println!("\n== eval --poses poses_full_truth_gauge.json --reference truth.tif --plots plots");
    super::run(
        super::Cli::try_parse_from([
            "dsmstream",
            "eval",
            &s(store_path),
            "--poses",
            &s(&gauged[0].1),
            "--reference",
            &s(&truth_tif),
            "--plots",
            &s(&work.join("plots")),
        ])?
        .command,
    )?;
    let cache = ChunkCache::new(64 << 20);
    let config = EvalConfig {
        threads: super::threads_or_all(None),
        ..Default::default()
    };
    println!(
        "\nside by side ({}; tau = {} m; fused = median of corrected DSMs, gauge fixed to the truth):",
        args.data.display(),
        config.tau_m
    );
    println!(
        "{:<8} {:>18} {:>14} {:>22} {:>16} {:>16}",
        "poses",
        "pairs rmse_tau m",
        "pairs NMAD m",
        "fused-truth rmse_tau m",
        "fused-truth NMAD",
        "fused-truth med"
    );
    let mut sets: Vec<(&str, Option<PoseSet>)> = vec![("none", None)];
    for (graph, path) in &gauged {
        sets.push((graph, Some(PoseSet::from_file(&store, path)?)));
    }
    // the truth's own matrices: the best any registration can do on this data
    let mut truth_file = rows[0].1.clone();
    truth_file.edges.clear();
    for p in &mut truth_file.poses {
        if let Some(t) = truth.tiles.iter().find(|t| t.id == p.id) {
            p.matrix_world = Matrix4::from_fn(|r, c| t.matrix_world[r][c]);
        }
    }
    let truth_json = args.data.join("truth.json");
    sets.push((
        "truth",
        Some(PoseSet::from_parsed(&store, &truth_json, truth_file)?),
    ));
    for (name, poses) in &sets {
        let (report, _) = evaluate(&store, &cache, poses.as_ref(), Some(&truth_tif), &config)?;
        let pairs = report.mean_after.or(report.mean_before).unwrap_or_default();
        let r = report.reference.as_ref().expect("reference given");
        let f = r.after.unwrap_or(r.before);
        println!(
            "{name:<8} {:>18.3} {:>14.3} {:>22.3} {:>16.3} {:>16.3}",
            pairs.rmse_tau_m, pairs.nmad_m, f.rmse_tau_m, f.nmad_m, f.median_m
        );
    }
    Ok(())
}

/// `poses` moved by the one rigid transform G that best maps them onto the
/// truth (G = mean over tiles of M_true M_est^-1, in a local frame at the data,
/// rotation projected onto SO(3)): the gauge of a registration is arbitrary.
fn truth_gauge(poses: &PosesFile, truth: &Truth) -> PosesFile {
    let m = |rows: &[[f64; 4]; 4]| Matrix4::from_fn(|r, c| rows[r][c]);
    let b = truth.bbox();
    let origin = Vector3::new((b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0, 0.0);
    let (mut r_sum, mut t_sum, mut n) = (Matrix3::zeros(), Vector3::zeros(), 0.0);
    for tile in &truth.tiles {
        if let Some(est) = poses.pose(&tile.id) {
            let g = to_local(&(m(&tile.matrix_world) * inverse_rigid(est)), &origin);
            r_sum += rigid::rotation(&g);
            t_sum += rigid::translation(&g);
            n += 1.0;
        }
    }
    let g_local = rigid::from_parts(&rigid::project_to_so3(&(r_sum / n)), &(t_sum / n));
    let g = to_world(&g_local, &origin);
    let mut out = poses.clone();
    for p in &mut out.poses {
        p.matrix_world = g * p.matrix_world;
    }
    out
}
