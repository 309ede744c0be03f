//! `dsmstream demo`: ingest → align (motion averaging and the greedy MST
//! baseline) on a bundled generated collection with known truth, then prints
//! how far each result is from the truth, side by side.

use std::path::PathBuf;

use anyhow::Context;
use clap::Parser;
use dsmstream::poses::PosesFile;
use dsmstream::synth::output::Truth;
use nalgebra::{Matrix4, Vector4};

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
        let (mean, worst, worst_deg) = pairwise_error(poses, &truth);
        println!("{graph:<8} {mean:>14.4} {worst:>14.4} {worst_deg:>16.5}");
    }
    println!("\nfiles in {}", work.display());
    Ok(())
}

/// Disagreement of M_i^-1 M_j with the truth's, over all pairs of tiles.
fn pairwise_error(poses: &PosesFile, truth: &Truth) -> (f64, f64, f64) {
    let m = |rows: &[[f64; 4]; 4]| Matrix4::from_fn(|r, c| rows[r][c]);
    let (mut sum, mut n, mut worst, mut worst_deg) = (0.0, 0, 0.0f64, 0.0f64);
    for (a, ta) in truth.tiles.iter().enumerate() {
        for tb in &truth.tiles[a + 1..] {
            let (Some(ea), Some(eb)) = (poses.pose(&ta.id), poses.pose(&tb.id)) else {
                continue;
            };
            let rel_est = ea.try_inverse().unwrap_or_else(Matrix4::identity) * eb;
            let rel_true = m(&ta.matrix_world)
                .try_inverse()
                .unwrap_or_else(Matrix4::identity)
                * m(&tb.matrix_world);
            let d = rel_true.try_inverse().unwrap_or_else(Matrix4::identity) * rel_est;
            let g = tb.geotransform;
            let centre = Vector4::new(
                g[0] + g[1] * tb.width as f64 / 2.0,
                g[3] + g[5] * tb.height as f64 / 2.0,
                200.0,
                1.0,
            );
            let disp = (d * centre - centre).xyz().norm();
            let trace = d[(0, 0)] + d[(1, 1)] + d[(2, 2)];
            let angle = ((trace - 1.0) / 2.0).clamp(-1.0, 1.0).acos().to_degrees();
            sum += disp;
            n += 1;
            worst = worst.max(disp);
            worst_deg = worst_deg.max(angle);
        }
    }
    (sum / n.max(1) as f64, worst, worst_deg)
}
