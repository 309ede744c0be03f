//! A GDAL VRT mosaic of GeoTIFFs as one ingest source (one DSM, its id the
//! VRT's stem). Only what places GeoTIFF pixels unchanged is accepted: a
//! `VRTDataset` (no `subClass`: no warping, no pansharpening) with a north-up
//! `GeoTransform` and one `VRTRasterBand` of `SimpleSource`s or
//! `ComplexSource`s, each band 1 of a GeoTIFF, with integer `SrcRect` and
//! `DstRect` of equal size (no resampling), the VRT's pixel size and the same
//! CRS as the other sources. Anything else (scaling, LUTs, masks, kernels,
//! other drivers or `/vsi` paths, more bands) is refused with one line naming
//! the file and the element.
//!
//! Pixels are composed as GDAL does for sources without scaling: in file
//! order, a later source's valid pixels overwrite earlier ones; no-data (the
//! source's own, a ComplexSource's `NODATA`, the band's `NoDataValue`) never
//! overwrites. Rows are read from each source only where its `DstRect` meets
//! the requested rows, so memory stays a block row per source (each source
//! is a [`GeoTiffSource`], which maps its file afresh as it streams).

use std::path::{Path, PathBuf};

use super::source::{open_geotiff, GeoTiffSource, RowSource, SourceError, SourceRaster};
use crate::raster::{Crs, GeoTransform};

mod xml;
use xml::Element;

/// Relative tolerance on pixel sizes (VRT text vs the sources' tags).
const GSD_TOLERANCE: f64 = 1e-6;

/// Opens `*.vrt` as a [`VrtSource`], anything else as a GeoTIFF.
pub fn open_input(path: &Path) -> Result<Box<dyn RowSource>, SourceError> {
    let is_vrt = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vrt"));
    if is_vrt {
        Ok(Box::new(VrtSource::open(path)?))
    } else {
        open_geotiff(path)
    }
}

/// A pixel rectangle (offsets and sizes in pixels).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelRect {
    pub x_off: i64,
    pub y_off: i64,
    pub x_size: u64,
    pub y_size: u64,
}

/// One GeoTIFF placed in the mosaic.
pub struct PlacedSource {
    pub path: PathBuf,
    reader: GeoTiffSource,
    pub src: PixelRect,
    pub dst: PixelRect,
    /// A ComplexSource's `NODATA`: source pixels equal to it are no-data.
    pub nodata: Option<f64>,
}

/// A VRT mosaic read a block of rows at a time.
pub struct VrtSource {
    raster: SourceRaster,
    sources: Vec<PlacedSource>,
    /// The band's `NoDataValue`.
    band_nodata: Option<f64>,
}

fn refuse(path: &Path, what: impl std::fmt::Display) -> SourceError {
    SourceError {
        message: format!("{}: {what}", path.display()),
        bad_input: true,
    }
}

impl VrtSource {
    /// Parse the VRT, open and check every source.
    pub fn open(path: &Path) -> Result<VrtSource, SourceError> {
        let text = std::fs::read_to_string(path).map_err(|e| SourceError {
            message: format!("{}: cannot read VRT: {e}", path.display()),
            bad_input: e.kind() == std::io::ErrorKind::NotFound,
        })?;
        let root = xml::parse(&text).map_err(|e| refuse(path, format!("not valid XML: {e}")))?;
        let spec = DatasetSpec::from_xml(path, &root)?;
        let mut sources = Vec::with_capacity(spec.sources.len());
        for s in spec.sources {
            sources.push(open_placed(path, s, &spec.geotransform)?);
        }
        let first = sources
            .first()
            .ok_or_else(|| refuse(path, "<VRTRasterBand> has no source"))?;
        let crs = first.reader.raster().crs.clone();
        check_same_crs(path, &crs, &sources)?;
        let raster = SourceRaster {
            path: path.to_path_buf(),
            width: spec.width,
            height: spec.height,
            geotransform: spec.geotransform,
            crs,
            nodata: spec.band_nodata.or(first.reader.raster().nodata),
            dtype: spec.data_type,
        };
        Ok(VrtSource {
            raster,
            sources,
            band_nodata: spec.band_nodata,
        })
    }

    /// The placed sources, in file order.
    pub fn sources(&self) -> &[PlacedSource] {
        &self.sources
    }
}

