//! What a VRT's XML says, checked before any source is opened: the dataset
//! size and geotransform, the band's no-data, and each source's file, rects
//! and NODATA. Every element outside the short lists below is refused, naming
//! it and its parent.

use std::path::{Path, PathBuf};

use super::{refuse, PixelRect};
use crate::geo::GeoTransform;
use crate::store::source::SourceError;
use crate::xml::Element;

/// What the XML says, before any source is opened.
pub(super) struct DatasetSpec {
    pub width: u64,
    pub height: u64,
    pub geotransform: GeoTransform,
    pub band_nodata: Option<f64>,
    pub data_type: String,
    pub sources: Vec<SourceSpec>,
}

pub(super) struct SourceSpec {
    /// Element name, for messages.
    pub kind: String,
    pub path: PathBuf,
    pub src: PixelRect,
    pub dst: PixelRect,
    pub nodata: Option<f64>,
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
    pub fn from_xml(path: &Path, root: &Element) -> Result<DatasetSpec, SourceError> {
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
