//! Benchmark of the informed motion averaging (`align`'s solve when pairs carry
//! covariances: [`average_informed`] with the default options, as
//! `src/align/solve.rs` calls it) on synthetic tile grids of `width` x `width`
//! DSMs with 8-neighbour overlaps, anisotropic 6x6 covariances, 10 % flat
//! overlaps, 3 % unreliable pairs and 3 % gross outliers
//! ([`informed_grid`]). Prints one table row per width: seconds (and those of
//! the scalar averaging that starts the solve), CG iterations, dropped edges (and how many of them are true outliers), pose
//! errors against the truth (gauge free) and the largest node sigma.
//!
//! `--keep F` keeps that fraction of the pairs (0.36: the sparse, nearly
//! tree-like graph of a grid of 32 m tiles).
//!
//! Usage: bench_informed [--widths 32,64,100] [--seed 7] [--keep 1]

use dsmstream::averaging::synthetic::informed::{informed_grid, InformedGridSpec};
use dsmstream::averaging::synthetic::pose_errors;
use dsmstream::averaging::{average_informed, InformedOptions};
use dsmstream::graph::Components;
use std::time::Instant;

struct Config {
    widths: Vec<usize>,
    seed: u64,
    keep: f64,
}

fn parse_args() -> Result<Config, String> {
    let mut config = Config {
        widths: vec![32, 64, 100],
        seed: 7,
        keep: 1.0,
    };
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().ok_or(format!("{arg} needs a value"));
        match arg.as_str() {
            "--widths" => {
                config.widths = value()?
                    .split(',')
                    .map(|s| s.trim().parse().map_err(|_| format!("bad width {s}")))
                    .collect::<Result<_, _>>()?
            }
            "--seed" => config.seed = value()?.parse().map_err(|_| "bad --seed")?,
            "--keep" => config.keep = value()?.parse().map_err(|_| "bad --keep")?,
            _ => return Err(format!("unknown argument {arg}")),
        }
    }
    Ok(config)
}

fn main() {
    let config = match parse_args() {
        Ok(c) => c,
        Err(message) => {
            eprintln!("bench_informed: {message}");
            std::process::exit(2);
        }
    };
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    println!(
        "# informed averaging, 8-neighbour grid, 200 m tiles, 10 % flat, 3 % unreliable, 3 % outliers, {} of the pairs kept, seed {}",
        config.keep, config.seed
    );
    println!(
        "| nodes | edges | build s | solve s | of which scalar s | scalar rot steps / CG, trans CG | refine CG | dropped | of which outliers | outliers kept at full weight | rot err deg (rms) | trans err m (rms) | max shift sigma m |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &width in &config.widths {
        let built = Instant::now();
        let grid = informed_grid(&InformedGridSpec {
            keep_fraction: config.keep,
            ..InformedGridSpec::new(width, config.seed)
        });
        let build_s = built.elapsed().as_secs_f64();
        let started = Instant::now();
        let result =
            match average_informed(&grid.graph, &grid.information, &InformedOptions::default()) {
                Ok(r) => r,
                Err(e) => {
                    eprintln!("bench_informed: {e}");
                    std::process::exit(1);
                }
            };
        let solve_s = started.elapsed().as_secs_f64();
        let averaging = &result.averaging;
        let caught = grid
            .outliers
            .iter()
            .filter(|k| averaging.dropped_edges.binary_search(k).is_ok())
            .count();
        let kept = grid
            .outliers
            .iter()
            .filter(|k| {
                averaging.dropped_edges.binary_search(k).is_err()
                    && averaging.downweighted_edges.binary_search(k).is_err()
            })
            .count();
        let components = Components::new(grid.graph.n, grid.graph.edges.iter().map(|e| (e.i, e.j)));
        let errors = pose_errors(&averaging.poses, &grid.truth, &components);
        let max_sigma = result
            .sigma
            .iter()
            .flat_map(|s| s.shift_m)
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.2} | {} / {}, {} | {} | {} | {} / {} | {} | {:.5} | {:.4} | {:.3} |",
            grid.graph.n,
            grid.graph.edges.len(),
            build_s,
            solve_s,
            averaging.timings.total_s,
            averaging.rotation_iterations,
            averaging.rotation_cg_iterations,
            averaging.cg_iterations,
            result.refine_iterations,
            averaging.dropped_edges.len(),
            caught,
            grid.outliers.len(),
            kept,
            errors.rotation_rms_deg,
            errors.translation_rms_m,
            max_sigma,
        );
    }
}
