//! `dsmgen`: synthetic DSMs with a known answer, for tests and benchmarks.
//!
//! - `dsmgen tiles`: overlapping perturbed tiles (chain or grid) + truth.json,
//!   rendered at pixel centres or gridded from scattered points (`--render`)
//! - `dsmgen big`: one large unperturbed DSM written tile by tile (ingest benchmark)
//! - `dsmgen truth-grid`: the noise-free true surface over a tile set or bbox
//! - `dsmgen cut`: overlapping perturbed tiles cut from a real DSM + truth.json
//! - `dsmgen grid`: a lidar point cloud gridded into a DSM (highest first return per cell)
//! - `dsmgen score`: poses.json and its journal against truth.json (errors, sigma calibration)
//!
//! Same seed, same bytes. Exit codes: 0 ok, 1 failure, 2 bad parameters.

mod grid;
mod score;

use std::path::PathBuf;

use clap::{Parser, Subcommand, ValueEnum};
use dsmstream::geo::GeoTransform;
use dsmstream::synth::{
    cut_collection, epsg_crs, render_window, tiles::rigid_about, write_raster, write_tile_set,
    write_truth_grid, CutParams, Layout, PixelEffects, Rendering, Surface, SurfaceParams,
    SynthError, TileSetParams, TileSpec, Truth,
};

#[derive(Parser)]
#[command(
    name = "dsmgen",
    about = "Generate synthetic DSMs with known registration truth"
)]
struct Cli {
    /// Log progress (tracing events at info level).
    #[arg(short, long, global = true)]
    verbose: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Overlapping perturbed tiles and truth.json.
    Tiles(TilesArgs),
    /// One large unperturbed DSM, tile by tile in bounded memory.
    Big(BigArgs),
    /// The noise-free, change-free true surface as a COG.
    TruthGrid(TruthGridArgs),
    /// Overlapping tiles cut from a real DSM, each moved by a known rigid motion, and truth.json.
    Cut(CutArgs),
    /// A lidar point cloud (LAS/LAZ) gridded into a DSM GeoTIFF: the highest (or mean) first return per cell.
    Grid(grid::GridArgs),
    /// A poses.json (and its journal) against truth.json: per-DSM, pairwise and per-pair errors, sigma calibration.
    Score(score::ScoreArgs),
}

/// How pixels are made from the world (see `dsmstream::synth::render`).
#[derive(Clone, Copy, ValueEnum)]
enum RenderArg {
    /// The surface at each pixel centre.
    Centre,
    /// Max of Poisson-scattered lidar points per pixel.
    LidarMax,
    /// Mean of Poisson-scattered lidar points per pixel.
    LidarMean,
    /// Linear in the Delaunay triangles of scattered (stereo) points.
    Tin,
    /// Inverse-distance weighting of scattered (stereo) points.
    Idw,
    /// lidar-mean then a 5 x 5 Gaussian (a matching window).
    Smooth,
}

impl RenderArg {
    fn rendering(self) -> Rendering {
        match self {
            RenderArg::Centre => Rendering::Centre,
            RenderArg::LidarMax => Rendering::LidarMax,
            RenderArg::LidarMean => Rendering::LidarMean,
            RenderArg::Tin => Rendering::Tin,
            RenderArg::Idw => Rendering::Idw,
            RenderArg::Smooth => Rendering::Smooth,
        }
    }
}

/// What lakes look like.
#[derive(Clone, Copy, ValueEnum)]
enum WaterArg {
    /// No-data.
    Nan,
    /// Flat water 1 m below the terrain at the lake's centre.
    Flat,
}

#[derive(Clone, Copy, ValueEnum)]
enum LayoutArg {
    Chain,
    Grid,
}

