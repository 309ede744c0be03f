//! Every number that enters or leaves the catalog is checked here, as strictly
//! at open as at ingest: a DSM id must be a plain folder name, pixel sizes and
//! coordinates plausible for a metric CRS, statistics finite and consistent,
//! levels halving from level 0 with a sane chunk side, the chunk record
//! inside the chunk grid, and each level's Zarr array matching its metadata.
//! The functions return one line saying what is wrong; callers add the file.

use std::collections::HashSet;

use super::catalog::{DsmMeta, LevelMeta, RootAttrs};
use super::LevelArray;
use crate::geo::{Crs, GeoTransform};

/// Pixel sizes outside this range (CRS units, metres) are not a DSM.
pub const GSD_RANGE_M: (f64, f64) = (1e-6, 1e6);
/// No projected coordinate (or raster extent) lies farther from the CRS
/// origin than this; UTM northings with false northing are about 1e7 m.
pub const MAX_COORDINATE_M: f64 = 1e9;
/// Chunk sides ingest writes (and readers accept).
pub const CHUNK_RANGE_PX: (u64, u64) = (16, 8192);
/// Longest raster side accepted (2^31 px).
pub const MAX_SIDE_PX: u64 = 1 << 31;

/// An id is one plain folder name inside the store: not empty, no path
/// separator, not `.`/`..`, not hidden, not one of our temporaries.
pub fn check_id(id: &str) -> Result<(), String> {
    let bad = id.is_empty()
        || id.starts_with('.')
        || id.starts_with("__")
        || id == "zarr.json"
        || id.contains(['/', '\\', '\0'])
        || id.contains(super::files::TMP_TAG)
        || id.contains(super::files::OLD_TAG);
    if bad {
        return Err(format!(
            "DSM id {id:?} is not a plain folder name (empty, a path, hidden, or a temporary's name)"
        ));
    }
    Ok(())
}

/// The root catalog: every id safe and listed once.
pub fn check_root(attrs: &RootAttrs) -> Result<(), String> {
    let mut seen = HashSet::new();
    for id in &attrs.dsms {
        check_id(id)?;
        if !seen.insert(id.as_str()) {
            return Err(format!(
                "the catalog lists DSM \"{id}\" twice; remove one entry"
            ));
        }
    }
    if let Some(crs) = &attrs.crs {
        check_crs(crs)?;
    }
    Ok(())
}

/// A CRS we can register in: known (EPSG code or geokeys) and not geographic.
pub fn check_crs(crs: &Crs) -> Result<(), String> {
    if crs.is_geographic {
        return Err(format!(
            "geographic CRS {} (degrees) is not a metric frame",
            crs.label()
        ));
    }
    if crs.epsg.is_none() && crs.wkt.is_none() && crs.geokeys.is_empty() {
        return Err(
            "no CRS (no GeoKeyDirectory): assign one first, e.g. gdal_edit.py -a_srs EPSG:326xx"
                .into(),
        );
    }
    if let Some(unit) = crate::geotiff::geokeys::non_metre_units(crs).first() {
        return Err(format!("{unit} in CRS {}, not metres", crs.label()));
    }
    Ok(())
}

/// A raster's size and georeferencing: finite, north-up, a plausible pixel
/// size, and every corner within [`MAX_COORDINATE_M`] of the origin.
pub fn check_raster(width: u64, height: u64, gt: &GeoTransform) -> Result<(), String> {
    if width == 0 || height == 0 || width > MAX_SIDE_PX || height > MAX_SIDE_PX {
        return Err(format!(
            "raster size {width} x {height} px is empty or too large"
        ));
    }
    if !gt.0.iter().all(|v| v.is_finite()) || !gt.is_north_up() {
        return Err(format!(
            "geotransform {:?} is not finite and north-up",
            gt.0
        ));
    }
    let (lo, hi) = GSD_RANGE_M;
    for (axis, gsd) in [("x", gt.gsd_x()), ("y", gt.gsd_y())] {
        if !(lo..=hi).contains(&gsd) {
            return Err(format!(
                "pixel size {gsd:e} in {axis} is implausible (a DSM cell is {lo:e} to {hi:e} m)"
            ));
        }
    }
    let b = gt.bounds(width, height);
    if !b
        .iter()
        .all(|v| v.is_finite() && v.abs() <= MAX_COORDINATE_M)
    {
        return Err(format!(
            "extent {b:?} reaches past {MAX_COORDINATE_M:e} m from the CRS origin (bad pixel size or origin)"
        ));
    }
    Ok(())
}

/// Levels: level 0 is the raster, each next level halves (rounding up); the
/// stored chunk side is within [`CHUNK_RANGE_PX`] and no level's is above it.
pub fn check_levels(meta: &DsmMeta) -> Result<(), String> {
    let (lo, hi) = CHUNK_RANGE_PX;
    let chunk = meta.storage.chunk;
    if !(lo..=hi).contains(&chunk) {
        return Err(format!("chunk side {chunk} px outside {lo}..={hi}"));
    }
    let Some(first) = meta.levels.first() else {
        return Err("no levels".into());
    };
    if meta.levels.len() > 40 || (first.width, first.height) != (meta.width, meta.height) {
        return Err(format!(
            "{} levels, level 0 {} x {} px for a {} x {} px DSM",
            meta.levels.len(),
            first.width,
            first.height,
            meta.width,
            meta.height
        ));
    }
    for (k, pair) in meta.levels.windows(2).enumerate() {
        let want = (pair[0].width.div_ceil(2), pair[0].height.div_ceil(2));
        if (pair[1].width, pair[1].height) != want {
            return Err(format!(
                "level {} is {} x {} px, expected {} x {} (half of level {k})",
                k + 1,
                pair[1].width,
                pair[1].height,
                want.0,
                want.1
            ));
        }
    }
    // Levels smaller than the stored side may have smaller chunks
    // (`pyramid::level_chunk`); stores written before that have one side.
    if let Some(k) = meta
        .levels
        .iter()
        .position(|l| l.chunk < lo || l.chunk > chunk)
    {
        return Err(format!(
            "level {k} has chunk side {} px, outside {lo}..={chunk} (the DSM's)",
            meta.levels[k].chunk
        ));
    }
    if let Some(record) = &meta.chunk_record {
        record.check(&meta.levels)?;
    }
    Ok(())
}

