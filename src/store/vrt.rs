//! A GDAL VRT mosaic of GeoTIFFs or SRTM HGT tiles (`gdalbuildvrt`) as one
//! ingest source (one DSM, its id the VRT's stem). Only what places source
//! pixels unchanged is accepted: a `VRTDataset` (no `subClass`: no warping, no
//! pansharpening) with a north-up `GeoTransform` and one `VRTRasterBand` of
//! `SimpleSource`s or `ComplexSource`s, each band 1 of a GeoTIFF or an HGT
//! tile, with integer `SrcRect` and `DstRect` of equal size (no resampling),
//! the VRT's pixel size and the same CRS as the other sources. Anything else
//! (scaling, LUTs, masks, kernels, other drivers or `/vsi` paths, more bands)
//! is refused with one line naming the file and the element.
//!
//! Pixels are composed as GDAL does for sources without scaling: in file
//! order, a later source's valid pixels overwrite earlier ones; no-data (the
//! source's own, a ComplexSource's `NODATA`, the band's `NoDataValue`) never
//! overwrites. Rows are read from each source only where its `DstRect` meets
//! the requested rows, so memory stays a block row per source (a GeoTIFF is
//! a [`GeoTiffSource`](super::source::GeoTiffSource), which maps its file
//! afresh as it streams; an HGT tile a [`super::hgt::HgtSource`], zipped
//! ones inflated as they are read).

use std::path::{Path, PathBuf};

use super::source::{open_geotiff, RowSource, SourceError, SourceRaster};
use crate::geo::{Crs, GeoTransform};

mod spec;
use crate::xml;
use spec::{DatasetSpec, SourceSpec};

/// Relative tolerance on pixel sizes (VRT text vs the sources' tags).
const GSD_TOLERANCE: f64 = 1e-6;

/// Opens `*.vrt` as a [`VrtSource`], SRTM tiles (`*.hgt`, `*.zip`) as an
/// [`HgtSource`](super::hgt::HgtSource), anything else as a GeoTIFF.
pub fn open_input(path: &Path) -> Result<Box<dyn RowSource>, SourceError> {
    let is_vrt = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("vrt"));
    if is_vrt {
        Ok(Box::new(VrtSource::open(path)?))
    } else if super::hgt::is_hgt_path(path) {
        Ok(Box::new(super::hgt::HgtSource::open(path)?))
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
    reader: Box<dyn RowSource>,
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
            // a source in feet speaks for the mosaic, else the first source
            height_unit: (sources.iter())
                .filter_map(|s| s.reader.raster().height_unit.clone())
                .find(|u| crate::geotiff::gdal_metadata::is_feet(u))
                .or_else(|| first.reader.raster().height_unit.clone()),
            // the sources' side files, in source order
            georeferenced_by: (sources.iter())
                .flat_map(|s| s.reader.raster().georeferenced_by.clone())
                .collect(),
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

/// Open one source and check it against the VRT (a GeoTIFF or an SRTM HGT
/// tile, pixel size, rects).
fn open_placed(
    vrt: &Path,
    spec: SourceSpec,
    gt: &GeoTransform,
) -> Result<PlacedSource, SourceError> {
    let name = spec.path.display().to_string();
    let opened = if super::hgt::is_hgt_path(&spec.path) {
        super::hgt::HgtSource::open(&spec.path).map(|s| Box::new(s) as Box<dyn RowSource>)
    } else {
        open_geotiff(&spec.path)
    };
    let reader = opened.map_err(|e| SourceError {
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