#[derive(clap::Args)]
struct TilesArgs {
    #[arg(long, value_enum, default_value = "chain")]
    layout: LayoutArg,
    /// Number of tiles of a chain.
    #[arg(long, default_value_t = 4)]
    count: u32,
    /// Grid rows.
    #[arg(long, default_value_t = 2)]
    rows: u32,
    /// Grid columns.
    #[arg(long, default_value_t = 2)]
    cols: u32,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Ground sample distance in metres.
    #[arg(long, default_value_t = 0.5)]
    gsd: f64,
    /// Fraction of a tile shared with its neighbour.
    #[arg(long, default_value_t = 0.6)]
    overlap: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Gaussian noise sigma in metres.
    #[arg(long, default_value_t = 0.3)]
    noise: f64,
    /// Fraction of pixels turned into spikes.
    #[arg(long, default_value_t = 0.02)]
    outliers: f64,
    /// Fraction of 32 px cells holding a void disc.
    #[arg(long, default_value_t = 0.03)]
    voids: f64,
    /// Maximum horizontal shift per axis, metres.
    #[arg(long, default_value_t = 3.0)]
    max_shift_m: f64,
    /// Maximum vertical shift, metres.
    #[arg(long, default_value_t = 2.0)]
    max_shift_z_m: f64,
    /// Maximum rotation per axis, degrees.
    #[arg(long, default_value_t = 0.03)]
    max_rot_deg: f64,
    /// No changed buildings.
    #[arg(long)]
    no_changes: bool,
    /// Leave tile_00 unperturbed.
    #[arg(long)]
    anchor_first: bool,
    /// How pixels are gridded: at pixel centres, or from scattered points.
    #[arg(long, value_enum, default_value = "centre")]
    render: RenderArg,
    /// Mean points per pixel of the point renderings (default: 4 lidar/smooth, 1 idw, 0.5 tin).
    #[arg(long)]
    points_per_px: Option<f64>,
    /// Vertical datum offset (metres) added to every tile with odd row + col,
    /// so that neighbours differ by it.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    dz_offset: f64,
    /// Write every tile with odd row + col at this many times the pixel, over
    /// the same footprint (a collection of mixed resolutions); must divide --size.
    #[arg(long, default_value_t = 1)]
    odd_gsd_factor: u32,
    /// Terrain relief scale (0 with --buildings 0 --trees 0: a flat field).
    #[arg(long, default_value_t = 1.0)]
    relief: f64,
    /// Fraction of 64 m cells with buildings.
    #[arg(long, default_value_t = 0.55)]
    buildings: f64,
    /// Fraction of 64 m cells with trees.
    #[arg(long, default_value_t = 0.25)]
    trees: f64,
    /// Fraction of 512 m cells holding a lake.
    #[arg(long, default_value_t = 0.2)]
    lakes: f64,
    /// Lakes as no-data or as flat water.
    #[arg(long, value_enum, default_value = "nan")]
    water: WaterArg,
    #[arg(long, default_value_t = 32617)]
    epsg: u32,
    /// COG tile size inside each file.
    #[arg(long, default_value_t = 256)]
    cog_tile: u32,
    #[arg(long)]
    out: PathBuf,
}

#[derive(Clone, Copy, ValueEnum)]
enum CompressionArg {
    Deflate,
}

#[derive(clap::Args)]
struct BigArgs {
    /// Width and height in pixels.
    #[arg(long, default_value_t = 20000)]
    size: u64,
    #[arg(long, default_value_t = 0.5)]
    gsd: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    #[arg(long, default_value_t = 0.3)]
    noise: f64,
    #[arg(long, default_value_t = 0.02)]
    outliers: f64,
    #[arg(long, default_value_t = 0.03)]
    voids: f64,
    /// Only deflate (with floating-point predictor) is written.
    #[arg(long, value_enum, default_value = "deflate")]
    compression: CompressionArg,
    /// COG tile size.
    #[arg(long, default_value_t = 256)]
    tile: u32,
    #[arg(long, default_value_t = 32617)]
    epsg: u32,
    /// Top-left corner (x y, CRS metres); default: the tile sets' origin.
    #[arg(long, num_args = 2, allow_negative_numbers = true, value_names = ["X", "Y"])]
    origin: Option<Vec<f64>>,
    /// Perturb the written data (dx dy dz, metres): p_true = M p_written, M about the raster centre.
    #[arg(long, num_args = 3, allow_negative_numbers = true, value_names = ["DX", "DY", "DZ"])]
    shift_m: Option<Vec<f64>>,
    /// Perturbation rotation (roll pitch yaw, degrees), with --shift-m.
    #[arg(long, num_args = 3, allow_negative_numbers = true, value_names = ["RX", "RY", "RZ"])]
    rot_deg: Option<Vec<f64>>,
    /// Seed of the noise, outliers and voids (default: --seed; the surface always uses --seed).
    #[arg(long)]
    pixel_seed: Option<u64>,
    #[arg(long)]
    out: PathBuf,
    /// Also write the same pixels, rendered independently of the COG writer,
    /// as a NumPy .npy file (for tools/scripts/check_cog.py; size^2 * 4 bytes).
    #[arg(long)]
    npy: Option<PathBuf>,
}

