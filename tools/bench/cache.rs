//! `bench_cache`: dsmstream's chunk cache against zarrs' own decoded-chunk LRU
//! cache, on the same store, windows and byte budgets, side by side in one run.
//!
//! The store is one DSM (`dsmgen big`, ingested with `--chunk`). Each workload
//! is a fixed list of windows at seeded random positions inside the raster:
//! - `large`: 600 x 700 px windows (several chunks each, the shape of a fuse
//!   tile or an overview scan);
//! - `nn`: 9 x 9 px windows (the window of one exact grid-NN query), visited in
//!   row-major chunk order as the ICP visits its samples.
//!
//! Each workload runs at two budgets: `fits` (the whole array fits, measured
//! after one warm-up pass, so every read hits) and `tight` (64 chunks, so
//! reads miss and decode). dsmstream reads through [`StoreGrid::read_window`]
//! over one shared [`ChunkCache`]; zarrs through
//! `ChunkCacheDecodedLruSizeLimit::retrieve_array_subset`. Both run on a rayon
//! pool of `--threads`, each window a task. The checksum column proves both
//! return the same values. Times are medians of `--repeats` passes.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{bail, Context};
use clap::Parser;
use dsmstream::cache::ChunkCache;
use dsmstream::rng::SplitMix64;
use dsmstream::store::{Store, StoreGrid};
use rayon::prelude::*;
use zarrs::array::chunk_cache::{ChunkCache as _, ChunkCacheDecodedLruSizeLimit};
use zarrs::array::{Array, ArraySubset, CodecOptions};
use zarrs::filesystem::FilesystemStore;
use zarrs::storage::ReadableStorageTraits;

#[derive(Parser)]
#[command(
    name = "bench_cache",
    about = "dsmstream chunk cache vs zarrs' LRU cache"
)]
struct Args {
    /// Working folder (the generated DSM and its store are kept for reruns).
    #[arg(long, default_value = "/tmp/bench_cache")]
    work: PathBuf,
    /// Raster side in pixels.
    #[arg(long, default_value_t = 4096)]
    size: u32,
    /// Chunk side in pixels.
    #[arg(long, default_value_t = 256)]
    chunk: u32,
    /// Windows of the `large` workload.
    #[arg(long, default_value_t = 2000)]
    large: usize,
    /// Windows of the `nn` workload.
    #[arg(long, default_value_t = 200_000)]
    nn: usize,
    /// Thread counts to run.
    #[arg(long, num_args = 1.., default_values_t = [1, 2])]
    threads: Vec<usize>,
    #[arg(long, default_value_t = 3)]
    repeats: usize,
    /// Run only one side (for profiling): dsmstream or zarrs.
    #[arg(long)]
    only: Option<String>,
}

/// One window: top-left (col, row) and size.
#[derive(Clone, Copy)]
struct Window {
    col: u64,
    row: u64,
    w: u64,
    h: u64,
}

fn windows(n: usize, w: u64, h: u64, size: u64, chunk: u64, seed: u64) -> Vec<Window> {
    let mut rng = SplitMix64::new(seed);
    let mut out: Vec<Window> = (0..n)
        .map(|_| Window {
            col: rng.next_u64() % (size - w),
            row: rng.next_u64() % (size - h),
            w,
            h,
        })
        .collect();
    if w < chunk {
        // chunk order, as the ICP visits its samples
        out.sort_by_key(|v| (v.row / chunk, v.col / chunk, v.row, v.col));
    }
    out
}

/// Sum of the finite values (identical for both readers if they agree).
fn checksum(values: &[f32]) -> f64 {
    values
        .iter()
        .filter(|v| v.is_finite())
        .map(|&v| v as f64)
        .sum()
}

fn ours(store: &Store, cache: &ChunkCache, wins: &[Window]) -> f64 {
    wins.par_chunks(64)
        .map_init(
            || StoreGrid::new(store, cache, 0, 0).expect("level 0"),
            |grid, part| {
                part.iter()
                    .map(|v| {
                        let data = grid.read_window(
                            v.col as i64,
                            v.row as i64,
                            v.w as usize,
                            v.h as usize,
                        );
                        checksum(&data)
                    })
                    .sum::<f64>()
            },
        )
        .sum()
}

