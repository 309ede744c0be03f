//! A DSM gridded from a lidar point cloud (LAS/LAZ) the way lidar DSMs are
//! made: the highest (or the mean) surface return in each cell of a regular
//! lattice, cells without a return left void. `dsmgen grid` writes it as a
//! COG, so that real photogrammetric DSMs can be registered against the lidar
//! of the same place (tests/cli/codem.rs: CODEM's DSM against its lidar).

use std::path::Path;

use las::Reader;

use super::output::epsg_crs;
use super::SynthError;
use crate::eval::las::{crs_epsg, on_surface};
use crate::geo::GeoTransform;
use crate::geotiff::writer::{CogOptions, CogWriter};

/// What a cell keeps of the returns in it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CellStat {
    /// The highest return (a lidar DSM's top surface).
    Max,
    /// The mean of the returns.
    Mean,
}

/// The surface returns of a LAS/LAZ file (first returns, no noise or withheld
/// points) and the EPSG code its header records, if any. All of them in
/// memory (24 bytes a point): a generator of test rasters, not an ingest path.
pub fn read_surface_points(path: &Path) -> Result<(Vec<[f64; 3]>, Option<u32>), SynthError> {
    let bad = |m: String| SynthError::BadSource(format!("{}: {m}", path.display()));
    let mut reader = Reader::from_path(path).map_err(|e| bad(e.to_string()))?;
    let epsg = crs_epsg(reader.header());
    let mut points = Vec::new();
    loop {
        let batch = reader
            .read_points(1 << 18)
            .map_err(|e| bad(format!("reading points: {e}")))?;
        if batch.is_empty() {
            break;
        }
        for p in batch.points() {
            let p = p.map_err(|e| bad(format!("reading points: {e}")))?;
            if on_surface(&p, false) {
                points.push([p.x, p.y, p.z]);
            }
        }
    }
    if points.is_empty() {
        return Err(bad("no surface returns (first returns, not noise)".into()));
    }
    Ok((points, epsg))
}

/// A gridded DSM in memory: row-major heights, NaN where no return fell.
#[derive(Clone, Debug)]
pub struct PointGrid {
    pub geotransform: GeoTransform,
    pub width: u64,
    pub height: u64,
    pub values: Vec<f32>,
}

/// Grids `points` on cells of `gsd_m`: the lattice starts at `origin` (the
/// top-left corner) or, without one, at the points' bounds rounded out to
/// whole cells; each cell takes `stat` of the heights of the points in it,
/// plus `dz_m` (a datum offset to simulate).
pub fn grid_points(
    points: &[[f64; 3]],
    gsd_m: f64,
    origin: Option<[f64; 2]>,
    stat: CellStat,
    dz_m: f64,
) -> Result<PointGrid, SynthError> {
    if !(gsd_m.is_finite() && gsd_m > 0.0) {
        return Err(SynthError::BadParams(format!("--gsd {gsd_m}: must be > 0")));
    }
    let bound =
        |k: usize, f: fn(f64, f64) -> f64, start: f64| points.iter().map(|p| p[k]).fold(start, f);
    let (min_x, max_x) = (
        bound(0, f64::min, f64::INFINITY),
        bound(0, f64::max, f64::NEG_INFINITY),
    );
    let (min_y, max_y) = (
        bound(1, f64::min, f64::INFINITY),
        bound(1, f64::max, f64::NEG_INFINITY),
    );
    let [x0, y0] = origin.unwrap_or([
        (min_x / gsd_m).floor() * gsd_m,
        (max_y / gsd_m).ceil() * gsd_m,
    ]);
    if !(x0 <= min_x && y0 >= max_y) {
        return Err(SynthError::BadParams(format!(
            "--origin ({x0}, {y0}) is not the top-left of the points ({min_x:.2}, {max_y:.2})"
        )));
    }
    let width = (((max_x - x0) / gsd_m).floor() as u64 + 1).max(1);
    let height = (((y0 - min_y) / gsd_m).floor() as u64 + 1).max(1);
    if width * height > 1 << 30 {
        return Err(SynthError::BadParams(format!(
            "{width} x {height} cells at --gsd {gsd_m}: too many"
        )));
    }
    let cells = (width * height) as usize;
    let (mut top, mut sum, mut count) = (
        vec![f64::NEG_INFINITY; cells],
        vec![0.0; cells],
        vec![0u32; cells],
    );
    for p in points {
        let c = (((p[0] - x0) / gsd_m).floor() as u64).min(width - 1);
        let r = (((y0 - p[1]) / gsd_m).floor() as u64).min(height - 1);
        let k = (r * width + c) as usize;
        top[k] = top[k].max(p[2]);
        sum[k] += p[2];
        count[k] += 1;
    }
    let values = (0..cells)
        .map(|k| match (count[k], stat) {
            (0, _) => f32::NAN,
            (_, CellStat::Max) => (top[k] + dz_m) as f32,
            (n, CellStat::Mean) => (sum[k] / n as f64 + dz_m) as f32,
        })
        .collect();
    Ok(PointGrid {
        geotransform: GeoTransform::north_up(x0, y0, gsd_m, gsd_m),
        width,
        height,
        values,
    })
}

