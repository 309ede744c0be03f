//! Stable-terrain masks (`--mask`, xDEM's `inlier_mask`): where the DSMs may
//! be matched. Points of a DSM whose position falls on an excluded cell (or
//! outside the mask) are not used by the pairwise registration: not by the
//! global search, not as ICP correspondences, not in the final information.
//!
//! Two inputs, one representation ([`StableMask`]: bits on a lattice plus 2x
//! overviews, 1 bit per cell in memory):
//! - a GeoTIFF in the DSMs' projected CRS: non-zero = stable; zero, no-data
//!   and NaN = excluded; or in longitude and latitude on the datum of the
//!   DSMs' UTM zone, sampled (nearest cell) on the finest DSM's lattice;
//! - GeoJSON polygons ([`geojson`]) in the DSMs' CRS, or in longitude and
//!   latitude (projected into the DSMs' UTM zone): inside = stable,
//!   rasterised at the finest DSM's pixel on its lattice over the DSMs' extent.

pub mod geojson;
pub mod raster;

use std::path::{Path, PathBuf};

pub use raster::{BitPyramid, BitRaster, MaskLookup};

use crate::geo::{Bounds, Crs, GeoTransform};
use crate::geotiff::reader::{GeoTiffError, GeoTiffReader};
use crate::store::Store;

/// The largest mask held in memory, cells (1 bit each: 1 GiB).
pub const MAX_MASK_CELLS: u64 = 8 << 30;

/// Why a mask cannot be used; every message names the file.
#[derive(Debug, thiserror::Error)]
pub enum MaskError {
    #[error(transparent)]
    GeoTiff(#[from] GeoTiffError),
    #[error("{}: {message}", .path.display())]
    Invalid { path: PathBuf, message: String },
}

impl MaskError {
    /// Every mask problem is the user's input (exit 2).
    pub fn is_bad_input(&self) -> bool {
        match self {
            MaskError::GeoTiff(e) => e.is_bad_input(),
            MaskError::Invalid { .. } => true,
        }
    }
}

/// What a mask is read for: the DSMs' CRS, their finest lattice and extent.
#[derive(Clone, Debug)]
pub struct MaskTarget {
    pub crs: Option<Crs>,
    /// The finest DSM's level-0 geotransform (GeoJSON is rasterised on it).
    pub finest: GeoTransform,
    /// The union of the DSMs' extents.
    pub extent: Bounds,
}

impl MaskTarget {
    pub fn of_store(store: &Store) -> MaskTarget {
        let dsms = store.dsms();
        let finest = dsms
            .iter()
            .map(|d| d.geotransform)
            .min_by(|a, b| a.gsd_x().total_cmp(&b.gsd_x()))
            .unwrap_or(GeoTransform::north_up(0.0, 0.0, 1.0, 1.0));
        let extent = Bounds::union_all(
            dsms.iter()
                .map(|d| d.geotransform.extent(d.width, d.height)),
        )
        .unwrap_or(Bounds::from_corners((0.0, 0.0), (0.0, 0.0)));
        MaskTarget {
            crs: store.crs().cloned(),
            finest,
            extent,
        }
    }
}

/// A loaded mask: stable cells as a bit pyramid.
pub struct StableMask {
    pub path: PathBuf,
    /// FNV-1a of the file's bytes (recorded in the journal's settings).
    pub content_hash: u64,
    pub pyramid: BitPyramid,
}

impl std::fmt::Debug for StableMask {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let l0 = &self.pyramid.levels[0];
        write!(
            f,
            "StableMask({}, {} x {} cells, {:016x})",
            self.path.display(),
            l0.width,
            l0.height,
            self.content_hash
        )
    }
}

