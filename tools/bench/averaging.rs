//! Benchmark of motion averaging on synthetic pose graphs (10^3 .. 10^6 nodes, about
//! 6 edges per node, noisy relative poses): prints one table row per size with build,
//! rotation, translation and total seconds, peak RSS, and the pose errors against the
//! truth (gauge free), beside the error of greedy spanning-tree chaining.
//!
//! Usage: bench_averaging [--sizes 1000,10000,100000,1000000] [--topology random|grid]
//!                        [--noise-m 0.02] [--noise-deg 0.002] [--no-robust] [--no-mst]
//!                        [--jacobi] [--information SPREAD]
//!
//! `--information SPREAD`: each edge's noise scaled by a factor log-uniform in
//! [1/SPREAD, SPREAD], and information weights (separate rotation / translation
//! Laplacians) instead of the paper's.

use dsmstream::averaging::synthetic::{generate, pose_errors, SyntheticSpec, Topology};
use dsmstream::averaging::{average, AveragingOptions, Preconditioner};
use dsmstream::graph::{chain_poses, information_weights, mst};
use std::time::Instant;

struct Config {
    sizes: Vec<usize>,
    topology: String,
    noise_m: f64,
    noise_deg: f64,
    robust: bool,
    with_mst: bool,
    preconditioner: Preconditioner,
    /// Some(spread): heteroscedastic noise and information weights.
    information: Option<f64>,
}

fn parse_args() -> Result<Config, String> {
    let mut config = Config {
        sizes: vec![1_000, 10_000, 100_000, 1_000_000],
        topology: "random".into(),
        noise_m: 0.02,
        noise_deg: 0.002,
        robust: true,
        with_mst: true,
        preconditioner: Preconditioner::Multigrid,
        information: None,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().ok_or(format!("{arg} needs a value"));
        match arg.as_str() {
            "--sizes" => {
                config.sizes = value()?
                    .split(',')
                    .map(|s| s.trim().parse().map_err(|_| format!("bad size {s}")))
                    .collect::<Result<_, _>>()?
            }
            "--topology" => config.topology = value()?,
            "--noise-m" => config.noise_m = value()?.parse().map_err(|_| "bad --noise-m")?,
            "--noise-deg" => config.noise_deg = value()?.parse().map_err(|_| "bad --noise-deg")?,
            "--no-robust" => config.robust = false,
            "--no-mst" => config.with_mst = false,
            "--jacobi" => config.preconditioner = Preconditioner::Jacobi,
            "--information" => {
                let spread: f64 = value()?.parse().map_err(|_| "bad --information")?;
                if spread.is_nan() || spread < 1.0 {
                    return Err("--information needs a spread >= 1".into());
                }
                config.information = Some(spread);
            }
            _ => return Err(format!("unknown argument {arg}")),
        }
    }
    if !matches!(config.topology.as_str(), "random" | "grid") {
        return Err(format!(
            "--topology must be random or grid, not {}",
            config.topology
        ));
    }
    Ok(config)
}

/// A size line of /proc/self/status ("VmHWM:", "VmRSS:") in MiB.
fn status_mb(key: &str) -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// Peak resident set size in MiB since the last reset.
fn peak_rss_mb() -> f64 {
    status_mb("VmHWM:")
}

/// Resident set size in MiB now (after generation: the input graph).
fn rss_mb() -> f64 {
    status_mb("VmRSS:")
}

/// Resets VmHWM to the current RSS (Linux: "5" > /proc/self/clear_refs).
fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

fn main() {
    let config = match parse_args() {
        Ok(c) => c,
        Err(message) => {
            eprintln!("bench_averaging: {message}");
            std::process::exit(2);
        }
    };
    println!(
        "# motion averaging, topology {}, noise {} m / {} deg per axis, robust {}, preconditioner {:?}, weights {}",
        config.topology,
        config.noise_m,
        config.noise_deg,
        config.robust,
        config.preconditioner,
        match config.information {
            Some(spread) => format!("information (noise spread {spread}x)"),
            None => "paper".into(),
        }
    );
    println!(
        "| nodes | edges | build s | setup s | rotation s | translation s | total s | peak RSS MB | of which graph MB | rot err deg (rms) | trans err m (rms) | MST trans err m (rms) | rot steps / CG | trans CG |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &n in &config.sizes {
        reset_peak_rss();
        let topology = match config.topology.as_str() {
            "grid" => Topology::Grid {
                width: (n as f64).sqrt().round().max(1.0) as usize,
            },
            _ => Topology::Random { edges_per_node: 6 },
        };
        let built = Instant::now();
        let mut synthetic = generate(&SyntheticSpec {
            noise_scale_spread: config.information.unwrap_or(1.0),
            ..SyntheticSpec::noisy(n, topology, 42, config.noise_deg, config.noise_m)
        });
        if config.information.is_some() {
            if let Err(e) = information_weights(&mut synthetic.graph.edges) {
                eprintln!("bench_averaging: {e}");
                std::process::exit(1);
            }
        }
        let build_s = built.elapsed().as_secs_f64();
        let graph_mb = rss_mb();
        let options = AveragingOptions {
            robust: config.robust,
            preconditioner: config.preconditioner,
            ..Default::default()
        };
        let result = match average(&synthetic.graph, &options) {
            Ok(r) => r,
            Err(e) => {
                eprintln!("bench_averaging: {e}");
                std::process::exit(1);
            }
        };
        let peak_mb = peak_rss_mb();
        let components = synthetic.graph.components();
        let errors = pose_errors(&result.poses, &synthetic.truth, &components);
        let mst_err = if config.with_mst {
            let chained =
                chain_poses(&synthetic.graph, &mst(&synthetic.graph), 0).expect("root 0 exists");
            format!(
                "{:.4}",
                pose_errors(&chained, &synthetic.truth, &components).translation_rms_m
            )
        } else {
            "-".into()
        };
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.0} | {:.0} | {:.5} | {:.4} | {} | {} / {} | {} |{}",
            n,
            synthetic.graph.edges.len(),
            build_s,
            result.timings.setup_s,
            result.timings.rotation_s,
            result.timings.translation_s,
            result.timings.total_s,
            peak_mb,
            graph_mb,
            errors.rotation_rms_deg,
            errors.translation_rms_m,
            mst_err,
            result.rotation_iterations,
            result.rotation_cg_iterations,
            result.cg_iterations,
            if result.converged { "" } else { " not converged" }
        );
    }
}
