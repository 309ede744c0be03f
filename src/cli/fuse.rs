//! `dsmstream fuse <store> --poses poses.json --out fused.tif`: the registered
//! mosaic as a Cloud-Optimized GeoTIFF (and `--per-dsm DIR`: each corrected DSM
//! on its own), with a progress bar over tiles. Existing outputs are kept unless
//! `--force`. `--bounds` sets the output extent, `--nodata` the no-data value of
//! height outputs; `--method count` writes a UInt16 band.

use std::path::PathBuf;

use dsmstream::fuse::{fuse, fuse_per_dsm, FuseConfig, FuseError, FuseMethod, PoseSet, TILE_SIZE};
use dsmstream::InputError;

use super::common::{classify, emit_line, open_store, progress_bar, require_file, ResourceArgs};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The store directory.
    pub store: PathBuf,
    /// poses.json from `dsmstream align` (omit to mosaic the raw collection).
    #[arg(long)]
    pub poses: Option<PathBuf>,
    /// The fused GeoTIFF (written to a temporary name, then renamed).
    #[arg(long, required_unless_present = "per_dsm")]
    pub out: Option<PathBuf>,
    /// Output cell in CRS units (default: the finest input cell); a coarser cell
    /// reads the matching store overview.
    #[arg(long)]
    pub gsd: Option<f64>,
    /// How overlapping corrected heights are combined.
    #[arg(long, value_enum, default_value = "median")]
    pub method: FuseMethod,
    /// Also write each corrected DSM alone as DIR/<id>.tif.
    #[arg(long)]
    pub per_dsm: Option<PathBuf>,
    /// Replace output files that already exist (refused otherwise).
    #[arg(long)]
    pub force: bool,
    /// Output extent in the store's CRS, snapped outward to the mosaic grid
    /// (as `gdalwarp -tap -te`); with --per-dsm every file gets this extent.
    #[arg(long, num_args = 4, allow_negative_numbers = true,
          value_names = ["XMIN", "YMIN", "XMAX", "YMAX"])]
    pub bounds: Option<Vec<f64>>,
    /// No-data value written for height outputs (default nan); not with
    /// --method count, whose UInt16 band has none (0 = no DSM).
    #[arg(long, allow_negative_numbers = true)]
    pub nodata: Option<f32>,
    #[command(flatten)]
    pub resources: ResourceArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if let Some(p) = &args.poses {
        require_file(p, "--poses")?;
    }
    if args.nodata.is_some() && args.method == FuseMethod::Count {
        return Err(InputError::new(
            "--nodata does not apply to --method count (a UInt16 band of counts, 0 = no DSM)",
        )
        .into());
    }
    let store = open_store(&args.store)?;
    if !args.force {
        refuse_existing(&args, &store)?;
    }
    let poses = match &args.poses {
        Some(p) => PoseSet::from_file(&store, p).map_err(to_anyhow)?,
        None => PoseSet::identity(&store),
    };
    let config = FuseConfig {
        gsd_m: args.gsd,
        method: args.method,
        threads: args.resources.threads(),
        tile_size: TILE_SIZE,
        bounds: args.bounds.as_deref().map(|b| [b[0], b[1], b[2], b[3]]),
        nodata: args.nodata.unwrap_or(f32::NAN),
    };
    let cache = args.resources.cache();
    let bar = progress_bar("tiles");
    let progress = |done: u64, total: u64| {
        bar.set_length(total);
        bar.set_position(done);
    };
    if let Some(out) = &args.out {
        bar.set_message(out.display().to_string());
        let r = fuse(&store, &cache, &poses, &config, out, &progress).map_err(to_anyhow)?;
        bar.finish_and_clear();
        emit_line(&format!(
            "fused {} DSMs (poses: {}) into {}: {} x {} px at {} m, {:.1}% valid, {:.1} s",
            r.dsms,
            poses.label(),
            out.display(),
            r.width,
            r.height,
            r.gsd_m,
            100.0 * r.valid_pixels as f64 / (r.width * r.height) as f64,
            r.seconds
        ))?;
    }
    if let Some(dir) = &args.per_dsm {
        let reports =
            fuse_per_dsm(&store, &cache, &poses, &config, dir, &progress).map_err(to_anyhow)?;
        bar.finish_and_clear();
        for r in &reports {
            emit_line(&format!(
                "wrote {}: {} x {} px at {} m",
                r.path.display(),
                r.width,
                r.height,
                r.gsd_m
            ))?;
        }
    }
    cache.log_stats();
    let s = cache.stats();
    tracing::info!(
        hits = s.hits,
        misses = s.misses,
        peak_mb = s.peak_bytes >> 20,
        "cache reported"
    );
    Ok(())
}

/// Exit 2 naming the first output that exists already.
fn refuse_existing(args: &Args, store: &dsmstream::store::Store) -> anyhow::Result<()> {
    let per_dsm = args.per_dsm.iter().flat_map(|dir| {
        store
            .dsms()
            .iter()
            .map(move |d| dir.join(format!("{}.tif", d.id)))
    });
    match args.out.iter().cloned().chain(per_dsm).find(|p| p.exists()) {
        Some(p) => Err(InputError::new(format!(
            "{}: exists already; add --force to replace it",
            p.display()
        ))
        .into()),
        None => Ok(()),
    }
}

fn to_anyhow(e: FuseError) -> anyhow::Error {
    classify(e, FuseError::is_bad_input)
}
