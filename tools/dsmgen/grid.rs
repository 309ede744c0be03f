//! `dsmgen grid`: a lidar point cloud (LAS/LAZ) gridded into a DSM GeoTIFF, the
//! highest (or mean) first return per cell, optionally moved by a datum
//! offset, to register real photogrammetric DSMs against their lidar.

use std::path::PathBuf;

use clap::ValueEnum;
use dsmstream::synth::points::{grid_points, read_surface_points, write_point_grid, CellStat};
use dsmstream::synth::SynthError;

#[derive(clap::Args)]
pub struct GridArgs {
    /// The point cloud (LAS or LAZ); first returns, noise classes and withheld points dropped.
    #[arg(long)]
    points: PathBuf,
    /// Cell size, metres.
    #[arg(long, default_value_t = 1.0)]
    gsd: f64,
    /// What a cell keeps of its returns.
    #[arg(long, value_enum, default_value_t = StatArg::Max)]
    stat: StatArg,
    /// Top-left corner of the lattice (x y in the CRS); default: the points' bounds rounded out to whole cells.
    #[arg(long, num_args = 2, allow_negative_numbers = true)]
    origin: Option<Vec<f64>>,
    /// Added to every height (metres): a vertical datum offset to simulate.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    dz: f64,
    /// Keep only subset K of N (written K/N): each point falls in one of N
    /// subsets at random (by its index, deterministic), so that DSMs gridded
    /// from different subsets of one cloud sample the surface independently.
    #[arg(long, value_parser = parse_subset)]
    subset: Option<(u64, u64)>,
    /// Move the points horizontally by (dx, dy) metres, after turning them
    /// by `--yaw-deg` about the centre of `--window` (or of the points): the
    /// DSM then needs the inverse motion to come back (`p_ref = M^-1 p`).
    #[arg(long, num_args = 2, allow_negative_numbers = true)]
    shift: Option<Vec<f64>>,
    /// Turn the points by this angle (degrees, counter-clockwise seen from above).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    yaw_deg: f64,
    /// Keep only the (moved) points inside xmin ymin xmax ymax; the lattice
    /// then starts at (xmin, ymax) unless `--origin` says otherwise.
    #[arg(long, num_args = 4, allow_negative_numbers = true)]
    window: Option<Vec<f64>>,
    /// EPSG code of the output, when the point cloud records none (else it must agree).
    #[arg(long)]
    epsg: Option<u32>,
    /// Output GeoTIFF (written under a temporary name, then renamed).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Clone, Copy, ValueEnum)]
enum StatArg {
    /// The highest return (a lidar DSM).
    Max,
    /// The mean of the returns.
    Mean,
}

fn parse_subset(s: &str) -> Result<(u64, u64), String> {
    let bad = || format!("{s}: expected K/N with 0 <= K < N");
    let (k, n) = s.split_once('/').ok_or_else(bad)?;
    let (k, n) = (k.parse().map_err(|_| bad())?, n.parse().map_err(|_| bad())?);
    (k < n).then_some((k, n)).ok_or_else(bad)
}

/// The subset (of `n`) point `index` falls in: a SplitMix64 hash of the index.
fn subset_of(index: u64, n: u64) -> u64 {
    let mut z = index.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    (z ^ (z >> 31)) % n
}

/// `points` reduced to `--subset`, moved by `--yaw-deg` and `--shift`, cut to `--window`.
fn select_and_move(a: &GridArgs, points: Vec<[f64; 3]>) -> Vec<[f64; 3]> {
    let mut points: Vec<[f64; 3]> = match a.subset {
        Some((k, n)) => points
            .into_iter()
            .enumerate()
            .filter(|(i, _)| subset_of(*i as u64, n) == k)
            .map(|(_, p)| p)
            .collect(),
        None => points,
    };
    let centre = match a.window.as_deref() {
        Some(w) => [(w[0] + w[2]) / 2.0, (w[1] + w[3]) / 2.0],
        None => {
            let n = points.len().max(1) as f64;
            let sum = points
                .iter()
                .fold([0.0; 2], |s, p| [s[0] + p[0], s[1] + p[1]]);
            [sum[0] / n, sum[1] / n]
        }
    };
    let (sin, cos) = a.yaw_deg.to_radians().sin_cos();
    let [dx, dy] = a.shift.as_deref().map_or([0.0; 2], |s| [s[0], s[1]]);
    for p in &mut points {
        let (x, y) = (p[0] - centre[0], p[1] - centre[1]);
        p[0] = centre[0] + cos * x - sin * y + dx;
        p[1] = centre[1] + sin * x + cos * y + dy;
    }
    if let Some(w) = a.window.as_deref() {
        points.retain(|p| p[0] >= w[0] && p[0] < w[2] && p[1] > w[1] && p[1] <= w[3]);
    }
    points
}

pub fn run(a: GridArgs) -> Result<(), SynthError> {
    let (points, recorded) = read_surface_points(&a.points)?;
    let points = select_and_move(&a, points);
    if points.is_empty() {
        return Err(SynthError::BadParams(format!(
            "{}: no surface returns left in --subset / --window",
            a.points.display()
        )));
    }
    let epsg = match (recorded, a.epsg) {
        (Some(r), Some(e)) if r != e => {
            return Err(SynthError::BadParams(format!(
                "--epsg {e}: {} records EPSG:{r}",
                a.points.display()
            )))
        }
        (Some(code), _) | (None, Some(code)) => code,
        (None, None) => {
            return Err(SynthError::BadParams(format!(
                "{} records no EPSG code: give --epsg",
                a.points.display()
            )))
        }
    };
    let stat = match a.stat {
        StatArg::Max => CellStat::Max,
        StatArg::Mean => CellStat::Mean,
    };
    let origin = a
        .origin
        .as_deref()
        .map(|o| [o[0], o[1]])
        .or_else(|| a.window.as_deref().map(|w| [w[0], w[3]]));
    let grid = grid_points(&points, a.gsd, origin, stat, a.dz)?;
    write_point_grid(&grid, epsg, &a.out)?;
    let filled = grid.values.iter().filter(|v| v.is_finite()).count();
    println!(
        "gridded {} surface returns of {} into {} x {} cells of {} m ({:.1} % filled), EPSG:{epsg}: {}",
        points.len(),
        a.points.display(),
        grid.width,
        grid.height,
        a.gsd,
        100.0 * filled as f64 / grid.values.len() as f64,
        a.out.display()
    );
    Ok(())
}
