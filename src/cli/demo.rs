//! `dsmstream demo`: ingest → align (motion averaging and the greedy MST
//! baseline) → fuse → eval on bundled collections with known truth, then prints
//! how far each result is from the truth, side by side: relative poses,
//! pairwise agreement, and the fused surface against the true surface (after
//! fixing the gauge, which no registration can observe, to the truth).
//! By default two collections: the generated city chain in
//! fixtures/synth/chain4, and six tiles cut from the real ttp2015 lidar DSM
//! with known shifts and rotations (the source DSM is then the truth).
//! Each collection ends with one conclusion line per part ([`conclusion`]),
//! the run with its time. The bundled fixtures are found from the current
//! directory, beside the binary (`target/release/` of a checkout) or in the
//! source tree it was built from, so the demo runs from any directory; the
//! work folder is removed at the end unless `--work` names it.

mod conclusion;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use dsmstream::cache::ChunkCache;
use dsmstream::eval::{evaluate, EvalConfig};
use dsmstream::fuse::{fuse, FuseConfig, FuseMethod, PoseSet};
use dsmstream::plots::write_eval_plots;
use dsmstream::poses::{inverse_rigid, rigid, to_local, to_world, PosesFile};
use dsmstream::store::ingest::NoProgress;
use dsmstream::store::{ingest, IngestOptions, StorageSettings, Store};
use dsmstream::synth::cut::{cut_collection, CutParams};
use dsmstream::synth::output::{epsg_crs, write_truth_grid, Truth};
use dsmstream::synth::tiles::Layout;
use dsmstream::InputError;
use nalgebra::{Matrix3, Matrix4, Vector3};

use super::align;
use super::align::{GraphArg, WeightsArg};
use super::common::{all_cores, emit_line, ResourceArgs};
use super::icp_args::IcpArgs;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder of GeoTIFF tiles with a truth.json (made by `dsmgen tiles` or
    /// `dsmgen cut`); default: fixtures/synth/chain4, then a cut of
    /// fixtures/real/ttp2015/ttp_dsm_source.tif.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Working folder, kept afterwards (default: a new folder under the system
    /// temp dir, removed at the end).
    #[arg(long)]
    pub work: Option<PathBuf>,
}

const SYNTH_CHAIN: &str = "fixtures/synth/chain4";
const TTP_SOURCE: &str = "fixtures/real/ttp2015/ttp_dsm_source.tif";

/// A bundled fixture: relative to the current directory, to a folder above
/// the binary (a checkout's `target/release/dsmstream`), or to the source tree
/// the binary was built from; None when none has it.
fn fixture(relative: &str) -> Option<PathBuf> {
    let exe = std::env::current_exe().ok();
    let beside_binary = exe
        .iter()
        .flat_map(|e| e.ancestors().skip(1).take(4))
        .map(|dir| dir.join(relative));
    std::iter::once(PathBuf::from(relative))
        .chain(beside_binary)
        .chain(std::iter::once(
            Path::new(env!("CARGO_MANIFEST_DIR")).join(relative),
        ))
        .find(|p| p.exists())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let work = args.work.clone().unwrap_or_else(|| {
        std::env::temp_dir().join(format!("dsmstream-demo-{}", std::process::id()))
    });
    std::fs::create_dir_all(&work).with_context(|| format!("creating {}", work.display()))?;
    let started = Instant::now();
    let result = run_in(&args, &work);
    if args.work.is_none() {
        // the temporary folder goes, whatever happened; --work keeps it
        let _ = std::fs::remove_dir_all(&work);
    } else if result.is_ok() {
        emit_line(&format!("\nfiles in {}", work.display()))?;
    }
    result?;
    emit_line(&format!(
        "\ndemo finished in {:.1} s",
        started.elapsed().as_secs_f64()
    ))?;
    Ok(())
}