impl StableMask {
    /// Reads a GeoTIFF (`.tif`, `.tiff`) or GeoJSON (`.geojson`, `.json`) mask
    /// for DSMs described by `target`.
    pub fn load(path: &Path, target: &MaskTarget) -> Result<StableMask, MaskError> {
        let invalid = |message: String| MaskError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let bytes = std::fs::read(path).map_err(|e| invalid(format!("cannot read: {e}")))?;
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase())
            .unwrap_or_default();
        let level0 = match ext.as_str() {
            "tif" | "tiff" => read_geotiff(path, target)?,
            "geojson" | "json" => {
                let text = String::from_utf8_lossy(&bytes);
                read_geojson(&text, target).map_err(invalid)?
            }
            _ => {
                return Err(invalid(
                    "a mask is a GeoTIFF (.tif, .tiff) or GeoJSON polygons (.geojson, .json)"
                        .into(),
                ))
            }
        };
        if level0.extent().intersection(&target.extent).is_none() {
            return Err(invalid(format!(
                "the mask covers none of the DSMs (mask {:?}, DSMs {:?}; coordinates in another CRS?)",
                level0.extent().to_array(),
                target.extent.to_array()
            )));
        }
        if level0.count() == 0 {
            return Err(invalid("no cell of the mask is stable (non-zero)".into()));
        }
        Ok(StableMask {
            path: path.to_path_buf(),
            content_hash: crate::view::content_hash(&bytes),
            pyramid: BitPyramid::build(level0),
        })
    }

    /// The look-up of the pixels of a `width` x `height` raster placed by `pixels`.
    pub fn lookup(&self, pixels: &GeoTransform, width: i64, height: i64) -> MaskLookup<'_> {
        self.pyramid.lookup(pixels, width, height)
    }

    /// Stable cells of level 0 over all its cells.
    pub fn stable_fraction(&self) -> f64 {
        let l0 = &self.pyramid.levels[0];
        l0.count() as f64 / (l0.width * l0.height).max(1) as f64
    }
}

/// A GeoTIFF mask, streamed a block of rows at a time into bits.
fn read_geotiff(path: &Path, target: &MaskTarget) -> Result<BitRaster, MaskError> {
    let invalid = |message: String| MaskError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    let mut reader = GeoTiffReader::open(path)?;
    let info = reader.info().clone();
    // a mask in longitude and latitude (global land cover), or in another UTM
    // zone, is sampled into DSMs in a UTM zone on its datum
    let projection =
        (target.crs.as_ref()).and_then(|crs| crate::store::warp::projection_into(&info.crs, crs));
    if let (Some(crs), None) = (&target.crs, &projection) {
        if info.crs.is_geographic || !info.crs.same_as(crs) {
            return Err(invalid(format!(
                "the mask's CRS {} is not the DSMs' CRS {}; reproject the mask (gdalwarp -t_srs {})",
                info.crs.label(),
                crs.label(),
                crs.label()
            )));
        }
    }
    if info.width * info.height > MAX_MASK_CELLS {
        return Err(invalid(format!(
            "{} x {} cells is more than the {MAX_MASK_CELLS} a mask may have; use a coarser mask",
            info.width, info.height
        )));
    }
    let (width, height) = (info.width as i64, info.height as i64);
    let mut raster = BitRaster::new(info.geotransform, width, height);
    let mut rows = Vec::new();
    const STEP: u64 = 256;
    for row0 in (0..info.height).step_by(STEP as usize) {
        let n = STEP.min(info.height - row0);
        reader.read_rows_into(row0, n, &mut rows)?;
        for (k, v) in rows.iter().enumerate() {
            if v.is_finite() && *v != 0.0 {
                let (col, row) = (k as i64 % width, row0 as i64 + k as i64 / width);
                raster.set(col, row);
            }
        }
    }
    Ok(match projection {
        Some(into) => in_zone(&raster, &into, target),
        None => raster,
    })
}

/// A mask in degrees (or another UTM zone) on the finest DSM lattice over
/// the part of the DSMs' extent it covers: each cell takes the mask cell its centre falls in (the
/// positions exact every 16 cells, as ingest puts DSMs into UTM). A mask that
/// covers none of the DSMs comes back as one cell over its projected box, for
/// the caller's message.
fn in_zone(bits: &BitRaster, into: &crate::store::warp::IntoCrs, target: &MaskTarget) -> BitRaster {
    let (w, h) = (bits.width as u64, bits.height as u64);
    let [e0, n0, e1, n1] = into.bounds(&bits.geotransform, w, h);
    let projected = Bounds::from_corners((e0, n0), (e1, n1));
    let Some(area) = projected.intersection(&target.extent) else {
        let gt = GeoTransform::north_up(e0, n1, (e1 - e0).max(1e-3), (n1 - n0).max(1e-3));
        return BitRaster::new(gt, 1, 1);
    };
    let (gt, width, height) = lattice_over(&area, target.finest);
    let mapping = into.mapping(gt, width as usize, bits.geotransform, w);
    let mut out = BitRaster::new(gt, width, height);
    let mut positions = Vec::new();
    for row in 0..height {
        mapping.positions(row as u64, &mut positions);
        for (col, &(u, v)) in positions.iter().enumerate() {
            if bits.get(u.round() as i64, v.round() as i64) {
                out.set(col as i64, row);
            }
        }
    }
    out
}

