//! DSMs delivered in longitude and latitude (SRTM, Copernicus, ALOS, NASADEM:
//! the global DSMs), and DSMs in another projected CRS (a neighbouring UTM
//! zone, a national or polar grid: [`ProjectedCrs`]), are put into the
//! collection's CRS as they are read, so they register in metres with the
//! rest of it. WGS 84, NAD83 and ETRS89 count as one datum, as PROJ's
//! default transformation between them has it (they differ by 1-2 m, an
//! offset registration estimates); the line of such a DSM says so.
//!
//! One CRS per run ([`choose_target`]): the CRS `--utm-zone` or `--crs` names,
//! else the collection's CRS when [`ProjectedCrs`] knows it (the store's,
//! else the first projected input's), else the UTM zone of the centre of the
//! geographic inputs. Each input in degrees or in
//! another known CRS becomes a [`WarpSource`]: a [`RowSource`] that hands out
//! rows of a north-up grid in the collection's CRS, with square pixels as
//! fine as the source's finer axis there (degrees: two significant digits;
//! another projected CRS: its own pixel), snapped
//! to multiples of the pixel, each pixel the bilinear interpolation of the
//! source at its centre (GDAL's `-r bilinear`; where a neighbour is no-data
//! the weights of the others are used, and a pixel whose nearest source
//! pixel is no-data stays no-data). Heights are not changed: the vertical
//! keys of the source are kept.

use std::path::Path;

use rayon::prelude::*;

use super::ingest::IngestError;
use super::source::{RowSource, SourceError, SourceOpener, SourceRaster};
use crate::geo::proj::{ProjectedCrs, Projection};
use crate::geo::tm::{Datum, Ellipsoid, Utm};
use crate::geo::{Crs, GeoTransform};
use crate::geotiff::equivalent::{code, geographic_datum};

/// Exact inverse projections every this many output columns; linear between
/// (2.3e-4 of a pixel at most for 72 m pixels, the unit test; GDAL's warper
/// allows 0.125 pixel by default).
const KNOT_STEP: usize = 16;
/// Farthest a DSM may reach from the zone's central meridian, degrees of
/// longitude (a UTM zone spans 3; the scale error at 15 degrees is 3.5 %).
const MAX_FROM_MERIDIAN_DEG: f64 = 15.0;
/// UTM's limits of latitude.
const MAX_LATITUDE_DEG: f64 = 84.0;
/// Largest scale error ([`Projection::scale_error`]) over a DSM's footprint
/// put into a CRS other than UTM (3.9 % for NSIDC's polar stereographic at
/// 60 N; UTM reaches 3.5 % at its limit above).
const MAX_SCALE_ERROR: f64 = 0.05;

/// The CRS asked for on the command line: a UTM zone (`--utm-zone 37N`, on
/// the datum of the inputs) or a CRS by its EPSG code (`--crs EPSG:3413`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CrsChoice {
    Zone(ZoneChoice),
    /// A code [`ProjectedCrs::from_epsg`] knows.
    Epsg(u32),
}

impl CrsChoice {
    /// `EPSG:3413`, `epsg:3413` or `3413`, when [`ProjectedCrs`] knows it.
    pub fn parse_epsg(text: &str) -> Option<CrsChoice> {
        let text = text.trim();
        let digits = (text.get(..5))
            .filter(|p| p.eq_ignore_ascii_case("EPSG:"))
            .map_or(text, |_| &text[5..]);
        let code: u32 = digits.parse().ok()?;
        ProjectedCrs::from_epsg(code)?.epsg?;
        Some(CrsChoice::Epsg(code))
    }

    /// The flag that asked for it, as typed ("--utm-zone 37N").
    fn flag(&self) -> String {
        match self {
            CrsChoice::Zone(z) => {
                let hemisphere = if z.north { 'N' } else { 'S' };
                format!("--utm-zone {}{hemisphere}", z.zone)
            }
            CrsChoice::Epsg(code) => format!("--crs EPSG:{code}"),
        }
    }

    /// The CRS, a UTM zone on `datum`.
    fn on(&self, datum: Datum) -> ProjectedCrs {
        match *self {
            CrsChoice::Zone(ZoneChoice { zone, north }) => {
                ProjectedCrs::utm(Utm { datum, zone, north })
            }
            CrsChoice::Epsg(code) => {
                ProjectedCrs::from_epsg(code).expect("a code checked by parse_epsg")
            }
        }
    }
}

/// A UTM zone asked for on the command line: "37N", "33S".
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ZoneChoice {
    pub zone: u8,
    pub north: bool,
}

impl ZoneChoice {
    pub fn parse(text: &str) -> Option<ZoneChoice> {
        let text = text.trim();
        let (digits, hemisphere) = text.split_at(text.len().checked_sub(1)?);
        let north = match hemisphere {
            "N" | "n" => true,
            "S" | "s" => false,
            _ => return None,
        };
        let zone: u8 = digits.parse().ok()?;
        (1..=60)
            .contains(&zone)
            .then_some(ZoneChoice { zone, north })
    }
}

/// The projected CRS [`ProjectedCrs`] knows that `crs` is, by its code.
fn known(crs: &Crs) -> Option<ProjectedCrs> {
    code(crs).and_then(ProjectedCrs::from_epsg)
}