fn run_in(args: &Args, work: &Path) -> anyhow::Result<()> {
    if let Some(data) = &args.data {
        return run_collection(data, work);
    }
    let found = |relative: &str| {
        fixture(relative).ok_or_else(|| {
            InputError::new(format!(
                "{relative}: bundled fixture not found here, above the binary or in the source tree it was built from (run from the repository, or give --data DIR)"
            ))
        })
    };
    let (chain, ttp) = (found(SYNTH_CHAIN)?, found(TTP_SOURCE)?);
    emit_line(&format!("=== 1. generated city tiles ({SYNTH_CHAIN})"))?;
    run_collection(&chain, &work.join("synth"))?;
    let real = work.join("ttp2015");
    let tiles = real.join("tiles");
    emit_line(&format!(
        "\n=== 2. real terrain: {TTP_SOURCE} cut into a 3 x 2 grid of 300 px tiles, shifted <= 3 m, rotated <= 0.02 deg"
    ))?;
    let params = CutParams {
        layout: Layout::Grid,
        rows: 3,
        cols: 2,
        size_px: 300,
        overlap: 0.6,
        anchor_first: true,
        ..CutParams::default()
    };
    cut_collection(&ttp, &params, &tiles, 256)
        .map_err(|e| anyhow::Error::new(InputError::new(e.to_string())))?;
    run_collection(&tiles, &real)
}

/// ingest → align full/mst → fuse → eval of one folder with a truth.json.
fn run_collection(data_dir: &Path, work: &Path) -> anyhow::Result<()> {
    std::fs::create_dir_all(work).with_context(|| format!("creating {}", work.display()))?;
    let store = work.join("collection.zarr");
    let options = IngestOptions {
        storage: StorageSettings::default(),
        force: false,
        target: None,
    };
    let ingested = ingest(&[data_dir.to_path_buf()], &store, &options, &NoProgress)
        .map_err(|e| super::common::classify(e, |e| e.is_bad_input()))?;
    let mut conclusions = vec![conclusion::ingest_line(&ingested.outcomes)];
    let mut rows = Vec::new();
    for (graph, kind) in [("full", GraphArg::Full), ("mst", GraphArg::Mst)] {
        let out = work.join(format!("poses_{graph}.json"));
        emit_line(&format!("\n== align --graph {graph}"))?;
        align::run(align::Args {
            store: store.clone(),
            out: out.clone(),
            resources: ResourceArgs::default(),
            graph: kind,
            weights: WeightsArg::Information,
            min_overlap: dsmstream::pipeline::DEFAULT_MIN_OVERLAP,
            min_overlap_px: dsmstream::pipeline::DEFAULT_MIN_OVERLAP_PX,
            anchor: None,
            resume: false,
            fresh: true,
            shard: None,
            merge: false,
            icp: IcpArgs::default(),
            inputs: Default::default(),
        })?;
        rows.push((graph, PosesFile::read(&out)?));
    }
    let truth_path = data_dir.join("truth.json");
    let truth =
        Truth::load(&truth_path).with_context(|| format!("reading {}", truth_path.display()))?;
    emit_line(
        "\nagreement with the truth (relative corrections of every pair, at the tile centres):",
    )?;
    emit_line(&format!(
        "{:<8} {:>14} {:>14} {:>16}",
        "graph", "mean error m", "worst error m", "worst angle deg"
    ))?;
    let mut errors = Vec::new();
    for (graph, poses) in &rows {
        let e = truth.pairwise_error(poses);
        let (mean, worst, worst_deg) = (e.mean_m, e.worst_m, e.worst_deg);
        emit_line(&format!(
            "{graph:<8} {mean:>14.4} {worst:>14.4} {worst_deg:>16.5}"
        ))?;
        errors.push(e);
    }
    let pairs = rows[0].1.edges.len();
    conclusions.push(conclusion::align_line(pairs, &errors[0], &errors[1]));
    conclusions.extend(fuse_and_eval(data_dir, work, &store, &truth, &rows)?);
    emit_line(&format!("\nconclusion ({}):", data_dir.display()))?;
    for line in &conclusions {
        emit_line(&format!("  {line}"))?;
    }
    Ok(())
}