/// The finest DSM lattice snapped outwards around `area`, coarsened 2x until
/// it holds at most [`MAX_MASK_CELLS`]: its placement, width and height.
fn lattice_over(area: &Bounds, finest: GeoTransform) -> (GeoTransform, i64, i64) {
    let mut gt = finest;
    loop {
        let (c0, r0) = gt.world_to_pixel(area.min_x, area.max_y);
        let (c1, r1) = gt.world_to_pixel(area.max_x, area.min_y);
        let (c0, r0) = (c0.floor(), r0.floor());
        let (w, h) = ((c1.ceil() - c0) as i64, (r1.ceil() - r0) as i64);
        if (w.max(1) * h.max(1)) as u64 <= MAX_MASK_CELLS {
            let (x0, y0) = gt.pixel_to_world(c0, r0);
            let placed = GeoTransform([x0, gt.0[1], 0.0, y0, 0.0, gt.0[5]]);
            return (placed, w.max(1), h.max(1));
        }
        gt = gt.overview(1);
    }
}

/// The projection that puts polygons in longitude and latitude into the DSMs'
/// CRS (a UTM zone or another [`crate::geo::proj::ProjectedCrs`]): when the document names WGS 84, ETRS89 or NAD83 degrees (or
/// CRS84), or names nothing, as RFC 7946 has it, and every vertex could be a
/// longitude and latitude while the DSMs' extent could not. WGS 84 is taken
/// as the CRS's datum (the three differ by 1-2 m).
fn degrees_into(
    polygons: &geojson::Polygons,
    target: &MaskTarget,
) -> Result<Option<crate::geo::proj::Projection>, String> {
    let named_degrees = matches!(polygons.named_epsg, Some(Some(4326 | 4258 | 4269)));
    let e = &target.extent;
    let dsms_in_degrees_range =
        e.min_x >= -180.0 && e.max_x <= 360.0 && e.min_y >= -90.0 && e.max_y <= 90.0;
    let unnamed_degrees =
        polygons.named_epsg.is_none() && polygons.could_be_degrees() && !dsms_in_degrees_range;
    if !(named_degrees || unnamed_degrees) {
        return Ok(None);
    }
    if !polygons.could_be_degrees() {
        return Err(format!(
            "the polygons name EPSG:{} (longitude and latitude) but reach {:?}, beyond degrees",
            polygons.named_epsg.flatten().unwrap_or(4326),
            polygons.bounds().to_array()
        ));
    }
    let projection = (target.crs.as_ref()).and_then(crate::store::warp::projection_of);
    match projection {
        Some(projection) => Ok(Some(projection)),
        None if named_degrees => Err(format!(
            "the polygons are in longitude and latitude and the DSMs' CRS {} is not a projected CRS dsmstream knows; reproject them (ogr2ogr -t_srs {})",
            target.crs.as_ref().map_or("unknown".to_string(), |c| c.label()),
            target.crs.as_ref().map_or("EPSG:...".to_string(), |c| c.label()),
        )),
        None => Ok(None),
    }
}

/// Longest piece of a polygon edge put into another UTM zone (a straight
/// edge in one zone is a curve in the other, by millimetres over a km).
const MAX_EDGE_M: f64 = 100.0;

/// GeoJSON polygons rasterised on the finest DSM's lattice over the part of
/// the DSMs' extent they cover (coarsened 2x until within [`MAX_MASK_CELLS`]).
fn read_geojson(text: &str, target: &MaskTarget) -> Result<BitRaster, String> {
    let mut polygons = geojson::Polygons::parse(text)?;
    if let Some(projection) = degrees_into(&polygons, target)? {
        polygons = polygons.projected(&projection);
    } else if let (Some(Some(named)), Some(crs)) = (polygons.named_epsg, &target.crs) {
        // polygons in another UTM zone on the datum of the DSMs' zone
        if let Some(into) = crate::store::warp::crs_into(named, crs) {
            polygons = polygons.mapped(|x, y| into.forward(x, y), MAX_EDGE_M);
        }
    }
    if let (Some(named), Some(crs)) = (polygons.named_epsg, &target.crs) {
        if named != crs.epsg || crs.epsg.is_none() {
            let shown = named.map_or("a non-EPSG CRS".to_string(), |c| format!("EPSG:{c}"));
            return Err(format!(
                "the polygons are in {shown}, not in the DSMs' CRS {}; reproject them (ogr2ogr -t_srs {})",
                crs.label(),
                crs.label()
            ));
        }
    }
    let b = polygons.bounds();
    let Some(area) = b.intersection(&target.extent) else {
        return Err(format!(
            "the polygons {:?} cover none of the DSMs {:?} (coordinates in another CRS?)",
            b.to_array(),
            target.extent.to_array()
        ));
    };
    let (placed, w, h) = lattice_over(&area, target.finest);
    Ok(polygons.rasterise(placed, w, h))
}

#[cfg(test)]
mod tests;
