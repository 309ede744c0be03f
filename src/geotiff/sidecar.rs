//! Georeferencing beside a GeoTIFF, found as GDAL finds it: a PAM sidecar
//! (`<file>.aux.xml`, its `<SRS>` and `<GeoTransform>`) before the file's own
//! tags; a world file (`.tfw`, `.tifw`, `.wld`, either case) when the file
//! has no transform tags; band 1's no-data, scale, offset and unit from the
//! PAM sidecar where the file's tags have none. Beyond GDAL (whose GeoTIFF driver ignores it), an
//! ESRI `.prj` names the CRS when neither the PAM sidecar nor the file does,
//! as ArcGIS reads it. A side file that is there but cannot be read is an
//! error naming it, never skipped: it would leave a DSM metres off, or in no
//! CRS.

use std::path::{Path, PathBuf};

use super::geokeys::GeoKeyError;
use super::reader::GeoTiffError;
use crate::geo::GeoTransform;

/// What a PAM sidecar says about the dataset (band statistics aside).
#[derive(Clone, Debug, PartialEq)]
pub struct Pam {
    pub path: PathBuf,
    /// The `<SRS>` text (WKT, as GDAL writes it).
    pub srs: Option<String>,
    /// The `<GeoTransform>`: GDAL's six coefficients, pixel-is-area.
    pub geotransform: Option<[f64; 6]>,
    /// What `<PAMRasterBand band="1">` says: GDAL takes each where the
    /// file's own tags say nothing.
    pub band: PamBand,
}

/// Band 1's no-data, scale, offset and unit in a PAM sidecar.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PamBand {
    pub nodata: Option<f64>,
    pub scale: Option<f64>,
    pub offset: Option<f64>,
    pub unit: Option<String>,
}

/// A world file and the geotransform it gives.
#[derive(Clone, Debug, PartialEq)]
pub struct WorldFile {
    pub path: PathBuf,
    pub geotransform: [f64; 6],
}

fn bad(path: &Path, detail: String) -> GeoTiffError {
    GeoTiffError::Sidecar {
        path: path.to_path_buf(),
        detail,
    }
}

/// Side files are text of kilobytes (an `.aux.xml` with histograms of many
/// bands: a few megabytes); anything larger is not one.
const MAX_SIDE_FILE_BYTES: u64 = 64 << 20;

fn read_text(path: &Path) -> Result<String, GeoTiffError> {
    let io = |source| GeoTiffError::Io {
        path: path.to_path_buf(),
        source,
    };
    let len = std::fs::metadata(path).map_err(io)?.len();
    if len > MAX_SIDE_FILE_BYTES {
        return Err(bad(
            path,
            format!("{len} bytes, too large for a side file (at most {MAX_SIDE_FILE_BYTES})"),
        ));
    }
    let bytes = std::fs::read(path).map_err(io)?;
    String::from_utf8(bytes).map_err(|_| bad(path, "not a text file (invalid UTF-8)".into()))
}

/// `<tif>.aux.xml`, when there is one.
pub fn pam(tif: &Path) -> Result<Option<Pam>, GeoTiffError> {
    let path = PathBuf::from(format!("{}.aux.xml", tif.display()));
    if !path.is_file() {
        return Ok(None);
    }
    let root = crate::xml::parse(&read_text(&path)?)
        .map_err(|e| bad(&path, format!("not valid XML: {e}")))?;
    if root.name != "PAMDataset" {
        return Err(bad(
            &path,
            format!("root element <{}>, not <PAMDataset>", root.name),
        ));
    }
    let srs = (root.child("SRS"))
        .map(|e| e.text.trim().to_string())
        .filter(|t| !t.is_empty());
    let geotransform = match root.child("GeoTransform") {
        Some(e) => Some(
            six_numbers(e.text.split(','))
                .map_err(|d| bad(&path, format!("<GeoTransform> {d}")))?,
        ),
        None => None,
    };
    let band = match (root.children_named("PAMRasterBand")).find(|b| b.attr("band") == Some("1")) {
        Some(b) => pam_band(b).map_err(|d| bad(&path, d))?,
        None => PamBand::default(),
    };
    Ok(Some(Pam {
        path,
        srs,
        geotransform,
        band,
    }))
}