/// What the XML says, before any source is opened.
struct DatasetSpec {
    width: u64,
    height: u64,
    geotransform: GeoTransform,
    band_nodata: Option<f64>,
    data_type: String,
    sources: Vec<SourceSpec>,
}

struct SourceSpec {
    /// Element name, for messages.
    kind: String,
    path: PathBuf,
    src: PixelRect,
    dst: PixelRect,
    nodata: Option<f64>,
}

/// Dataset children taken (SRS: the CRS is read from the GeoTIFFs) or ignored.
const DATASET_CHILDREN: &[&str] = &["SRS", "GeoTransform", "VRTRasterBand", "Metadata"];
/// Band children taken or ignored.
const BAND_CHILDREN: &[&str] = &[
    "NoDataValue",
    "ColorInterp",
    "Description",
    "UnitType",
    "Metadata",
    "SimpleSource",
    "ComplexSource",
];
/// Source children taken or ignored.
const SOURCE_CHILDREN: &[&str] = &[
    "SourceFilename",
    "SourceBand",
    "SourceProperties",
    "SrcRect",
    "DstRect",
    "NODATA",
];

fn only_known(path: &Path, parent: &Element, known: &[&str]) -> Result<(), SourceError> {
    match parent.children.iter().find(|c| !known.contains(&c.name.as_str())) {
        Some(c) => Err(refuse(
            path,
            format!(
                "<{}> inside <{}> is not supported (only GeoTIFF mosaics without resampling, scaling or masks)",
                c.name, parent.name
            ),
        )),
        None => Ok(()),
    }
}

impl DatasetSpec {
    fn from_xml(path: &Path, root: &Element) -> Result<DatasetSpec, SourceError> {
        if root.name != "VRTDataset" {
            return Err(refuse(
                path,
                format!("root element <{}> is not <VRTDataset>", root.name),
            ));
        }
        if let Some(sub) = root.attr("subClass") {
            return Err(refuse(
                path,
                format!(
                    "<VRTDataset subClass=\"{sub}\"> (warped or derived VRTs) is not supported"
                ),
            ));
        }
        only_known(path, root, DATASET_CHILDREN)?;
        let width = size_attr(path, root, "rasterXSize")?;
        let height = size_attr(path, root, "rasterYSize")?;
        let geotransform = parse_geotransform(path, root)?;
        let bands: Vec<&Element> = root.children_named("VRTRasterBand").collect();
        let [band] = bands[..] else {
            return Err(refuse(
                path,
                format!(
                    "{} <VRTRasterBand> elements; a DSM VRT has exactly one",
                    bands.len()
                ),
            ));
        };
        if let Some(sub) = band.attr("subClass") {
            return Err(refuse(
                path,
                format!(
                    "<VRTRasterBand subClass=\"{sub}\"> (derived or warped bands) is not supported"
                ),
            ));
        }
        only_known(path, band, BAND_CHILDREN)?;
        let band_nodata = match band.child("NoDataValue") {
            Some(e) => Some(parse_f64(path, e, e.text.trim())?),
            None => None,
        };
        let sources = band
            .children
            .iter()
            .filter(|c| c.name == "SimpleSource" || c.name == "ComplexSource")
            .map(|c| SourceSpec::from_xml(path, c))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(DatasetSpec {
            width,
            height,
            geotransform,
            band_nodata,
            data_type: band.attr("dataType").unwrap_or("Float32").to_string(),
            sources,
        })
    }
}

