//! Command-line definitions: one file per command, each with its clap `Args`
//! and a `run` that builds the library configs and prints the command's output;
//! `common` (resource flags, store opening, progress bar, stdout) and
//! `icp_args` (the ICP flags of `pair` and `align`) are shared by them.

pub mod align;
pub mod check;
pub mod common;
pub mod demo;
pub mod eval;
pub mod fuse;
pub mod icp_args;
pub mod info;
pub mod ingest;
pub mod pair;
pub mod progress;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(
    name = "dsmstream",
    version,
    about = "Register large collections of overlapping DSMs out of core (DSM-ICP + motion averaging)"
)]
pub struct Cli {
    /// More log output (-v info, -vv debug, -vvv trace); RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    /// Only errors on stderr: no warnings, progress bars or per-DSM lines (the
    /// command's results on stdout stay).
    #[arg(short, long, global = true)]
    pub quiet: bool,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Convert GeoTIFF DSMs into a chunked Zarr v3 collection store (once).
    Ingest(ingest::Args),
    /// Print the catalog of a store.
    Info(info::Args),
    /// Register one DSM to another with DSM-ICP and print the transform.
    Pair(pair::Args),
    /// Register the whole collection: pairs, ICP, scene graph, motion averaging.
    Align(align::Args),
    /// Write the registered, fused mosaic as a Cloud-Optimized GeoTIFF.
    Fuse(fuse::Args),
    /// Accuracy report: rmse_tau before/after over every pair, and against a reference.
    Eval(eval::Args),
    /// Run ingest, align, fuse and eval on the bundled fixtures.
    Demo(demo::Args),
    /// Verify every DSM of a store (chunks, metadata, statistics); exit 1 if damaged.
    Check(check::Args),
}

pub fn run(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Ingest(a) => ingest::run(a),
        Command::Info(a) => info::run(a),
        Command::Pair(a) => pair::run(a),
        Command::Align(a) => align::run(a),
        Command::Fuse(a) => fuse::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Demo(a) => demo::run(a),
        Command::Check(a) => check::run(a),
    }
}

/// tracing to stderr through indicatif, so log lines and progress bars do not
/// tear; colour only when stderr is a terminal and NO_COLOR is unset or empty.
pub fn init_logging(verbose: u8, quiet: bool) {
    use tracing_subscriber::prelude::*;
    let default = match (quiet, verbose) {
        (true, _) => "error",
        (false, 0) => "warn",
        (false, 1) => "info",
        (false, 2) => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        tracing_subscriber::EnvFilter::new(format!("dsmstream={default},{default}"))
    });
    let indicatif_layer = tracing_indicatif::IndicatifLayer::new();
    let writer = indicatif_layer.get_stderr_writer();
    tracing_subscriber::registry()
        .with(filter)
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(writer)
                .with_ansi(use_colour())
                .with_target(false),
        )
        .with(indicatif_layer)
        .init();
}

/// ANSI colour on stderr: only for a terminal, and never with NO_COLOR set
/// to a non-empty value (https://no-color.org).
fn use_colour() -> bool {
    use std::io::IsTerminal;
    let no_color = std::env::var_os("NO_COLOR").is_some_and(|v| !v.is_empty());
    !no_color && std::io::stderr().is_terminal()
}