#[derive(clap::Args)]
struct TruthGridArgs {
    /// Cover the tiles of this truth.json with its seed and GSD.
    #[arg(long, conflicts_with_all = ["bbox", "seed"])]
    truth: Option<PathBuf>,
    /// min_x min_y max_x max_y in CRS metres (with --seed).
    #[arg(long, num_args = 4, allow_negative_numbers = true)]
    bbox: Option<Vec<f64>>,
    #[arg(long)]
    seed: Option<u64>,
    /// Pixel size; defaults to the truth.json GSD, else 0.5 m.
    #[arg(long)]
    gsd: Option<f64>,
    #[arg(long, default_value_t = 32617)]
    epsg: u32,
    #[arg(long)]
    out: PathBuf,
}

#[derive(clap::Args)]
struct CutArgs {
    /// The real DSM to cut (GeoTIFF, north-up, projected CRS).
    source: PathBuf,
    #[arg(long, value_enum, default_value = "chain")]
    layout: LayoutArg,
    /// Number of tiles of a chain.
    #[arg(long, default_value_t = 4)]
    count: u32,
    /// Grid rows.
    #[arg(long, default_value_t = 2)]
    rows: u32,
    /// Grid columns.
    #[arg(long, default_value_t = 2)]
    cols: u32,
    /// Tile edge in source pixels.
    #[arg(long, default_value_t = 256)]
    size: u32,
    /// Fraction of a tile shared with its neighbour.
    #[arg(long, default_value_t = 0.6)]
    overlap: f64,
    /// Top-left source pixel of tile_00 (col row); default: the layout centred on the source.
    #[arg(long, num_args = 2, allow_negative_numbers = true, value_names = ["COL", "ROW"])]
    origin_px: Option<Vec<i64>>,
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Maximum horizontal shift per axis, metres (exact: the geotransform moves).
    #[arg(long, default_value_t = 3.0)]
    max_shift_m: f64,
    /// Maximum vertical shift, metres.
    #[arg(long, default_value_t = 2.0)]
    max_shift_z_m: f64,
    /// Maximum rotation per axis (roll, pitch, yaw), degrees; resampled bilinearly.
    #[arg(long, default_value_t = 0.02)]
    max_rot_deg: f64,
    /// Leave tile_00 unperturbed (the truth's gauge: align --anchor tile_00).
    #[arg(long)]
    anchor_first: bool,
    /// COG tile size inside each file.
    #[arg(long, default_value_t = 256)]
    cog_tile: u32,
    #[arg(long)]
    out: PathBuf,
}

fn main() {
    let cli = Cli::parse();
    let level = if cli.verbose { "info" } else { "warn" };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level)),
        )
        .with_writer(std::io::stderr)
        .init();
    let result = match cli.command {
        Command::Tiles(a) => tiles(a),
        Command::Big(a) => big(a),
        Command::TruthGrid(a) => truth_grid(a),
        Command::Cut(a) => cut(a),
        Command::Grid(a) => grid::run(a),
        Command::Score(a) => {
            if let Err(message) = score::run(a) {
                eprintln!("error: {message}");
                std::process::exit(2);
            }
            Ok(())
        }
    };
    if let Err(err) = result {
        eprintln!("error: {err}");
        std::process::exit(if err.is_bad_input() { 2 } else { 1 });
    }
}