impl SourceSpec {
    fn from_xml(path: &Path, e: &Element) -> Result<SourceSpec, SourceError> {
        only_known(path, e, SOURCE_CHILDREN)?;
        let file = e
            .child("SourceFilename")
            .ok_or_else(|| refuse(path, format!("<{}> without <SourceFilename>", e.name)))?;
        let name = file.text.trim();
        let relative = file.attr("relativeToVRT").is_some_and(|v| v.trim() == "1");
        let source_path = match (relative, path.parent()) {
            (true, Some(dir)) => dir.join(name),
            _ => PathBuf::from(name),
        };
        // "/vsizip/...", "NETCDF:file:var", ...: other GDAL drivers
        if name.starts_with("/vsi") || (name.contains(':') && !source_path.exists()) {
            return Err(refuse(
                path,
                format!("<SourceFilename> {name}: only plain GeoTIFF files are supported"),
            ));
        }
        if let Some(b) = e.child("SourceBand") {
            if b.text.trim() != "1" {
                return Err(refuse(
                    path,
                    format!(
                        "<SourceBand>{}</SourceBand> of {name}: only band 1 is read",
                        b.text.trim()
                    ),
                ));
            }
        }
        let rect = |tag: &str| match e.child(tag) {
            Some(r) => parse_rect(path, r).map(Some),
            None => Ok(None),
        };
        let (src, dst) = (rect("SrcRect")?, rect("DstRect")?);
        if let (Some(s), Some(d)) = (src, dst) {
            if (s.x_size, s.y_size) != (d.x_size, d.y_size) {
                return Err(refuse(path, format!(
                    "<{}> {name}: <SrcRect> {} x {} and <DstRect> {} x {} differ (resampling is not supported)",
                    e.name, s.x_size, s.y_size, d.x_size, d.y_size
                )));
            }
        }
        let nodata = match e.child("NODATA") {
            Some(n) => Some(parse_f64(path, n, n.text.trim())?),
            None => None,
        };
        Ok(SourceSpec {
            kind: e.name.clone(),
            path: source_path,
            src: src.unwrap_or(PixelRect {
                x_off: 0,
                y_off: 0,
                x_size: 0,
                y_size: 0,
            }),
            dst: dst.or(src).unwrap_or(PixelRect {
                x_off: 0,
                y_off: 0,
                x_size: 0,
                y_size: 0,
            }),
            nodata,
        })
    }
}

fn parse_f64(path: &Path, e: &Element, text: &str) -> Result<f64, SourceError> {
    let t = text.trim();
    if t.eq_ignore_ascii_case("nan") {
        return Ok(f64::NAN);
    }
    t.parse::<f64>()
        .map_err(|_| refuse(path, format!("<{}>: {t:?} is not a number", e.name)))
}

fn size_attr(path: &Path, e: &Element, name: &str) -> Result<u64, SourceError> {
    e.attr(name)
        .and_then(|v| v.trim().parse::<u64>().ok())
        .filter(|&v| v > 0)
        .ok_or_else(|| {
            refuse(
                path,
                format!("<{}> needs a positive integer {name}", e.name),
            )
        })
}

/// An attribute that must be an integer (GDAL writes "0" or "0.0" alike).
fn int_attr(path: &Path, e: &Element, name: &str) -> Result<f64, SourceError> {
    let v = e
        .attr(name)
        .ok_or_else(|| refuse(path, format!("<{}> without {name}", e.name)))?;
    match v.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x.fract() == 0.0 => Ok(x),
        _ => Err(refuse(path, format!(
            "<{} {name}=\"{v}\">: not an integer (sub-pixel placement means resampling, not supported)",
            e.name
        ))),
    }
}

fn parse_rect(path: &Path, e: &Element) -> Result<PixelRect, SourceError> {
    let (x_size, y_size) = (int_attr(path, e, "xSize")?, int_attr(path, e, "ySize")?);
    if x_size < 1.0 || y_size < 1.0 {
        return Err(refuse(path, format!("<{}> has an empty size", e.name)));
    }
    Ok(PixelRect {
        x_off: int_attr(path, e, "xOff")? as i64,
        y_off: int_attr(path, e, "yOff")? as i64,
        x_size: x_size as u64,
        y_size: y_size as u64,
    })
}

fn parse_geotransform(path: &Path, root: &Element) -> Result<GeoTransform, SourceError> {
    let e = root
        .child("GeoTransform")
        .ok_or_else(|| refuse(path, "<VRTDataset> without <GeoTransform>"))?;
    let values: Vec<f64> = e
        .text
        .split(',')
        .map(|v| parse_f64(path, e, v))
        .collect::<Result<_, _>>()?;
    let ok = values.len() == 6
        && values.iter().all(|v| v.is_finite())
        && values[2] == 0.0
        && values[4] == 0.0
        && values[1] > 0.0
        && values[5] < 0.0;
    if !ok {
        return Err(refuse(
            path,
            format!(
                "<GeoTransform> {:?} is not a north-up geotransform",
                e.text.trim()
            ),
        ));
    }
    Ok(GeoTransform([
        values[0], values[1], values[2], values[3], values[4], values[5],
    ]))
}