fn pam_band(band: &crate::xml::Element) -> Result<PamBand, String> {
    let text = |name: &str| {
        (band.child(name))
            .map(|e| e.text.trim())
            .filter(|t| !t.is_empty())
    };
    let number = |name: &str| match text(name) {
        Some(t) => t
            .parse::<f64>()
            .map(Some)
            .map_err(|_| format!("band 1's <{name}> holds {t:?}, not a number")),
        None => Ok(None),
    };
    let nodata = match text("NoDataValue") {
        Some(t) => Some(
            super::geokeys::parse_gdal_nodata(t)
                .ok_or_else(|| format!("band 1's <NoDataValue> holds {t:?}, not a number"))?,
        ),
        None => None,
    };
    Ok(PamBand {
        nodata,
        scale: number("Scale")?,
        offset: number("Offset")?,
        unit: text("UnitType").map(str::to_string),
    })
}

/// Exactly six finite numbers.
fn six_numbers<'a>(items: impl Iterator<Item = &'a str>) -> Result<[f64; 6], String> {
    let mut values = Vec::new();
    for item in items {
        let v: f64 =
            (item.trim().parse()).map_err(|_| format!("holds {:?}, not a number", item.trim()))?;
        if !v.is_finite() {
            return Err(format!("holds {v}"));
        }
        values.push(v);
    }
    <[f64; 6]>::try_from(values.as_slice())
        .map_err(|_| format!("holds {} numbers, not 6", values.len()))
}

/// The world files GDAL looks for beside `tif`, in its order: the extension's
/// first and last letters + `w` (`.tfw`), the extension + `w` (`.tifw`),
/// `.wld`; each in lower case, then upper case.
fn world_file_names(tif: &Path) -> Vec<PathBuf> {
    let ext = (tif.extension())
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut exts = Vec::new();
    if ext.chars().count() >= 2 {
        let (first, last) = (ext.chars().next().unwrap(), ext.chars().last().unwrap());
        exts.push(format!("{first}{last}w"));
        exts.push(format!("{ext}w"));
    }
    exts.push("wld".to_string());
    exts.iter()
        .flat_map(|e| [e.to_lowercase(), e.to_uppercase()])
        .map(|e| tif.with_extension(e))
        .collect()
}

/// The first world file beside `tif`, as GDAL reads it: six numbers, one per
/// line (pixel width, row rotation, column rotation, pixel height, and the
/// centre of the top-left pixel), blank lines skipped.
pub fn world_file(tif: &Path) -> Result<Option<WorldFile>, GeoTiffError> {
    let Some(path) = world_file_names(tif).into_iter().find(|p| p.is_file()) else {
        return Ok(None);
    };
    let text = read_text(&path)?;
    let lines = text.lines().filter(|l| !l.trim().is_empty());
    let [a, d, b, e, c, f] =
        six_numbers(lines).map_err(|detail| bad(&path, format!("bad world file: {detail}")))?;
    // the world file gives the top-left pixel's centre; GDAL's origin is its corner
    let geotransform = [c - 0.5 * a - 0.5 * b, a, b, f - 0.5 * d - 0.5 * e, d, e];
    Ok(Some(WorldFile { path, geotransform }))
}

/// `<stem>.prj` (ESRI's CRS file), when there is one.
pub fn prj(tif: &Path) -> Result<Option<(PathBuf, String)>, GeoTiffError> {
    let path = tif.with_extension("prj");
    if !path.is_file() {
        return Ok(None);
    }
    let text = read_text(&path)?;
    Ok(Some((path, text.trim().to_string())))
}

/// Every side file beside `tif` that can georeference it (existing ones):
/// a change to any of them changes the DSM.
pub fn paths(tif: &Path) -> Vec<PathBuf> {
    let mut all = vec![PathBuf::from(format!("{}.aux.xml", tif.display()))];
    all.extend(world_file_names(tif));
    all.push(tif.with_extension("prj"));
    all.retain(|p| p.is_file());
    all
}

