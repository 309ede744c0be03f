//! `bench_nn run`: generates the inputs with `dsmgen big`, ingests them, runs
//! each method in its own process per reference size (`bench_nn dsm`,
//! `bench_nn kdtree`) and records the table, CSV and Markdown.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context};
use serde_json::{json, Value};

use crate::report::{self, write_csv, write_markdown, Row};
use crate::RunArgs;

/// The moving DSM: 700 x 700 px, 1 m inside the references' top-left corner,
/// written with a known shift (the truth ICP should recover).
const MOVING_SHIFT_M: [f64; 3] = [1.3, -0.7, 0.9];

pub fn run(a: RunArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&a.work)?;
    let exe_dir = std::env::current_exe()?
        .parent()
        .context("executable directory")?
        .to_path_buf();
    let moving = a.work.join("moving.tif");
    let mut commands = Vec::new();
    let s = MOVING_SHIFT_M.map(|v| v.to_string());
    let mut args = vec!["big", "--size", "700", "--origin", "500001", "4799999"];
    args.extend(["--pixel-seed", "2", "--shift-m", &s[0], &s[1], &s[2]]);
    args.extend(["--out", path_str(&moving)?]);
    commands.push(format!("dsmgen {}", args.join(" ")));
    if !moving.exists() {
        tool(&exe_dir.join("dsmgen"), &args)?;
    }
    let mut rows = Vec::new();
    for &size in &a.sizes {
        let (store, prep) = prepare(&exe_dir, &a.work, &moving, size, &mut commands)?;
        let mut side = |method: &str| -> anyhow::Result<Value> {
            let id = format!("ref_{size}");
            let samples = a.samples.to_string();
            let cache = a.cache_mb.to_string();
            let args = [
                method,
                path_str(&store)?,
                "--reference",
                &id,
                "--samples",
                &samples,
                "--cache-mb",
                &cache,
            ];
            eprintln!("bench_nn: {method} on {size}^2 ...");
            commands.push(format!("bench_nn {}", args.join(" ")));
            let out = std::process::Command::new(std::env::current_exe()?)
                .args(args)
                .output()?;
            if !out.status.success() {
                let stderr = String::from_utf8_lossy(&out.stderr);
                let tail: String = stderr.lines().rev().take(3).collect::<Vec<_>>().join(" | ");
                return Ok(json!({"method": method, "failed": format!("{} {tail}", out.status)}));
            }
            Ok(serde_json::from_slice(&out.stdout)?)
        };
        let dsm = side("dsm")?;
        let kd = if a.kd_max_pixels > 0 && size * size > a.kd_max_pixels {
            json!({"method": "kdtree", "failed": "skipped (--kd-max-pixels)"})
        } else {
            side("kdtree")?
        };
        let row = Row::new(size, prep, dsm, kd, MOVING_SHIFT_M);
        eprintln!("{}", row.table_line());
        rows.push(row);
        write_csv(&a.csv, &rows)?;
    }
    println!("{}", report::table(&rows));
    let command = std::env::args().collect::<Vec<_>>().join(" ");
    write_markdown(&a.markdown, &rows, &command, &commands)?;
    Ok(())
}

/// Generation and ingest times of one size (not part of either method).
#[derive(Clone, Copy, Debug)]
pub struct Prep {
    pub generate_s: f64,
    pub ingest_s: f64,
}

/// `dsmgen big` the reference and ingest it with the moving DSM into its own store.
fn prepare(
    exe_dir: &Path,
    work: &Path,
    moving: &Path,
    size: u64,
    commands: &mut Vec<String>,
) -> anyhow::Result<(PathBuf, Prep)> {
    let reference = work.join(format!("ref_{size}.tif"));
    let store = work.join(format!("s_{size}.zarr"));
    let mut prep = Prep {
        generate_s: f64::NAN,
        ingest_s: f64::NAN,
    };
    let size_s = size.to_string();
    let generate = ["big", "--size", &size_s, "--out", path_str(&reference)?];
    let ingest = [
        "ingest",
        path_str(&reference)?,
        path_str(moving)?,
        "--store",
        path_str(&store)?,
    ];
    commands.push(format!("dsmgen {}", generate.join(" ")));
    commands.push(format!("dsmstream {}", ingest.join(" ")));
    if !reference.exists() {
        let t = Instant::now();
        tool(&exe_dir.join("dsmgen"), &generate)?;
        prep.generate_s = t.elapsed().as_secs_f64();
    }
    if !store.join("zarr.json").exists() {
        let t = Instant::now();
        tool(&exe_dir.join("dsmstream"), &ingest)?;
        prep.ingest_s = t.elapsed().as_secs_f64();
    }
    Ok((store, prep))
}

fn tool(exe: &Path, args: &[&str]) -> anyhow::Result<()> {
    eprintln!("bench_nn: {} {}", exe.display(), args.join(" "));
    let status = std::process::Command::new(exe).args(args).status()?;
    if !status.success() {
        bail!("{} {} failed: {status}", exe.display(), args.join(" "));
    }
    Ok(())
}

fn path_str(p: &Path) -> anyhow::Result<&str> {
    p.to_str()
        .with_context(|| format!("{}: not UTF-8", p.display()))
}
