//! What a fused raster says about itself, so the files stack in a GIS: the
//! sample type (heights Float32 with the chosen no-data value; `count` a
//! UInt16 band with no no-data, 0 meaning no DSM), the band description and
//! unit GDAL reads (GDAL_METADATA), provenance items (method, DSM id; not the
//! poses file's path: the same poses give the same bytes wherever they came from),
//! and the output extent: the union of the corrected footprints, or
//! `--bounds` snapped outward to the mosaic's lattice (as `gdalwarp -tap -te`).

use super::layout::OutputGrid;
use super::{FuseConfig, FuseError, FuseMethod, PoseSet};
use crate::geo::Crs;
use crate::geotiff::writer::{CogOptions, CogSample, GdalMetadata};
use crate::store::Store;

/// Unit of heights and height differences: the store's heights are metres.
pub const HEIGHT_UNIT: &str = "m";

/// What one raster holds, for its metadata.
#[derive(Clone, Copy, Debug)]
pub struct RasterContent<'a> {
    pub method: FuseMethod,
    /// The DSM of a per-DSM output (None for the mosaic).
    pub dsm_id: Option<&'a str>,
}

impl FuseMethod {
    /// The band description GDAL shows ("height", "height spread", "count").
    pub fn band_description(self) -> &'static str {
        match self {
            FuseMethod::Median | FuseMethod::Mean | FuseMethod::Min | FuseMethod::Max => "height",
            FuseMethod::Spread => "height spread",
            FuseMethod::Count => "count",
        }
    }

    /// The band's unit (none for a count).
    pub fn band_unit(self) -> Option<&'static str> {
        match self {
            FuseMethod::Count => None,
            _ => Some(HEIGHT_UNIT),
        }
    }

    /// Lower-case name, as on the command line.
    pub fn name(self) -> &'static str {
        match self {
            FuseMethod::Median => "median",
            FuseMethod::Mean => "mean",
            FuseMethod::Min => "min",
            FuseMethod::Max => "max",
            FuseMethod::Count => "count",
            FuseMethod::Spread => "spread",
        }
    }

    /// The stored sample type: counts are integers.
    pub fn sample(self) -> CogSample {
        match self {
            FuseMethod::Count => CogSample::UInt16,
            _ => CogSample::Float32,
        }
    }
}

/// GDAL_METADATA of one output: band description and unit, then provenance.
pub fn metadata(content: RasterContent<'_>) -> GdalMetadata {
    let method = content.method;
    let mut items = vec![("FUSE_METHOD".to_string(), method.name().to_string())];
    if let Some(id) = content.dsm_id {
        items.push(("DSM_ID".to_string(), id.to_string()));
    }
    GdalMetadata {
        band_description: Some(method.band_description().to_string()),
        band_unit: method.band_unit().map(str::to_string),
        items,
    }
}

/// The COG options of one output raster on `grid`.
pub fn cog_options(
    config: &FuseConfig,
    grid: &OutputGrid,
    crs: Crs,
    content: RasterContent<'_>,
) -> CogOptions {
    CogOptions {
        tile_size: config.tile_size,
        geotransform: grid.geotransform,
        crs,
        nodata: config.nodata,
        overviews: true,
        sample: config.method.sample(),
        metadata: metadata(content),
    }
}

/// Refuse `--bounds` that are not a box (min < max, finite) and a `--nodata`
/// that cannot be stored.
pub fn check_options(config: &FuseConfig) -> Result<(), FuseError> {
    if let Some(b) = config.bounds {
        if !(b.iter().all(|v| v.is_finite()) && b[0] < b[2] && b[1] < b[3]) {
            return Err(FuseError::Input(format!(
                "--bounds {} {} {} {} must be xmin ymin xmax ymax with xmin < xmax and ymin < ymax",
                b[0], b[1], b[2], b[3]
            )));
        }
    }
    if config.nodata.is_infinite() {
        return Err(FuseError::Input(format!(
            "--nodata {} must be a finite number or nan",
            config.nodata
        )));
    }
    Ok(())
}