fn tiles(a: TilesArgs) -> Result<(), SynthError> {
    let (layout, rows, cols) = match a.layout {
        LayoutArg::Chain => (Layout::Chain, 1, a.count),
        LayoutArg::Grid => (Layout::Grid, a.rows, a.cols),
    };
    let params = TileSetParams {
        layout,
        rows,
        cols,
        size_px: a.size,
        gsd_m: a.gsd,
        overlap: a.overlap,
        epsg: a.epsg,
        seed: a.seed,
        noise_sigma_m: a.noise,
        outlier_fraction: a.outliers,
        void_fraction: a.voids,
        max_shift_xy_m: a.max_shift_m,
        max_shift_z_m: a.max_shift_z_m,
        max_rot_deg: a.max_rot_deg,
        changes: !a.no_changes,
        anchor_first: a.anchor_first,
        rendering: a.render.rendering(),
        points_per_px: a.points_per_px.unwrap_or(0.0),
        dz_offset_m: a.dz_offset,
        odd_gsd_factor: a.odd_gsd_factor,
        ..Default::default()
    };
    let scene = [a.relief, a.buildings, a.trees, a.lakes];
    if scene.iter().any(|v| !v.is_finite() || *v < 0.0)
        || a.points_per_px
            .is_some_and(|d| d.is_nan() || d <= 0.0 || d > 64.0)
        || !a.dz_offset.is_finite()
    {
        return Err(SynthError::BadParams(
            "--relief, --buildings, --trees, --lakes must be >= 0, --points-per-px in (0, 64], --dz-offset finite".into(),
        ));
    }
    let defaults = SurfaceParams::default();
    let surface = SurfaceParams {
        seed: a.seed,
        relief_scale: a.relief,
        lake_cells: a.lakes,
        flat_water: matches!(a.water, WaterArg::Flat),
        objects: dsmstream::synth::objects::ObjectParams {
            building_cells: a.buildings,
            tree_cells: a.trees,
            changed_cells: defaults.objects.changed_cells.min(a.buildings),
        },
        ..defaults
    };
    let truth = write_tile_set(&params, &surface, &a.out, a.cog_tile)?;
    println!(
        "wrote {} tiles of {} px at {} m ({} rendering) and truth.json to {}",
        truth.tiles.len(),
        a.size,
        a.gsd,
        RenderArg::value_variants()
            .iter()
            .find(|v| v.rendering() == params.rendering)
            .and_then(|v| v.to_possible_value())
            .map_or("centre".to_string(), |v| v.get_name().to_string()),
        a.out.display()
    );
    Ok(())
}

fn big(a: BigArgs) -> Result<(), SynthError> {
    let CompressionArg::Deflate = a.compression;
    if a.size == 0 || a.gsd.is_nan() || a.gsd <= 0.0 {
        return Err(SynthError::BadParams(format!(
            "size {} px and gsd {} m must be positive",
            a.size, a.gsd
        )));
    }
    let defaults = TileSetParams::default();
    let (ox, oy) = match &a.origin {
        Some(o) => (o[0], o[1]),
        None => (defaults.origin_x_m, defaults.origin_y_m),
    };
    let gt = GeoTransform::north_up(ox, oy, a.gsd, a.gsd);
    let mut spec = TileSpec::unperturbed("big", a.size, a.size, gt, a.pixel_seed.unwrap_or(a.seed));
    let surface = Surface::new(SurfaceParams {
        seed: a.seed,
        ..Default::default()
    });
    if a.shift_m.is_some() || a.rot_deg.is_some() {
        let shift = a.shift_m.as_deref().unwrap_or(&[0.0; 3]);
        let rot = a.rot_deg.as_deref().unwrap_or(&[0.0; 3]);
        let half_m = a.size as f64 * a.gsd / 2.0;
        let centre =
            nalgebra::Vector3::new(ox + half_m, oy - half_m, surface.params().base_elevation_m);
        spec.shift_m = [shift[0], shift[1], shift[2]];
        spec.rot_deg = [rot[0], rot[1], rot[2]];
        spec.m_world = rigid_about(centre, spec.shift_m, spec.rot_deg);
        let m = dsmstream::icp::matrix_rows(&spec.m_world);
        println!("matrix_world (p_true = M p_written): {m:?}");
    }
    let fx = PixelEffects {
        noise_sigma_m: a.noise,
        outlier_fraction: a.outliers,
        void_fraction: a.voids,
        changes: false,
        rendering: Rendering::Centre,
        points_per_px: 0.0,
    };
    let bar = indicatif::ProgressBar::new(a.size.div_ceil(a.tile as u64));
    let started = std::time::Instant::now();
    write_raster(
        &surface,
        &spec,
        &fx,
        &epsg_crs(a.epsg),
        &a.out,
        a.tile,
        &|done, _| bar.set_position(done),
    )?;
    bar.finish_and_clear();
    if let Some(npy) = &a.npy {
        write_npy(&surface, &spec, &fx, npy).map_err(|source| SynthError::Io {
            path: npy.clone(),
            source,
        })?;
    }
    println!(
        "wrote {} ({} x {} px, {} m) in {:.1} s",
        a.out.display(),
        a.size,
        a.size,
        a.gsd,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Stream the raster as a little-endian float32 .npy, one row at a time.
fn write_npy(
    surface: &Surface,
    spec: &TileSpec,
    fx: &PixelEffects,
    path: &std::path::Path,
) -> std::io::Result<()> {
    use rayon::prelude::*;
    use std::io::Write;
    let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
    let dict = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}), }}",
        spec.height, spec.width
    );
    let unpadded = 10 + dict.len() + 1;
    let header = format!(
        "{dict}{}\n",
        " ".repeat(unpadded.div_ceil(64) * 64 - unpadded)
    );
    out.write_all(b"\x93NUMPY\x01\x00")?;
    out.write_all(&(header.len() as u16).to_le_bytes())?;
    out.write_all(header.as_bytes())?;
    for row0 in (0..spec.height).step_by(64) {
        let rows: Vec<Vec<f32>> = (row0..(row0 + 64).min(spec.height))
            .into_par_iter()
            .map(|r| render_window(surface, spec, fx, 0, r, spec.width, 1))
            .collect();
        for row in rows {
            for v in row {
                out.write_all(&v.to_le_bytes())?;
            }
        }
    }
    out.flush()
}

