//! The `dsmstream` binary: parses the command line once, sets up logging, runs
//! one command and maps its outcome to the exit code (0 ok, 1 work failed,
//! 2 bad usage or bad input). A reader that closes stdout early (`| head`)
//! ends the command quietly with 0, as other Unix tools do.

mod cli;

use clap::Parser;
use dsmstream::InputError;

fn main() {
    dsmstream::cache::release_large_buffers_on_free();
    let args = cli::Cli::parse();
    cli::init_logging(args.verbose, args.quiet);
    match cli::run(args.command) {
        Ok(()) => {}
        Err(err) if cli::common::is_broken_pipe(&err) => {}
        Err(err) => {
            let code = if err
                .chain()
                .any(|e| e.downcast_ref::<InputError>().is_some())
            {
                2
            } else {
                1
            };
            eprintln!("error: {}", one_line(&err));
            std::process::exit(code);
        }
    }
}

/// The error chain on one line: "outer: inner: cause".
fn one_line(err: &anyhow::Error) -> String {
    let mut parts: Vec<String> = Vec::new();
    for cause in err.chain() {
        let s = cause.to_string();
        if !parts.iter().any(|p| p.contains(&s)) {
            parts.push(s);
        }
    }
    parts.join(": ").replace('\n', " ")
}