/// Writes `grid` as a float32 COG (NaN no-data) in EPSG:`epsg`.
pub fn write_point_grid(grid: &PointGrid, epsg: u32, path: &Path) -> Result<(), SynthError> {
    let options = CogOptions {
        geotransform: grid.geotransform,
        crs: epsg_crs(epsg),
        ..Default::default()
    };
    let t = options.tile_size as u64;
    let mut writer = CogWriter::create(path, grid.width, grid.height, options)?;
    for ty in 0..writer.tiles_y() {
        for tx in 0..writer.tiles_x() {
            let tile: Vec<f32> = (0..t * t)
                .map(|i| {
                    let (c, r) = (tx * t + i % t, ty * t + i / t);
                    if c < grid.width && r < grid.height {
                        grid.values[(r * grid.width + c) as usize]
                    } else {
                        f32::NAN
                    }
                })
                .collect();
            writer.write_tile(tx, ty, &tile)?;
        }
    }
    writer.finish()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_keep_the_highest_or_the_mean_return() {
        // two points in the top-left cell, one in the bottom-right, none between
        let points = [[0.2, 2.9, 10.0], [0.7, 2.1, 12.0], [2.5, 0.5, 5.0]];
        let max = grid_points(&points, 1.0, None, CellStat::Max, 0.0).unwrap();
        assert_eq!((max.width, max.height), (3, 3));
        assert_eq!(max.geotransform, GeoTransform::north_up(0.0, 3.0, 1.0, 1.0));
        assert_eq!(max.values[0], 12.0);
        assert_eq!(max.values[8], 5.0);
        assert_eq!(max.values.iter().filter(|v| v.is_nan()).count(), 7);
        let mean = grid_points(&points, 1.0, None, CellStat::Mean, 100.0).unwrap();
        assert_eq!(mean.values[0], 111.0);
        assert_eq!(mean.values[8], 105.0);
    }

    #[test]
    fn an_origin_inside_the_points_is_refused() {
        let points = [[0.2, 2.9, 10.0], [2.5, 0.5, 5.0]];
        assert!(grid_points(&points, 1.0, Some([1.0, 3.0]), CellStat::Max, 0.0).is_err());
        let shifted = grid_points(&points, 1.0, Some([-0.5, 3.5]), CellStat::Max, 0.0).unwrap();
        assert_eq!((shifted.width, shifted.height), (4, 4));
        assert_eq!(shifted.values[0], 10.0);
        assert!(grid_points(&points, 0.0, None, CellStat::Max, 0.0).is_err());
    }
}