/// What a GeoTIFF's own tags say of its georeferencing.
pub struct InTags {
    /// The transform of ModelPixelScale + ModelTiepoint or ModelTransformation.
    pub transform: Result<GeoTransform, GeoKeyError>,
    /// The CRS of the geokeys (empty keys: none).
    pub crs: crate::geo::Crs,
    /// The file has a GeoKeyDirectory.
    pub names_a_crs: bool,
    pub pixel_is_point: bool,
}

/// A GeoTIFF's georeferencing: its tags', with its side files'.
pub struct Georeferencing {
    pub geotransform: GeoTransform,
    pub crs: crate::geo::Crs,
    pub pixel_is_point: bool,
    /// The side files it was taken from; empty: the tags alone.
    pub georeferenced_by: Vec<PathBuf>,
}

/// A warning said once per process: a file is opened by the ingest plan and
/// again by each reader, and a side file overriding its tags is news once.
fn warn_once(message: String) {
    use std::collections::HashSet;
    use std::sync::{Mutex, OnceLock};
    static SAID: OnceLock<Mutex<HashSet<String>>> = OnceLock::new();
    let said = SAID.get_or_init(|| Mutex::new(HashSet::new()));
    if said
        .lock()
        .map(|mut s| s.insert(message.clone()))
        .unwrap_or(true)
    {
        tracing::warn!("{message}");
    }
}