fn zarrs_cached(cache: &ChunkCacheDecodedLruSizeLimit, wins: &[Window]) -> f64 {
    let options = CodecOptions::default();
    wins.par_chunks(64)
        .map(|part| {
            part.iter()
                .map(|v| {
                    let subset =
                        ArraySubset::new_with_ranges(&[v.row..v.row + v.h, v.col..v.col + v.w]);
                    let data: Vec<f32> = cache
                        .retrieve_array_subset(&subset, &options)
                        .expect("zarrs read");
                    checksum(&data)
                })
                .sum::<f64>()
        })
        .sum()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn prepare(a: &Args) -> anyhow::Result<PathBuf> {
    std::fs::create_dir_all(&a.work)?;
    let exe = std::env::current_exe()?;
    let bin = exe.parent().context("executable directory")?;
    let tif = a.work.join(format!("big_{}.tif", a.size));
    let store = a.work.join(format!("big_{}_c{}.zarr", a.size, a.chunk));
    let run = |tool: &str, args: &[&str]| -> anyhow::Result<()> {
        let status = std::process::Command::new(bin.join(tool))
            .args(args)
            .status()
            .with_context(|| format!("running {tool} (build it: cargo build --release --bins)"))?;
        if !status.success() {
            bail!("{tool} {args:?} failed: {status}");
        }
        Ok(())
    };
    if !tif.exists() {
        run(
            "dsmgen",
            &["big", "--size", &a.size.to_string(), "--out", path(&tif)?],
        )?;
    }
    if !store.exists() {
        let chunk = a.chunk.to_string();
        run(
            "dsmstream",
            &[
                "ingest",
                path(&tif)?,
                "--store",
                path(&store)?,
                "--chunk",
                &chunk,
                "-q",
            ],
        )?;
    }
    Ok(store)
}

fn path(p: &Path) -> anyhow::Result<&str> {
    p.to_str().context("non-UTF-8 path")
}

fn main() -> anyhow::Result<()> {
    dsmstream::cache::release_large_buffers_on_free(); // as the CLI runs
    let a = Args::parse();
    let root = prepare(&a)?;
    let store = Store::open(&root)?;
    let id = store.dsms()[0].id.clone();
    let fs: Arc<dyn ReadableStorageTraits> = Arc::new(FilesystemStore::new(&root)?);
    let array = Arc::new(Array::open(fs, &format!("/{id}/0"))?);
    let (size, chunk) = (a.size as u64, a.chunk as u64);
    let chunk_bytes = chunk * chunk * 4;
    let array_bytes = size.div_ceil(chunk).pow(2) * chunk_bytes;
    let workloads = [
        ("large 600x700", windows(a.large, 600, 700, size, chunk, 1)),
        ("nn 9x9", windows(a.nn, 9, 9, size, chunk, 2)),
    ];
    let budgets = [
        ("fits", array_bytes + chunk_bytes),
        ("tight 64 chunks", 64 * chunk_bytes),
    ];
    println!(
        "bench_cache: {size}^2 f32 px, {chunk}^2 chunks ({} chunks, {} MB), median of {} passes",
        size.div_ceil(chunk).pow(2),
        array_bytes >> 20,
        a.repeats
    );
    println!("| workload | budget | threads | dsmstream s | zarrs s | zarrs / dsmstream | dsmstream misses | checksums equal |");
    println!("|---|---|---|---|---|---|---|---|");
    for (name, wins) in &workloads {
        for &(budget_name, budget) in &budgets {
            for &threads in &a.threads {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()?;
                let (ours_s, zarrs_s, misses, equal) = pool.install(|| {
                    // fresh caches per cell; `fits` is measured warm
                    let cache = ChunkCache::new(budget as usize);
                    let zcache = ChunkCacheDecodedLruSizeLimit::new(array.clone(), budget);
                    let warm = budget_name == "fits";
                    let run_ours = a.only.as_deref() != Some("zarrs");
                    let run_zarrs = a.only.as_deref() != Some("dsmstream");
                    if warm {
                        ours(&store, &cache, wins);
                        zarrs_cached(&zcache, wins);
                    }
                    let before = cache.stats().misses;
                    let (mut t_ours, mut t_zarrs) = (Vec::new(), Vec::new());
                    let (mut c_ours, mut c_zarrs) = (0.0, 0.0);
                    for _ in 0..a.repeats {
                        let t = Instant::now();
                        if run_ours {
                            c_ours = ours(&store, &cache, wins);
                        }
                        t_ours.push(t.elapsed().as_secs_f64());
                        let t = Instant::now();
                        if run_zarrs {
                            c_zarrs = zarrs_cached(&zcache, wins);
                        }
                        t_zarrs.push(t.elapsed().as_secs_f64());
                    }
                    let misses = (cache.stats().misses - before) / a.repeats as u64;
                    let equal = (c_ours - c_zarrs).abs() <= 1e-9 * c_ours.abs().max(1.0);
                    (median(t_ours), median(t_zarrs), misses, equal)
                });
                println!(
                    "| {name} | {budget_name} | {threads} | {ours_s:.3} | {zarrs_s:.3} | {:.2}x | {misses} | {} |",
                    zarrs_s / ours_s,
                    if equal { "yes" } else { "NO" }
                );
            }
        }
    }
    Ok(())
}
