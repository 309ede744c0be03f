//! `dsmstream demo`: ingest → align (motion averaging and the greedy MST
//! baseline) on a bundled generated collection with known truth, then prints
//! how far each result is from the truth, side by side.

use std::path::PathBuf;

use anyhow::Context;
use clap::Parser;
use dsmstream::poses::PosesFile;
use dsmstream::synth::output::Truth;

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
    println!("\nfiles in {}", work.display());
    Ok(())
}