fn truth_grid(a: TruthGridArgs) -> Result<(), SynthError> {
    let (surface, bbox, gsd, epsg) = match (&a.truth, &a.bbox, a.seed) {
        (Some(path), _, _) => {
            let truth = Truth::load(path)?;
            let gsd = a.gsd.unwrap_or(truth.gsd);
            let Some((generation, surface)) = truth.synthetic() else {
                return Err(SynthError::BadTruth {
                    path: path.clone(),
                    message: "no synthetic surface (a cut: its source DSM is the truth)".into(),
                });
            };
            (*surface, truth.bbox(), gsd, generation.epsg)
        }
        (None, Some(b), Some(seed)) => {
            let surface = SurfaceParams {
                seed,
                ..Default::default()
            };
            (
                surface,
                [b[0], b[1], b[2], b[3]],
                a.gsd.unwrap_or(0.5),
                a.epsg,
            )
        }
        _ => {
            return Err(SynthError::BadParams(
                "give --truth truth.json, or --bbox and --seed".to_string(),
            ))
        }
    };
    write_truth_grid(&surface, bbox, gsd, &epsg_crs(epsg), &a.out)?;
    println!("wrote {} over {bbox:?} at {gsd} m", a.out.display());
    Ok(())
}

fn cut(a: CutArgs) -> Result<(), SynthError> {
    let (layout, rows, cols) = match a.layout {
        LayoutArg::Chain => (Layout::Chain, 1, a.count),
        LayoutArg::Grid => (Layout::Grid, a.rows, a.cols),
    };
    let params = CutParams {
        layout,
        rows,
        cols,
        size_px: a.size,
        overlap: a.overlap,
        origin_px: a.origin_px.as_deref().map(|o| [o[0], o[1]]),
        seed: a.seed,
        max_shift_xy_m: a.max_shift_m,
        max_shift_z_m: a.max_shift_z_m,
        max_rot_deg: a.max_rot_deg,
        anchor_first: a.anchor_first,
    };
    let report = cut_collection(&a.source, &params, &a.out, a.cog_tile)?;
    let truth = &report.truth;
    let [col, row] = truth
        .cut
        .as_ref()
        .and_then(|c| c.params.origin_px)
        .unwrap_or_default();
    println!(
        "cut {} into {} tiles of {} px (tile_00 at source pixel col {col}, row {row}), truth.json in {}",
        a.source.display(),
        truth.tiles.len(),
        a.size,
        a.out.display()
    );
    println!(
        "{:<8} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>9}",
        "tile", "valid %", "dx m", "dy m", "dz m", "roll deg", "pitch deg", "yaw deg"
    );
    for (t, valid) in truth.tiles.iter().zip(&report.valid_fraction) {
        let [dx, dy, dz] = t.shift_m;
        let [rx, ry, rz] = t.rot_deg;
        println!(
            "{:<8} {:>8.1} {dx:>9.3} {dy:>9.3} {dz:>9.3} {rx:>9.4} {ry:>9.4} {rz:>9.4}",
            t.id,
            valid * 100.0
        );
    }
    Ok(())
}