/// Fuse the motion-averaging result, evaluate it against the true surface with
/// plots, and print none / mst / full side by side; the fuse and eval
/// conclusion lines.
fn fuse_and_eval(
    data_dir: &Path,
    work: &Path,
    store_path: &Path,
    truth: &Truth,
    rows: &[(&str, PosesFile)],
) -> anyhow::Result<[String; 2]> {
    // The true surface: rendered from the generator's parameters, or the
    // source DSM a cut was taken from.
    let truth_tif = match (truth.synthetic(), &truth.cut) {
        (Some((generation, surface)), _) => {
            let path = work.join("truth.tif");
            write_truth_grid(
                surface,
                truth.bbox(),
                truth.gsd,
                &epsg_crs(generation.epsg),
                &path,
            )
            .with_context(|| format!("writing {}", path.display()))?;
            path
        }
        (None, Some(cut)) => cut.source.clone(),
        (None, None) => {
            return Err(InputError::new(format!(
                "{}: truth.json names neither a generated surface nor a cut source",
                data_dir.display()
            ))
            .into())
        }
    };
    let store = Store::open(store_path)?;
    let mut gauged = Vec::new();
    for (graph, poses) in rows {
        let path = work.join(format!("poses_{graph}_truth_gauge.json"));
        truth_gauge(poses, truth).write(&path)?;
        gauged.push((*graph, path));
    }
    let fused = {
        let config = FuseConfig {
            method: FuseMethod::Median,
            threads: all_cores(),
            ..Default::default()
        };
        let poses = PoseSet::from_file(&store, &work.join("poses_full.json"))?;
        let cache = ResourceArgs::default().cache();
        let out = work.join("fused_full.tif");
        fuse(&store, &cache, &poses, &config, &out, &|_, _| {})?
    };
    let eval_defaults = EvalConfig::default();
    let cache = ChunkCache::new(64 << 20);
    let config = EvalConfig {
        threads: all_cores(),
        ..eval_defaults
    };
    emit_line(&format!(
        "\nside by side ({}; tau = {} m; fused = median of corrected DSMs, gauge fixed to the truth):",
        data_dir.display(),
        config.tau_m
    ))?;
    emit_line(&format!(
        "{:<8} {:>18} {:>14} {:>22} {:>16} {:>16}",
        "poses",
        "pairs rmse_tau m",
        "pairs NMAD m",
        "fused-truth rmse_tau m",
        "fused-truth NMAD",
        "fused-truth med"
    ))?;
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
    let truth_json = data_dir.join("truth.json");
    sets.push((
        "truth",
        Some(PoseSet::from_parsed(&store, &truth_json, truth_file)?),
    ));
    let plots = work.join("plots");
    let mut fused_rmse = std::collections::HashMap::new();
    for (name, poses) in &sets {
        let (report, plot_data) =
            evaluate(&store, &cache, poses.as_ref(), Some(&truth_tif), &config)?;
        let pairs = report.mean_after.or(report.mean_before).unwrap_or_default();
        let r = report.reference.as_ref().expect("reference given");
        let f = r.after.unwrap_or(r.before);
        emit_line(&format!(
            "{name:<8} {:>18.3} {:>14.3} {:>22.3} {:>16.3} {:>16.3}",
            pairs.rmse_tau_m, pairs.nmad_m, f.rmse_tau_m, f.nmad_m, f.median_m
        ))?;
        fused_rmse.insert(*name, f.rmse_tau_m);
        if *name == "full" {
            // the pictures `eval --plots` draws, for the gauged full-graph poses
            write_eval_plots(&plots, &store, poses.as_ref(), &report, &plot_data)?;
        }
    }
    emit_line(&format!(
        "plots of the full-graph result (scene graph, histograms, difference map) in {}",
        plots.display()
    ))?;
    Ok([
        conclusion::fuse_line(&fused),
        conclusion::eval_line(fused_rmse["full"], fused_rmse["none"], fused_rmse["truth"]),
    ])
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
