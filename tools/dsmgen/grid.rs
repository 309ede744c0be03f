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

pub fn run(a: GridArgs) -> Result<(), SynthError> {
    let (points, recorded) = read_surface_points(&a.points)?;
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
    let origin = a.origin.as_deref().map(|o| [o[0], o[1]]);
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