/// The CRS this run puts its inputs in degrees and in other projected CRSs
/// into (a new collection in degrees: the UTM zone of their centre, or UPS
/// North or South beyond 84 degrees), or `None` when no input needs one (none in longitude and latitude on
/// WGS 84, NAD83 or ETRS89, and none in another known CRS than the
/// collection's; others are refused later by the header checks).
///
/// WGS 84, NAD83 and ETRS89 are taken as one datum here, as PROJ's default
/// (ballpark) transformation between them does: they differ by 1-2 m, an
/// offset registration estimates like any other ([`Warped::datum`] says so).
pub(super) fn choose_target(
    collection: Option<&Crs>,
    forced: Option<CrsChoice>,
    paths: &[&Path],
    open: &SourceOpener,
) -> Result<Option<ProjectedCrs>, IngestError> {
    let mut collection = collection.cloned();
    let (mut degrees, mut zones) = (None, Vec::new());
    let (mut lon, mut lat) = (
        (f64::INFINITY, f64::NEG_INFINITY),
        (f64::INFINITY, f64::NEG_INFINITY),
    );
    for path in paths {
        let source = open(path)?;
        let raster = source.raster();
        let Some(d) = geographic_datum(&raster.crs) else {
            if !raster.crs.is_geographic {
                collection.get_or_insert_with(|| raster.crs.clone());
                zones.extend(known(&raster.crs));
            }
            continue;
        };
        degrees.get_or_insert(d);
        let b = raster.geotransform.bounds(raster.width, raster.height);
        lon = (lon.0.min(b[0]), lon.1.max(b[2]));
        lat = (lat.0.min(b[1]), lat.1.max(b[3]));
    }
    let collection_crs = collection.as_ref().and_then(known);
    // the datum a UTM zone asked for is on: the collection's, else the inputs'
    let datum = (collection_crs.as_ref().map(|c| c.datum))
        .or(degrees)
        .or(zones.first().map(|u| u.datum));
    let Some(degrees) = degrees else {
        // no input in degrees: a CRS for the inputs in other known CRSs
        let chosen = match (forced, datum) {
            (Some(choice), Some(datum)) => Some(choice.on(datum)),
            _ => collection_crs,
        };
        let moves = |to: &ProjectedCrs| zones.iter().any(|u| u != to);
        if let Some(choice) = forced.filter(|_| !chosen.as_ref().is_some_and(moves)) {
            tracing::warn!(
                "{} has no effect: no DSM to ingest is in longitude and latitude or in another projected CRS",
                choice.flag()
            );
        }
        return Ok(chosen.filter(moves));
    };
    if let Some(choice) = forced {
        return Ok(Some(choice.on(datum.unwrap_or(degrees))));
    }
    let (lon, lat) = (0.5 * (lon.0 + lon.1), 0.5 * (lat.0 + lat.1));
    Ok(Some(collection_crs.unwrap_or_else(|| {
        if lat.abs() > MAX_LATITUDE_DEG {
            // UPS beyond UTM's latitudes (WGS 84 only, taken as the datum)
            let ups = if lat > 0.0 { 5041 } else { 5042 };
            return ProjectedCrs::from_epsg(ups).expect("UPS is in the table");
        }
        ProjectedCrs::utm(Utm::containing(degrees, lon, lat))
    })))
}

/// The frame a source is put into `target` from, and its datum: longitude
/// and latitude, or another known projected CRS; `None`: the source is read
/// as it is (already in the target CRS, or in a CRS the header checks
/// judge).
fn source_frame(crs: &Crs, target: &ProjectedCrs) -> Option<(Frame, Datum)> {
    if let Some(datum) = geographic_datum(crs) {
        return Some((Frame::Degrees, datum));
    }
    let from = known(crs)?;
    (from != *target).then_some((Frame::Projected(from.projection), from.datum))
}

/// `open`, with sources in longitude and latitude, or in another known
/// projected CRS, on `target`'s datum put into `target`; other sources as
/// they are.
pub(super) fn open_in_target(
    open: &SourceOpener,
    target: Option<&ProjectedCrs>,
    path: &Path,
) -> Result<Box<dyn RowSource>, SourceError> {
    let source = open(path)?;
    match target {
        Some(target) if source_frame(&source.raster().crs, target).is_some() => {
            Ok(Box::new(WarpSource::new(source, target)?))
        }
        _ => Ok(source),
    }
}

/// What a DSM read through a [`WarpSource`] was and became, for the user
/// (kept in the store's catalog).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Warped {
    /// The source's CRS ("EPSG:4326").
    pub from: String,
    /// "EPSG:32637, UTM 37N (WGS 84)".
    pub to: String,
    /// The output pixel (m).
    pub pixel_m: f64,
    /// "WGS 84 taken as NAD83" when the source's datum is not the target's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub datum: Option<String>,
}

/// The frame of a source's geotransform.
#[derive(Clone, Debug)]
pub(crate) enum Frame {
    /// Longitude and latitude, degrees.
    Degrees,
    /// Easting and northing of another projected CRS, metres.
    Projected(Projection),
}

impl Frame {
    /// Longitude and latitude of a point of this frame.
    fn to_lonlat(&self, x: f64, y: f64) -> (f64, f64) {
        match self {
            Frame::Degrees => (x, y),
            Frame::Projected(p) => p.inverse(x, y),
        }
    }