/// Open one source and check it against the VRT (GeoTIFF, pixel size, rects).
fn open_placed(
    vrt: &Path,
    spec: SourceSpec,
    gt: &GeoTransform,
) -> Result<PlacedSource, SourceError> {
    let name = spec.path.display().to_string();
    let reader = GeoTiffSource::open(&spec.path).map_err(|e| SourceError {
        message: format!("{}: <{}> {}", vrt.display(), spec.kind, e.message),
        bad_input: e.bad_input,
    })?;
    let info = reader.raster();
    let g = info.geotransform.0;
    let same = |a: f64, b: f64| (a - b).abs() <= GSD_TOLERANCE * b.abs();
    if !same(g[1], gt.0[1]) || !same(g[5], gt.0[5]) {
        return Err(refuse(vrt, format!(
            "<{}> {name}: pixel size {} x {} differs from the VRT's {} x {} (resampling is not supported)",
            spec.kind, g[1], -g[5], gt.0[1], -gt.0[5]
        )));
    }
    let full = PixelRect {
        x_off: 0,
        y_off: 0,
        x_size: info.width,
        y_size: info.height,
    };
    let src = if spec.src.x_size == 0 { full } else { spec.src };
    let dst = if spec.dst.x_size == 0 { src } else { spec.dst };
    Ok(PlacedSource {
        path: spec.path,
        reader,
        src,
        dst,
        nodata: spec.nodata,
    })
}

fn check_same_crs(vrt: &Path, crs: &Crs, sources: &[PlacedSource]) -> Result<(), SourceError> {
    match sources.iter().find(|s| !s.reader.raster().crs.same_as(crs)) {
        Some(s) => Err(refuse(
            vrt,
            format!(
                "<SourceFilename> {}: CRS {} differs from {} of {} (one CRS per VRT)",
                s.path.display(),
                s.reader.raster().crs.label(),
                crs.label(),
                sources[0].path.display()
            ),
        )),
        None => Ok(()),
    }
}

impl RowSource for VrtSource {
    fn raster(&self) -> &SourceRaster {
        &self.raster
    }

    fn read_rows(&mut self, row0: u64, rows: u64) -> Result<Vec<f32>, SourceError> {
        let width = self.raster.width as usize;
        let mut out = vec![f32::NAN; width * rows as usize];
        let vrt_path = self.raster.path.clone();
        for s in &mut self.sources {
            paste_source(&vrt_path, s, row0, rows, width, &mut out)?;
        }
        if let Some(nd) = self.band_nodata.filter(|v| !v.is_nan()) {
            out.iter_mut()
                .filter(|v| **v as f64 == nd)
                .for_each(|v| *v = f32::NAN);
        }
        Ok(out)
    }
}

/// Copy the valid pixels of source `s` that land on rows `row0..row0+rows`
/// (and inside the VRT) into `out`.
fn paste_source(
    vrt: &Path,
    s: &mut PlacedSource,
    row0: u64,
    rows: u64,
    width: usize,
    out: &mut [f32],
) -> Result<(), SourceError> {
    let info = s.reader.raster();
    let (src_w, src_h) = (info.width as i64, info.height as i64);
    // destination rows and columns this source may write, clipped to the VRT,
    // the requested rows and the source raster
    let dy = s.src.y_off - s.dst.y_off; // source row = VRT row + dy
    let dx = s.src.x_off - s.dst.x_off;
    let r_lo = (row0 as i64).max(s.dst.y_off).max(-dy);
    let r_hi = ((row0 + rows) as i64)
        .min(s.dst.y_off + s.dst.y_size as i64)
        .min(src_h - dy);
    let c_lo = 0i64.max(s.dst.x_off).max(-dx);
    let c_hi = (width as i64)
        .min(s.dst.x_off + s.dst.x_size as i64)
        .min(src_w - dx);
    if r_lo >= r_hi || c_lo >= c_hi {
        return Ok(());
    }
    let src_rows = s
        .reader
        .read_rows((r_lo + dy) as u64, (r_hi - r_lo) as u64)
        .map_err(|e| SourceError {
            message: format!("{}: {}", vrt.display(), e.message),
            bad_input: e.bad_input,
        })?;
    let nodata = s.nodata.filter(|v| !v.is_nan());
    for r in r_lo..r_hi {
        let src_row = &src_rows[((r - r_lo) * src_w) as usize..][..src_w as usize];
        let dst_row = &mut out[((r - row0 as i64) as usize) * width..][..width];
        for c in c_lo..c_hi {
            let v = src_row[(c + dx) as usize];
            if !v.is_nan() && nodata != Some(v as f64) {
                dst_row[c as usize] = v;
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