/// The grid of an output: `grid` (the union of the footprints) unless
/// `bounds`, then the smallest grid on the same cell and lattice covering them.
pub fn extent(grid: OutputGrid, bounds: Option<[f64; 4]>) -> OutputGrid {
    match bounds {
        None => grid,
        Some(b) => {
            let g = grid.geotransform.0;
            OutputGrid::covering(b, grid.gsd_m(), (g[0], g[3]))
        }
    }
}

/// True when [xmin, ymin, xmax, ymax] boxes share some area.
pub fn overlaps(a: [f64; 4], b: [f64; 4]) -> bool {
    a[0] < b[2] && b[0] < a[2] && a[1] < b[3] && b[1] < a[3]
}

/// Refuse bad options, and `bounds` that meet none of the corrected DSMs.
pub fn check_bounds_meet_data(
    store: &Store,
    poses: &PoseSet,
    config: &FuseConfig,
) -> Result<(), FuseError> {
    check_options(config)?;
    let Some(b) = config.bounds else {
        return Ok(());
    };
    let all: Vec<usize> = (0..store.dsms().len()).collect();
    if let Some((grid, placed)) = super::plan_grid(store, poses, &all, config.gsd_m) {
        if !placed.iter().any(|p| overlaps(p.corrected_bounds, b)) {
            let g = grid.geotransform.0;
            let x1 = g[0] + grid.width as f64 * grid.gsd_m();
            let y0 = g[3] - grid.height as f64 * grid.gsd_m();
            return Err(FuseError::Input(format!(
                "--bounds {} {} {} {} meet no DSM (the corrected DSMs cover {} {y0} {x1} {})",
                b[0], b[1], b[2], b[3], g[0], g[3]
            )));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::GeoTransform;

    #[test]
    fn bounds_snap_outward_to_the_lattice() {
        let grid = OutputGrid::covering([10.0, 20.0, 30.0, 40.0], 0.5, (0.25, 0.25));
        let g = extent(grid, Some([12.1, 22.9, 14.0, 24.3]));
        assert_eq!(g.geotransform.0, [11.75, 0.5, 0.0, 24.75, 0.0, -0.5]);
        assert_eq!((g.width, g.height), (5, 4));
        assert_eq!(extent(grid, None), grid);
        let on = GeoTransform::north_up(11.75, 24.75, 0.5, 0.5);
        assert_eq!(on.0, g.geotransform.0);
    }

    #[test]
    fn options_are_checked() {
        let bad = |bounds, nodata| FuseConfig {
            bounds,
            nodata,
            ..Default::default()
        };
        assert!(check_options(&bad(Some([1.0, 0.0, 1.0, 5.0]), f32::NAN)).is_err());
        assert!(check_options(&bad(Some([0.0, f64::NAN, 1.0, 5.0]), f32::NAN)).is_err());
        assert!(check_options(&bad(None, f32::INFINITY)).is_err());
        assert!(check_options(&bad(Some([0.0, 0.0, 1.0, 5.0]), -9999.0)).is_ok());
        assert!(overlaps([0.0, 0.0, 2.0, 2.0], [1.0, 1.0, 3.0, 3.0]));
        assert!(!overlaps([0.0, 0.0, 2.0, 2.0], [2.0, 0.0, 3.0, 3.0]));
    }

    #[test]
    fn count_is_an_integer_band_without_unit() {
        let m = metadata(RasterContent {
            method: FuseMethod::Count,
            dsm_id: None,
        });
        assert_eq!(m.band_description.as_deref(), Some("count"));
        assert_eq!(m.band_unit, None);
        assert_eq!(FuseMethod::Count.sample(), CogSample::UInt16);
        let m = metadata(RasterContent {
            method: FuseMethod::Median,
            dsm_id: Some("tile_00"),
        });
        assert_eq!(m.band_unit.as_deref(), Some("m"));
        assert!(m.items.contains(&("DSM_ID".into(), "tile_00".into())));
    }
}