    /// This frame's coordinates of a longitude and latitude.
    fn of_lonlat(&self, lon: f64, lat: f64) -> (f64, f64) {
        match self {
            Frame::Degrees => (lon, lat),
            Frame::Projected(p) => p.forward(lon, lat),
        }
    }
}

/// A source in longitude and latitude, or in another UTM zone, read as a
/// grid in a UTM zone.
pub struct WarpSource {
    inner: Box<dyn RowSource>,
    raster: SourceRaster,
    mapping: Mapping,
    source_size: (u64, u64),
    warped: Warped,
    /// Source rows of the last read (first row, values).
    rows: (u64, Vec<f32>),
}

impl WarpSource {
    pub fn new(
        inner: Box<dyn RowSource>,
        target: &ProjectedCrs,
    ) -> Result<WarpSource, SourceError> {
        let src = inner.raster().clone();
        let bad = |message: String| SourceError {
            message: format!("{}: {message}", src.path.display()),
            bad_input: true,
        };
        let code = target.epsg.ok_or_else(|| {
            bad(format!(
                "{} has no EPSG code to put this DSM into; choose another zone (--utm-zone) or reproject first",
                target.label()
            ))
        })?;
        let (frame, datum) = source_frame(&src.crs, target).ok_or_else(|| {
            bad(format!(
                "CRS {} is neither longitude and latitude nor another projected CRS dsmstream knows",
                src.crs.label(),
            ))
        })?;
        let gt = src.geotransform;
        within_reach(&frame, &gt, (src.width, src.height), target).map_err(bad)?;
        let crs = crate::geotiff::geokeys::projected_crs(code, &src.crs).ok_or_else(|| {
            bad(format!(
                "cannot describe {} as GeoTIFF keys",
                target.label()
            ))
        })?;
        let projection = &target.projection;
        let ellipsoid = target.datum.ellipsoid();
        let (grid, width, height) =
            output_grid(projection, &frame, &gt, (src.width, src.height), ellipsoid);
        let warped = Warped {
            from: src.crs.label(),
            to: target.label(),
            pixel_m: grid.gsd_x(),
            datum: (datum != target.datum)
                .then(|| format!("{} taken as {}", datum.name(), target.datum.name())),
        };
        let raster = SourceRaster {
            width,
            height,
            geotransform: grid,
            crs,
            ..src.clone()
        };
        let mapping = Mapping::new(projection.clone(), grid, width as usize, gt, src.width)
            .in_frame(frame, src.width);
        Ok(WarpSource {
            inner,
            raster,
            mapping,
            source_size: (src.width, src.height),
            warped,
            rows: (0, Vec::new()),
        })
    }
}

/// Whether a raster's footprint (placed by `gt` in `frame`) can be put into
/// `target`: for a UTM zone, latitudes within [`MAX_LATITUDE_DEG`] and
/// longitudes within [`MAX_FROM_MERIDIAN_DEG`] of its meridian; for another
/// CRS, a scale error within [`MAX_SCALE_ERROR`] all along its edges.
fn within_reach(
    frame: &Frame,
    gt: &GeoTransform,
    (width, height): (u64, u64),
    target: &ProjectedCrs,
) -> Result<(), String> {
    let [lon0, lat0, lon1, lat1] = lonlat_bounds(frame, gt, width, height);
    let finite = [lon0, lat0, lon1, lat1].iter().all(|v| v.is_finite());
    let footprint = format!(
        "its footprint (longitude {lon0:.4} to {lon1:.4}, latitude {lat0:.4} to {lat1:.4}) cannot be put into {}",
        target.label()
    );
    let Some(zone) = target.utm else {
        let ellipsoid = target.datum.ellipsoid();
        let mut worst = if gt.is_north_up() && finite {
            0.0_f64
        } else {
            f64::INFINITY
        };
        for_edge_points(gt, width, height, |x, y| {
            let (lon, lat) = frame.to_lonlat(x, y);
            let error = target.projection.scale_error(ellipsoid, lon, lat);
            worst = worst.max(if error.is_finite() {
                error
            } else {
                f64::INFINITY
            });
        });
        if worst <= MAX_SCALE_ERROR {
            return Ok(());
        }
        let percent = 100.0 * MAX_SCALE_ERROR;
        return Err(format!(
            "{footprint}: its scale there is off by more than {percent} % (the CRS is not meant for this place); reproject first (gdalwarp -t_srs EPSG:...)"
        ));
    };
    let meridian = -183.0 + 6.0 * f64::from(zone.zone);
    let centre_lon = 0.5 * (lon0 + lon1);
    let from_meridian =
        ((centre_lon - meridian + 540.0).rem_euclid(360.0) - 180.0).abs() + 0.5 * (lon1 - lon0);
    if !(gt.is_north_up() && finite)
        || lat0 < -MAX_LATITUDE_DEG
        || lat1 > MAX_LATITUDE_DEG
        || from_meridian > MAX_FROM_MERIDIAN_DEG
    {
        return Err(format!(
            "{footprint}: UTM needs latitudes within {MAX_LATITUDE_DEG} degrees and longitudes within {MAX_FROM_MERIDIAN_DEG} degrees of the zone's central meridian {meridian}; choose the zone (--utm-zone) or reproject first (gdalwarp -t_srs EPSG:...)"
        ));
    }
    Ok(())
}