/// The georeferencing of the file's tags, completed or overridden by its side
/// files in GDAL's order: the transform from the PAM sidecar, the tags, a
/// world file; the CRS from the PAM sidecar, the tags (when they have keys),
/// then an ESRI `.prj` (beyond GDAL).
pub fn with_side_files(
    path: &Path,
    pam: Option<&Pam>,
    in_tags: InTags,
) -> Result<Georeferencing, GeoTiffError> {
    let north_up = |by: &Path, g: [f64; 6]| {
        let gt = GeoTransform(g);
        match gt.is_north_up() {
            true => Ok(gt),
            false => Err(GeoTiffError::NotNorthUp {
                path: by.to_path_buf(),
                geotransform: g,
            }),
        }
    };
    let mut by = Vec::new();
    let mut pixel_is_point = in_tags.pixel_is_point;
    let pam_transform = pam.and_then(|p| Some((&p.path, p.geotransform?)));
    let geotransform = match (pam_transform, in_tags.transform) {
        (Some((aux, g)), tags) => {
            by.push(aux.clone());
            pixel_is_point = false;
            if tags.is_ok_and(|t| t.0 != g) {
                warn_once(format!(
                    "{}: its GeoTransform {g:?} overrides the one of the file's own tags, as GDAL reads it",
                    aux.display()
                ));
            }
            north_up(aux, g)?
        }
        (None, Ok(gt)) => gt,
        (None, Err(GeoKeyError::NoGeoreferencing)) => match world_file(path)? {
            Some(w) => {
                by.push(w.path.clone());
                pixel_is_point = false;
                north_up(&w.path, w.geotransform)?
            }
            None => return Err(GeoTiffError::NoGeoreferencing { path: path.into() }),
        },
        (None, Err(e)) => return Err(GeoTiffError::from_geokeys(path, e)),
    };
    let wkt_crs = |by: &Path, text: &str| {
        crate::geotiff::wkt::crs_from_wkt(text).map_err(|detail| GeoTiffError::Sidecar {
            path: by.to_path_buf(),
            detail,
        })
    };
    let crs = match pam.and_then(|p| Some((&p.path, p.srs.as_deref()?))) {
        Some((aux, srs)) => {
            if !by.contains(aux) {
                by.push(aux.clone());
            }
            let crs = wkt_crs(aux, srs)?;
            if in_tags.names_a_crs && !crs.same_as(&in_tags.crs) {
                warn_once(format!(
                    "{}: its CRS {} overrides the file's own {}, as GDAL reads it",
                    aux.display(),
                    crs.label(),
                    in_tags.crs.label()
                ));
            }
            crs
        }
        None if in_tags.names_a_crs => in_tags.crs,
        None => match prj(path)? {
            Some((prj, text)) => {
                let crs = wkt_crs(&prj, &text)?;
                by.push(prj);
                crs
            }
            None => in_tags.crs,
        },
    };
    if !by.is_empty() {
        tracing::debug!(path = %path.display(), side_files = ?by, "georeferencing read beside the file");
    }
    Ok(Georeferencing {
        geotransform,
        crs,
        pixel_is_point,
        georeferenced_by: by,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn world_files_are_looked_for_as_gdal_does() {
        let names: Vec<String> = world_file_names(Path::new("/d/a.tif"))
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(
            names,
            ["a.tfw", "a.TFW", "a.tifw", "a.TIFW", "a.wld", "a.WLD"]
        );
    }

    #[test]
    fn a_world_file_gives_the_corner_of_its_top_left_pixel() {
        let dir = tempfile::tempdir().unwrap();
        let tif = dir.path().join("a.tiff");
        std::fs::write(
            dir.path().join("a.tfw"),
            "0.5\n0.0\n0.0\n-0.5\n\n630000.75\r\n4830000.0\n",
        )
        .unwrap();
        let wf = world_file(&tif).unwrap().unwrap();
        assert_eq!(wf.path, dir.path().join("a.tfw"));
        assert_eq!(wf.geotransform, [630000.5, 0.5, 0.0, 4830000.25, 0.0, -0.5]);
        std::fs::write(dir.path().join("a.tfw"), "0.5\n0\n0\n-0.5\n630000.75\n").unwrap();
        let e = world_file(&tif).unwrap_err().to_string();
        assert!(
            e.contains("a.tfw: bad world file: holds 5 numbers, not 6"),
            "{e}"
        );
        std::fs::write(dir.path().join("a.tfw"), "0.5\n0\n0\n-0.5\nx\n1\n").unwrap();
        let e = world_file(&tif).unwrap_err().to_string();
        assert!(e.contains("holds \"x\", not a number"), "{e}");
    }

    #[test]
    fn a_pam_sidecar_gives_its_srs_and_geotransform() {
        let dir = tempfile::tempdir().unwrap();
        let tif = dir.path().join("a.tif");
        assert_eq!(pam(&tif).unwrap(), None);
        let aux = dir.path().join("a.tif.aux.xml");
        std::fs::write(
            &aux,
            "<PAMDataset>\n  <SRS dataAxisToSRSAxisMapping=\"1,2\">PROJCS[&quot;x&quot;]</SRS>\n  <GeoTransform>  6.3e+05,  5.0e-01,  0.0,  4.8e+06,  0.0, -5.0e-01</GeoTransform>\n  <PAMRasterBand band=\"2\"><NoDataValue>7</NoDataValue></PAMRasterBand>\n  <PAMRasterBand band=\"1\"><NoDataValue le_hex_equiv=\"000000000088C3C0\">-9.99900000000000E+03</NoDataValue><Scale>0.01</Scale><UnitType>m</UnitType><Metadata/></PAMRasterBand>\n</PAMDataset>\n",
        )
        .unwrap();
        let p = pam(&tif).unwrap().unwrap();
        assert_eq!(p.srs.as_deref(), Some("PROJCS[\"x\"]"));
        assert_eq!(p.geotransform, Some([6.3e5, 0.5, 0.0, 4.8e6, 0.0, -0.5]));
        let band = PamBand {
            nodata: Some(-9999.0),
            scale: Some(0.01),
            offset: None,
            unit: Some("m".into()),
        };
        assert_eq!(p.band, band);
        assert_eq!(paths(&tif), std::slice::from_ref(&aux));
        std::fs::write(
            &aux,
            "<PAMDataset><GeoTransform>1,2,3</GeoTransform></PAMDataset>",
        )
        .unwrap();
        let e = pam(&tif).unwrap_err().to_string();
        assert!(
            e.contains("a.tif.aux.xml: <GeoTransform> holds 3 numbers"),
            "{e}"
        );
        std::fs::write(&aux, "<PAMDataset><SRS>").unwrap();
        assert!(pam(&tif).unwrap_err().to_string().contains("not valid XML"));
    }
}