/// Everything the catalog says about one DSM.
pub fn check_dsm(meta: &DsmMeta) -> Result<(), String> {
    check_id(&meta.id)?;
    check_crs(&meta.crs)?;
    check_raster(meta.width, meta.height, &meta.geotransform)?;
    check_levels(meta)?;
    let pixels = meta.width * meta.height;
    if meta.valid_count == 0 || meta.valid_count > pixels {
        return Err(format!(
            "valid pixel count {} outside 1..={pixels}",
            meta.valid_count
        ));
    }
    let s = &meta.height_stats;
    let finite = [s.min, s.max, s.mean, s.std].iter().all(|v| v.is_finite());
    let slack = 1e-6 * (s.min.abs() + s.max.abs() + 1.0);
    if !finite || s.min > s.max || s.std < 0.0 || s.mean < s.min - slack || s.mean > s.max + slack {
        return Err(format!(
            "height statistics {s:?} are not finite and consistent"
        ));
    }
    let f = &meta.footprint.to_array();
    let b = meta.geotransform.bounds(meta.width, meta.height);
    let tol = meta.gsd_m();
    let inside =
        f[0] >= b[0] - tol && f[1] >= b[1] - tol && f[2] <= b[2] + tol && f[3] <= b[3] + tol;
    if !f.iter().all(|v| v.is_finite()) || f[0] > f[2] || f[1] > f[3] || !inside {
        return Err(format!(
            "footprint {f:?} is not a box inside the raster's extent {b:?}"
        ));
    }
    Ok(())
}

/// A level's Zarr array must have the shape and chunk side its metadata says.
pub fn check_array(array: &LevelArray, level: &LevelMeta) -> Result<(), String> {
    let shape = array.shape().to_vec();
    let chunk: Vec<u64> = array
        .chunk_shape(&[0, 0])
        .map(|c| c.iter().map(|v| v.get()).collect())
        .map_err(|e| format!("no chunk grid: {e}"))?;
    let want_shape = vec![level.height, level.width];
    if shape != want_shape || chunk != vec![level.chunk, level.chunk] {
        return Err(format!(
            "array of shape {shape:?} with chunks {chunk:?}; the DSM's metadata says {want_shape:?} with {} px chunks",
            level.chunk
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::catalog::tests::sample_meta;

    #[test]
    fn ids_that_leave_the_store_are_refused() {
        for id in [
            "../outside",
            "a/b",
            "..",
            ".",
            "",
            ".hidden",
            "x.tmp-1",
            "a\\b",
        ] {
            assert!(check_id(id).is_err(), "{id:?}");
        }
        check_id("tile_01").unwrap();
        let attrs = RootAttrs {
            version: 1,
            crs: None,
            dsms: vec!["a".into(), "b".into(), "a".into()],
        };
        let err = check_root(&attrs).unwrap_err();
        assert!(err.contains("\"a\" twice"), "{err}");
    }

    #[test]
    fn implausible_numbers_are_refused() {
        check_dsm(&sample_meta("a")).unwrap();
        let mut small_overview_chunks = sample_meta("a");
        small_overview_chunks.levels[1].chunk = 64;
        check_dsm(&small_overview_chunks).unwrap();
        type Mutation = Box<dyn Fn(&mut DsmMeta)>;
        let cases: Vec<(&str, Mutation)> = vec![
            ("scale 1e308", Box::new(|m| m.geotransform.0[1] = 1e308)),
            ("scale 1e-300", Box::new(|m| m.geotransform.0[5] = -1e-300)),
            ("origin 1e12", Box::new(|m| m.geotransform.0[0] = 1e12)),
            ("nan stats", Box::new(|m| m.height_stats.mean = f64::NAN)),
            ("min > max", Box::new(|m| m.height_stats.min = 1e6)),
            (
                "inf footprint",
                Box::new(|m| m.footprint.max_x = f64::INFINITY),
            ),
            ("footprint outside", Box::new(|m| m.footprint.min_x = 0.0)),
            ("no valid pixels", Box::new(|m| m.valid_count = 0)),
            ("chunk 0", Box::new(|m| m.levels[1].chunk = 0)),
            ("storage chunk 0", Box::new(|m| m.storage.chunk = 0)),
            ("chunk above", Box::new(|m| m.levels[1].chunk = 1024)),
            ("level 1 wrong", Box::new(|m| m.levels[1].width = 7)),
            ("no levels", Box::new(|m| m.levels.clear())),
            ("geographic", Box::new(|m| m.crs.is_geographic = true)),
            ("no crs", Box::new(|m| m.crs = Crs::default())),
            ("bad id", Box::new(|m| m.id = "../x".into())),
        ];
        for (what, mutate) in cases {
            let mut m = sample_meta("a");
            mutate(&mut m);
            assert!(check_dsm(&m).is_err(), "{what} accepted");
        }
    }
}