/// Where each output pixel's centre falls in the source.
pub(crate) struct Mapping {
    projection: Projection,
    /// The output grid (in `projection`) and its width.
    grid: GeoTransform,
    width: usize,
    /// The source's geotransform (degrees).
    source_gt: GeoTransform,
    /// Longitude of the source's centre: inverse longitudes are taken within
    /// 180 degrees of it (a source in 0..360 longitudes).
    centre_lon: f64,
    /// The frame of `source_gt`.
    frame: Frame,
}

impl Mapping {
    /// The mapping of `grid` (`width` cells across, in `projection`'s metres)
    /// into a raster in degrees placed by `source_gt` (see
    /// [`Mapping::in_frame`]).
    fn new(
        projection: Projection,
        grid: GeoTransform,
        width: usize,
        source_gt: GeoTransform,
        source_width: u64,
    ) -> Mapping {
        let centre_lon = source_gt.pixel_to_world(0.5 * source_width as f64, 0.0).0;
        Mapping {
            projection,
            grid,
            width,
            source_gt,
            centre_lon,
            frame: Frame::Degrees,
        }
    }

    /// The same mapping into a raster whose `source_gt` is in `frame`.
    fn in_frame(mut self, frame: Frame, source_width: u64) -> Mapping {
        let (x, y) = (self.source_gt).pixel_to_world(0.5 * source_width as f64, 0.0);
        self.centre_lon = frame.to_lonlat(x, y).0;
        self.frame = frame;
        self
    }

    /// Source pixel positions (column, row; pixel centres at whole numbers)
    /// of output row `row`'s pixel centres: exact every [`KNOT_STEP`]
    /// columns, linear between.
    pub(crate) fn positions(&self, row: u64, out: &mut Vec<(f64, f64)>) {
        let (width, gt) = (self.width, &self.grid);
        let knots = width.div_ceil(KNOT_STEP) + 1;
        let knot: Vec<(f64, f64)> = (0..knots)
            .map(|k| {
                let (e, n) = gt.pixel_to_world((k * KNOT_STEP) as f64 + 0.5, row as f64 + 0.5);
                let (lon, lat) = self.projection.inverse(e, n);
                let lon = lon + 360.0 * ((self.centre_lon - lon) / 360.0).round();
                let (x, y) = self.frame.of_lonlat(lon, lat);
                let (u, v) = self.source_gt.world_to_pixel(x, y);
                (u - 0.5, v - 0.5)
            })
            .collect();
        out.clear();
        out.extend((0..width).map(|c| {
            let (k, t) = (c / KNOT_STEP, (c % KNOT_STEP) as f64 / KNOT_STEP as f64);
            let (a, b) = (knot[k], knot[k + 1]);
            (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1))
        }));
    }
}

/// The output grid of a source in longitude and latitude, or in another
/// projected CRS: square pixels of the source's finer axis at its centre
/// (degrees: two significant digits; metres: the source's own), the
/// projected footprint snapped outwards to multiples of the pixel.
fn output_grid(
    projection: &Projection,
    frame: &Frame,
    gt: &GeoTransform,
    (width, height): (u64, u64),
    ellipsoid: Ellipsoid,
) -> (GeoTransform, u64, u64) {
    let pixel = match frame {
        Frame::Degrees => {
            let [_, lat0, _, lat1] = gt.bounds(width, height);
            let per = ellipsoid.metres_per_degree(0.5 * (lat0 + lat1));
            round_to_two_digits((gt.gsd_x() * per.0).min(gt.gsd_y() * per.1))
        }
        Frame::Projected(_) => gt.gsd_x().min(gt.gsd_y()),
    };
    let [e0, n0, e1, n1] = footprint_in(projection, frame, gt, width, height);
    let (x0, y1) = ((e0 / pixel).floor() * pixel, (n1 / pixel).ceil() * pixel);
    let w = ((e1 - x0) / pixel).ceil().max(1.0) as u64;
    let h = ((y1 - n0) / pixel).ceil().max(1.0) as u64;
    (GeoTransform::north_up(x0, y1, pixel, pixel), w, h)
}

/// The box of the longitudes and latitudes of a raster's footprint in
/// `frame` (its edges at [`EDGE_POINTS`] points each).
fn lonlat_bounds(frame: &Frame, gt: &GeoTransform, width: u64, height: u64) -> [f64; 4] {
    match frame {
        Frame::Degrees => gt.bounds(width, height),
        Frame::Projected(_) => edge_box(gt, width, height, |x, y| frame.to_lonlat(x, y)),
    }
}

/// The box of `f` over the edges of a raster's footprint ([`EDGE_POINTS`]
/// points each).
fn edge_box(
    gt: &GeoTransform,
    width: u64,
    height: u64,
    f: impl Fn(f64, f64) -> (f64, f64),
) -> [f64; 4] {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for_edge_points(gt, width, height, |u, v| {
        let (p, q) = f(u, v);
        b = [b[0].min(p), b[1].min(q), b[2].max(p), b[3].max(q)];
    });
    b
}

/// `f` at [`EDGE_POINTS`] + 1 points along each edge of a raster's footprint.
fn for_edge_points(gt: &GeoTransform, width: u64, height: u64, mut f: impl FnMut(f64, f64)) {
    let [x0, y0, x1, y1] = gt.bounds(width, height);
    for i in 0..=EDGE_POINTS {
        let t = i as f64 / EDGE_POINTS as f64;
        let (x, y) = (x0 + t * (x1 - x0), y0 + t * (y1 - y0));
        for (u, v) in [(x, y0), (x, y1), (x0, y), (x1, y)] {
            f(u, v);
        }
    }
}

/// Points per edge at which footprints are projected.
const EDGE_POINTS: usize = 64;

/// The box (min E, min N, max E, max N) holding the projected footprint of a
/// raster in `frame`.
fn footprint_in(
    projection: &Projection,
    frame: &Frame,
    gt: &GeoTransform,
    width: u64,
    height: u64,
) -> [f64; 4] {
    edge_box(gt, width, height, |x, y| {
        let (lon, lat) = frame.to_lonlat(x, y);
        projection.forward(lon, lat)
    })
}

/// How a raster in longitude and latitude, or in another projected CRS, is
/// put into a collection's CRS ([`projection_into`]): for `eval --reference`
/// and masks, which project points and sample rasters without ingesting
/// them.
#[derive(Clone, Debug)]
pub struct IntoCrs {
    projection: Projection,
    frame: Frame,
}

impl IntoCrs {
    /// The collection CRS's coordinates of a point of the raster's frame.
    pub fn forward(&self, x: f64, y: f64) -> (f64, f64) {
        let (lon, lat) = self.frame.to_lonlat(x, y);
        self.projection.forward(lon, lat)
    }

    /// The box (min E, min N, max E, max N) in the zone holding the footprint
    /// of a raster placed by `gt` (its edges at [`EDGE_POINTS`] points each).
    pub fn bounds(&self, gt: &GeoTransform, width: u64, height: u64) -> [f64; 4] {
        footprint_in(&self.projection, &self.frame, gt, width, height)
    }

    /// Where the cell centres of `grid` (`width` cells across, in the zone)
    /// fall in the raster placed by `source_gt`.
    pub(crate) fn mapping(
        &self,
        grid: GeoTransform,
        width: usize,
        source_gt: GeoTransform,
        source_width: u64,
    ) -> Mapping {
        Mapping::new(
            self.projection.clone(),
            grid,
            width,
            source_gt,
            source_width,
        )
        .in_frame(self.frame.clone(), source_width)
    }
}

/// How a raster in `crs` is put into `collection`'s CRS: `Some` when
/// [`ProjectedCrs`] knows `collection` and `crs` is longitude and latitude
/// (WGS 84, NAD83 or ETRS89) or another known CRS.
pub fn projection_into(crs: &Crs, collection: &Crs) -> Option<IntoCrs> {
    let target = known(collection)?;
    let (frame, _) = source_frame(crs, &target)?;
    Some(IntoCrs {
        projection: target.projection,
        frame,
    })
}

/// How coordinates of the CRS whose EPSG code is `epsg` are put into
/// `collection`'s CRS: `Some` when [`ProjectedCrs`] knows both and they
/// differ (a mask's polygons that name their CRS by code).
pub fn crs_into(epsg: u32, collection: &Crs) -> Option<IntoCrs> {
    let from = ProjectedCrs::from_epsg(epsg)?;
    let target = known(collection)?;
    (from != target).then_some(IntoCrs {
        projection: target.projection,
        frame: Frame::Projected(from.projection),
    })
}

/// The projection of `collection`'s CRS when [`ProjectedCrs`] knows it (to
/// put longitudes and latitudes into it).
pub fn projection_of(collection: &Crs) -> Option<Projection> {
    known(collection).map(|target| target.projection)
}

/// `x` rounded to two significant digits (71.4 -> 71, 0.926 -> 0.93).
fn round_to_two_digits(x: f64) -> f64 {
    let scale = 10f64.powf(x.log10().floor() - 1.0);
    (x / scale).round() * scale
}

impl RowSource for WarpSource {
    fn raster(&self) -> &SourceRaster {
        &self.raster
    }

    fn warped(&self) -> Option<Warped> {
        Some(self.warped.clone())
    }

    fn read_rows(&mut self, row0: u64, rows: u64) -> Result<Vec<f32>, SourceError> {
        let (sw, sh) = (self.source_size.0 as usize, self.source_size.1);
        let width = self.raster.width as usize;
        // the source rows this block reads: its first and last rows' extremes
        // (parallels curve, so the knots of both rows are looked at)
        let mut positions = Vec::with_capacity(width);
        let (mut vmin, mut vmax) = (f64::INFINITY, f64::NEG_INFINITY);
        for row in [row0, row0 + rows.max(1) - 1] {
            self.mapping.positions(row, &mut positions);
            for &(_, v) in &positions {
                (vmin, vmax) = (vmin.min(v), vmax.max(v));
            }
        }
        let first = (vmin.floor() - 1.0).clamp(0.0, sh as f64) as u64;
        let last = (vmax.ceil() + 2.0).clamp(0.0, sh as f64) as u64;
        if last > first {
            let (at, data) = &mut self.rows;
            let held = *at <= first && *at + (data.len() / sw.max(1)) as u64 >= last;
            if !held {
                self.inner.read_rows_into(first, last - first, data)?;
                *at = first;
            }
        }
        let (at, data) = (&self.rows.0, &self.rows.1);
        let held_rows = (data.len() / sw.max(1)) as i64;
        let sample = |i: i64, j: i64| -> Option<f32> {
            let j = j - *at as i64;
            if i < 0 || i >= sw as i64 || j < 0 || j >= held_rows {
                return None;
            }
            Some(data[j as usize * sw + i as usize]).filter(|z| z.is_finite())
        };
        // rows in parallel, each on its own: the same values on any thread count
        let mut out = vec![0.0; width * rows as usize];
        let mapping = &self.mapping;
        (out.par_chunks_mut(width.max(1)).enumerate()).for_each_init(
            Vec::new,
            |positions, (k, row)| {
                mapping.positions(row0 + k as u64, positions);
                for (z, &(u, v)) in row.iter_mut().zip(positions.iter()) {
                    *z = bilinear(&sample, u, v);
                }
            },
        );
        Ok(out)
    }
}

/// The bilinear interpolation at (u, v) (pixel centres at whole numbers) of
/// the valid neighbours, renormalised; no-data when the nearest is no-data.
fn bilinear(sample: &impl Fn(i64, i64) -> Option<f32>, u: f64, v: f64) -> f32 {
    if sample(u.round() as i64, v.round() as i64).is_none() {
        return f32::NAN;
    }
    let (i, j) = (u.floor(), v.floor());
    let (fx, fy) = (u - i, v - j);
    let (i, j) = (i as i64, j as i64);
    let (mut sum, mut weight) = (0.0, 0.0);
    for (di, dj, w) in [
        (0, 0, (1.0 - fx) * (1.0 - fy)),
        (1, 0, fx * (1.0 - fy)),
        (0, 1, (1.0 - fx) * fy),
        (1, 1, fx * fy),
    ] {
        if let Some(z) = sample(i + di, j + dj) {
            sum += w * f64::from(z);
            weight += w;
        }
    }
    (sum / weight) as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::source::MemSource;
    use std::path::PathBuf;

    fn geographic(lon0: f64, lat1: f64, deg: f64, w: u64, h: u64, data: Vec<f32>) -> MemSource {
        let crs = crate::geotiff::geokeys::crs_from_entries(vec![
            (1024, crate::geotiff::geokeys::GeoKeyValue::Short(2)),
            (2048, crate::geotiff::geokeys::GeoKeyValue::Short(4326)),
        ])
        .unwrap();
        MemSource {
            raster: SourceRaster {
                path: PathBuf::from("geo.tif"),
                width: w,
                height: h,
                geotransform: GeoTransform::north_up(lon0, lat1, deg, deg),
                crs,
                nodata: None,
                dtype: "Int16".into(),
                height_unit: None,
                georeferenced_by: Vec::new(),
            },
            data,
        }
    }

    #[test]
    fn zone_choices_parse() {
        assert_eq!(
            ZoneChoice::parse("37N"),
            Some(ZoneChoice {
                zone: 37,
                north: true
            })
        );
        assert_eq!(
            ZoneChoice::parse("1s"),
            Some(ZoneChoice {
                zone: 1,
                north: false
            })
        );
        for bad in ["", "N", "0N", "61N", "37", "37X", "-3N"] {
            assert_eq!(ZoneChoice::parse(bad), None, "{bad}");
        }
    }

    #[test]
    fn pixels_round_to_two_digits() {
        assert_eq!(round_to_two_digits(71.4), 71.0);
        assert!((round_to_two_digits(0.926) - 0.93).abs() < 1e-12);
        assert_eq!(round_to_two_digits(23.72), 24.0);
        assert_eq!(round_to_two_digits(105.0), 110.0);
    }

    /// A plane in longitude and latitude is a plane in UTM too (nearly, over
    /// a few kilometres): the warped heights are the plane at each output
    /// pixel's own longitude and latitude, and the knots' interpolation is
    /// exact to a thousandth of a pixel.
    #[test]
    fn a_plane_is_resampled_at_each_pixels_own_position() {
        let (w, h, deg) = (120u64, 90u64, 1.0 / 1200.0);
        let (lon0, lat1) = (40.3, 39.7);
        let plane = |lon: f64, lat: f64| 1000.0 + 5000.0 * (lon - lon0) - 3000.0 * (lat - lat1);
        let data = (0..h)
            .flat_map(|r| (0..w).map(move |c| (r, c)))
            .map(|(r, c)| {
                plane(lon0 + (c as f64 + 0.5) * deg, lat1 - (r as f64 + 0.5) * deg) as f32
            })
            .collect();
        let zone = Utm::from_epsg(32637).unwrap();
        let mut warp = WarpSource::new(
            Box::new(geographic(lon0, lat1, deg, w, h, data)),
            &ProjectedCrs::utm(zone),
        )
        .unwrap();
        let r = warp.raster().clone();
        assert_eq!(r.crs.epsg, Some(32637));
        // 3" pixels at 39.66 N: 71.5 m across, 92.5 m along the meridian
        assert_eq!(r.geotransform.gsd_x(), 72.0);
        assert_eq!(r.geotransform.0[0] % 72.0, 0.0);
        let values = warp.read_rows(0, r.height).unwrap();
        let tm = zone.projection();
        let (mut inside, mut worst_pos) = (0, 0.0f64);
        let mut positions = Vec::new();
        for row in 0..r.height {
            warp.mapping.positions(row, &mut positions);
            for col in 0..r.width {
                let (e, n) = r
                    .geotransform
                    .pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
                let (lon, lat) = tm.inverse(e, n);
                let (u, v) = ((lon - lon0) / deg - 0.5, (lat1 - lat) / deg - 0.5);
                let got = positions[col as usize];
                worst_pos = worst_pos.max((got.0 - u).abs()).max((got.1 - v).abs());
                let z = values[(row * r.width + col) as usize];
                let interior = u > 0.0 && v > 0.0 && u < (w - 1) as f64 && v < (h - 1) as f64;
                if interior {
                    inside += 1;
                    assert!(
                        (f64::from(z) - plane(lon, lat)).abs() < 1e-3,
                        "({col}, {row}): {z} against {}",
                        plane(lon, lat)
                    );
                }
                let outside = u < -0.5 || v < -0.5 || u > w as f64 - 0.5 || v > h as f64 - 0.5;
                if outside {
                    assert!(z.is_nan(), "({col}, {row}) outside the source: {z}");
                }
            }
        }
        assert!(worst_pos < 1e-3, "knot interpolation off by {worst_pos} px");
        assert!(inside as u64 > r.width * r.height / 2);
        // read in blocks of 7 rows: the same values
        let mut blocks = Vec::new();
        let mut row0 = 0;
        while row0 < r.height {
            let rows = 7.min(r.height - row0);
            blocks.extend(warp.read_rows(row0, rows).unwrap());
            row0 += rows;
        }
        let same = blocks
            .iter()
            .zip(&values)
            .all(|(a, b)| a.to_bits() == b.to_bits());
        assert!(same && blocks.len() == values.len());
        // and on one thread
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let alone = one.install(|| warp.read_rows(0, r.height).unwrap());
        assert!(alone
            .iter()
            .zip(&values)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }

    /// A DSM in UTM 37N near the zone's eastern edge put into 38N (a
    /// collection across the boundary): a plane in 37N's metres comes out as
    /// that plane at each 38N pixel's own position (bilinear is exact on a
    /// plane), at the source's own 30 m pixel, snapped.
    /// A plane in the projected CRS `from` (30 m pixels, its north-west
    /// corner at `corner` degrees) put into `to`: each output pixel is the
    /// plane at its own centre's position in `from`, and no-data outside.
    fn a_plane_between_crss(from: u32, to: u32, corner: (f64, f64)) {
        let (w, h, px) = (200u64, 150u64, 30.0);
        let proj_from = ProjectedCrs::from_epsg(from).unwrap().projection;
        let (e0, n1) = proj_from.forward(corner.0, corner.1);
        let (e0, n1) = ((e0 / px).round() * px, (n1 / px).round() * px);
        let plane = |e: f64, n: f64| 1000.0 + 0.05 * (e - e0) - 0.03 * (n - n1);
        let data = (0..h)
            .flat_map(|r| (0..w).map(move |c| (r, c)))
            .map(|(r, c)| plane(e0 + (c as f64 + 0.5) * px, n1 - (r as f64 + 0.5) * px) as f32)
            .collect();
        let code = crate::geotiff::geokeys::GeoKeyValue::Short(from as u16);
        let crs = crate::geotiff::geokeys::crs_from_entries(vec![
            (1024, crate::geotiff::geokeys::GeoKeyValue::Short(1)),
            (3072, code),
        ])
        .unwrap();
        let mut source = geographic(e0, n1, px, w, h, data);
        source.raster.crs = crs;
        let target = ProjectedCrs::from_epsg(to).unwrap();
        assert!(
            source_frame(&source.raster.crs, &ProjectedCrs::from_epsg(from).unwrap()).is_none(),
            "its own CRS"
        );
        let mut warp = WarpSource::new(Box::new(source), &target).unwrap();
        let r = warp.raster().clone();
        assert_eq!(r.crs.epsg, Some(to));
        assert_eq!(r.geotransform.gsd_x(), 30.0);
        assert_eq!(r.geotransform.0[0] % 30.0, 0.0);
        assert_eq!(warp.warped().unwrap().from, format!("EPSG:{from}"));
        let values = warp.read_rows(0, r.height).unwrap();
        let mut inside = 0;
        for row in 0..r.height {
            for col in 0..r.width {
                let (e, n) = (r.geotransform).pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
                let (lon, lat) = target.projection.inverse(e, n);
                let (x, y) = proj_from.forward(lon, lat);
                let (u, v) = ((x - e0) / px - 0.5, (n1 - y) / px - 0.5);
                let z = values[(row * r.width + col) as usize];
                if u > 0.0 && v > 0.0 && u < (w - 1) as f64 && v < (h - 1) as f64 {
                    inside += 1;
                    let want = plane(x, y);
                    assert!(
                        (f64::from(z) - want).abs() < 2e-3,
                        "EPSG:{from} to {to} ({col}, {row}): {z} / {want}"
                    );
                } else if u < -0.5 || v < -0.5 || u > w as f64 - 0.5 || v > h as f64 - 0.5 {
                    assert!(z.is_nan(), "({col}, {row}) outside the source: {z}");
                }
            }
        }
        // the grid is turned by the two CRSs' convergences: a box around it
        assert!(inside as u64 > r.width * r.height * 4 / 10, "{inside}");
    }

    #[test]
    fn a_neighbouring_zone_is_put_into_the_zone_at_each_pixels_position() {
        // 1.6 and -2.2 degrees of convergence
        a_plane_between_crss(32637, 32638, (41.5, 39.7));
    }

    #[test]
    fn utm_and_polar_and_national_grids_are_put_into_one_another() {
        // Svalbard: UTM 33N into NSIDC's polar stereographic (turned by 60
        // degrees) and back; Arctic polar stereographic into it
        a_plane_between_crss(32633, 3413, (15.5, 78.2));
        a_plane_between_crss(3413, 32633, (15.5, 78.2));
        a_plane_between_crss(3995, 3413, (15.5, 78.2));
        // France: ETRS89 / UTM 31N into Lambert-93; LAEA Europe into it
        a_plane_between_crss(25831, 2154, (2.3, 48.9));
        a_plane_between_crss(3035, 2154, (2.3, 48.9));
        // Antarctica; the United States
        a_plane_between_crss(32758, 3031, (166.7, -77.8));
        a_plane_between_crss(26913, 5070, (-105.3, 40.0));
    }

    #[test]
    fn wgs84_nad83_and_etrs89_count_as_one_datum_and_others_do_not() {
        let projected = |code: u16| {
            crate::geotiff::geokeys::crs_from_entries(vec![
                (1024, crate::geotiff::geokeys::GeoKeyValue::Short(1)),
                (3072, crate::geotiff::geokeys::GeoKeyValue::Short(code)),
            ])
            .unwrap()
        };
        let lambert93 = ProjectedCrs::from_epsg(2154).unwrap();
        let (_, datum) = source_frame(&projected(32631), &lambert93).unwrap();
        assert_eq!(datum, Datum::Wgs84);
        // the same zone on another of the three: put into it, said
        let nad83 = ProjectedCrs::from_epsg(26917).unwrap();
        let (w, h, px) = (20u64, 20u64, 10.0);
        let mut source = geographic(500_000.0, 4_800_000.0, px, w, h, vec![7.0; 400]);
        source.raster.crs = projected(32617);
        let warp = WarpSource::new(Box::new(source), &nad83).unwrap();
        let said = warp.warped().unwrap();
        assert_eq!(said.datum.as_deref(), Some("WGS 84 taken as NAD83"));
        // ED50 / UTM 31N and NAD83(CSRS) / UTM 17N are not
        assert!(source_frame(&projected(23031), &lambert93).is_none());
        assert!(source_frame(&projected(2958), &nad83).is_none());
    }

    #[test]
    fn no_data_stays_where_it_is_nearest() {
        let (w, h, deg) = (40u64, 40u64, 1.0 / 1200.0);
        let data: Vec<f32> = (0..w * h)
            .map(|k| if k % w < 20 { f32::NAN } else { 50.0 })
            .collect();
        let zone = ProjectedCrs::from_epsg(32637).unwrap();
        let mut warp =
            WarpSource::new(Box::new(geographic(40.0, 39.0, deg, w, h, data)), &zone).unwrap();
        let r = warp.raster().clone();
        let values = warp.read_rows(0, r.height).unwrap();
        let valid: Vec<f32> = values.iter().copied().filter(|z| z.is_finite()).collect();
        assert!(!valid.is_empty() && valid.iter().all(|&z| z == 50.0));
        let share = valid.len() as f64 / values.len() as f64;
        assert!((0.3..0.6).contains(&share), "valid share {share}");
    }

    #[test]
    fn footprints_utm_cannot_hold_are_refused_by_name() {
        let zone = ProjectedCrs::from_epsg(32637).unwrap();
        let far = geographic(80.0, 40.0, 0.01, 10, 10, vec![1.0; 100]);
        let err = WarpSource::new(Box::new(far), &zone).err().unwrap();
        assert!(
            err.bad_input && err.message.starts_with("geo.tif: its footprint"),
            "{}",
            err.message
        );
        let polar = geographic(39.0, 89.0, 0.01, 10, 10, vec![1.0; 100]);
        assert!(WarpSource::new(Box::new(polar), &zone).is_err());
    }

    #[test]
    fn footprints_a_polar_or_national_grid_cannot_hold_are_refused_by_name() {
        // the tropics into NSIDC's north polar stereographic; southern France
        // is fine in Lambert-93, Brazil is not in LAEA Europe
        let on_datum = |mut source: MemSource, datum: Datum| {
            let geographic = match datum {
                Datum::Etrs89 => 4258,
                _ => 4326,
            };
            source.raster.crs = crate::geotiff::geokeys::crs_from_entries(vec![
                (1024, crate::geotiff::geokeys::GeoKeyValue::Short(2)),
                (
                    2048,
                    crate::geotiff::geokeys::GeoKeyValue::Short(geographic),
                ),
            ])
            .unwrap();
            source
        };
        for (code, lon, lat) in [(3413, 40.0, 10.0), (3035, -50.0, -10.0), (3031, 0.0, 60.0)] {
            let target = ProjectedCrs::from_epsg(code).unwrap();
            let far = on_datum(
                geographic(lon, lat, 0.01, 10, 10, vec![1.0; 100]),
                target.datum,
            );
            let err = WarpSource::new(Box::new(far), &target).err().unwrap();
            assert!(
                err.bad_input
                    && err.message.starts_with("geo.tif: its footprint")
                    && err.message.contains("scale there is off by more than 5 %"),
                "{}",
                err.message
            );
        }
        let lambert93 = ProjectedCrs::from_epsg(2154).unwrap();
        let nice = on_datum(
            geographic(7.2, 43.8, 0.001, 10, 10, vec![1.0; 100]),
            Datum::Etrs89,
        );
        assert!(WarpSource::new(Box::new(nice), &lambert93).is_ok());
    }
}
