//! The catalog: what the store's JSON says about the collection and each DSM.
//!
//! The root group's `zarr.json` carries `{"dsmstream": {version, crs, dsms}}`
//! (the ordered list of DSM ids); each DSM group `<id>/zarr.json` carries
//! `{"dsmstream": DsmMeta, "multiscales": {...}}`. `DsmMeta` is the single
//! source of truth (deserialized as is); `multiscales` repeats the levels with
//! their paths, shapes and geotransforms for other tools. Group metadata files
//! are always replaced atomically (write to a temporary name, then rename).

use std::path::Path;

use serde::{Deserialize, Serialize};
use serde_json::{json, Value};

use super::chunks::ChunkRecord;
use super::{validate, StoreError};
use crate::geo::{Bounds, Crs, GeoTransform};

/// Version of the attribute layout written by this code.
pub const STORE_VERSION: u32 = 1;

/// Height statistics over the valid pixels of level 0, in CRS height units (metres).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HeightStats {
    pub min: f64,
    pub max: f64,
    pub mean: f64,
    pub std: f64,
}

/// One level of the multiscale pyramid; array path = level index.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct LevelMeta {
    pub width: u64,
    pub height: u64,
    /// Square chunk side in pixels.
    pub chunk: u64,
}

/// The input file a DSM was ingested from; size and mtime decide re-ingest,
/// its side files' too (a world file, `.aux.xml` or `.prj` added, changed or
/// removed changes the DSM's georeferencing).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SourceInfo {
    /// Absolute path at ingest time.
    pub path: String,
    pub size: u64,
    /// Modification time, nanoseconds since the Unix epoch.
    pub mtime_unix_ns: i64,
    /// The side files beside it that can georeference it, each as a
    /// `SourceInfo` of its own (no side files of their own).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub side_files: Vec<SourceInfo>,
}

/// Chunk compression of every array.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "codec", rename_all = "lowercase")]
pub enum Compression {
    None,
    Zstd { level: i32 },
}

/// zstd level of `--compression zstd` and of the default settings. Level 1:
/// on float32 heights (noisy mantissa bytes) level 3 costs ~35 % more ingest
/// CPU for 0.5 % smaller chunks on a 20000^2 generated DSM and 0-14 % on the
/// real rasters of ../shared/data (tools/results/bench_results.md).
pub const DEFAULT_ZSTD_LEVEL: i32 = 1;

impl Compression {
    /// "none" | "zstd" (level [`DEFAULT_ZSTD_LEVEL`]) | "zstd:<level>".
    pub fn parse(text: &str) -> Option<Compression> {
        match text {
            "none" => Some(Compression::None),
            "zstd" => Some(Compression::Zstd {
                level: DEFAULT_ZSTD_LEVEL,
            }),
            _ => {
                let level = text.strip_prefix("zstd:")?.parse().ok()?;
                Some(Compression::Zstd { level })
            }
        }
    }
}

/// How the arrays of a DSM were laid out (recorded for information).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct StorageSettings {
    pub chunk: u64,
    pub compression: Compression,
    /// Overviews are added until the long side is at most this many pixels
    /// (64 by default: coarse-to-fine ICP needs a few levels even on small DSMs).
    pub min_overview_px: u64,
}

impl Default for StorageSettings {
    fn default() -> Self {
        StorageSettings {
            chunk: 512,
            compression: Compression::Zstd {
                level: DEFAULT_ZSTD_LEVEL,
            },
            min_overview_px: 64,
        }
    }
}

/// Everything the store knows about one DSM.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DsmMeta {
    /// The input file's stem; also the group name in the store.
    pub id: String,
    pub width: u64,
    pub height: u64,
    /// Level-0 geotransform (north-up).
    pub geotransform: GeoTransform,
    pub crs: Crs,
    /// The source's declared no-data value (stored pixels use NaN instead).
    #[serde(with = "nodata_json")]
    pub nodata: Option<f64>,
    pub valid_count: u64,
    pub height_stats: HeightStats,
    /// The box of the valid pixels, in CRS units (on disk the array
    /// `[min_x, min_y, max_x, max_y]`).
    pub footprint: Bounds,
    pub levels: Vec<LevelMeta>,
    pub source: SourceInfo,
    /// Sample type of the source file, GDAL names: "Float32", "Int16", ...
    pub source_dtype: String,
    pub storage: StorageSettings,
    /// Which chunks hold data, per level, so a missing chunk file is an error
    /// and not no-data. Absent in stores written before the record existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub chunk_record: Option<ChunkRecord>,
    /// Put into a UTM zone from longitude and latitude at ingest.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reprojected: Option<super::warp::Warped>,
}

impl DsmMeta {
    /// Ground sampling distance of level 0 (pixel width), CRS units.
    pub fn gsd_m(&self) -> f64 {
        self.geotransform.gsd_x()
    }

    pub fn level_geotransform(&self, level: usize) -> GeoTransform {
        self.geotransform.overview(level as u32)
    }

    /// Valid pixels / all pixels of level 0.
    pub fn valid_fraction(&self) -> f64 {
        self.valid_count as f64 / (self.width * self.height).max(1) as f64
    }

    /// The DSM group's attributes: the metadata plus the levels in the
    /// multiscales convention (see [`super::geo_attrs::multiscales`]).
    pub fn to_attributes(&self) -> Value {
        let levels: Vec<(GeoTransform, u64, u64)> = self
            .levels
            .iter()
            .enumerate()
            .map(|(k, l)| (self.level_geotransform(k), l.height, l.width))
            .collect();
        let mut attrs = super::geo_attrs::multiscales(&levels, &self.crs);
        attrs.insert("dsmstream".into(), json!(self));
        Value::Object(attrs)
    }
}

/// The root group's attributes: the collection.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RootAttrs {
    pub version: u32,
    /// CRS shared by every DSM (None while the store is empty).
    pub crs: Option<Crs>,
    /// DSM ids in ingest order.
    pub dsms: Vec<String>,
}

/// Serialize no-data so NaN survives JSON ("nan"); None is null.
mod nodata_json {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    #[derive(Serialize, Deserialize)]
    #[serde(untagged)]
    enum Repr {
        Number(f64),
        Text(String),
    }

    pub fn serialize<S: Serializer>(v: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
        match v {
            None => s.serialize_none(),
            Some(x) if x.is_finite() => s.serialize_some(&Repr::Number(*x)),
            Some(x) => s.serialize_some(&Repr::Text(x.to_string().to_lowercase())),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
        match Option::<Repr>::deserialize(d)? {
            None => Ok(None),
            Some(Repr::Number(x)) => Ok(Some(x)),
            Some(Repr::Text(t)) => t
                .parse::<f64>()
                .map(Some)
                .map_err(|_| serde::de::Error::custom(format!("bad nodata {t:?}"))),
        }
    }
}

/// Read the `attributes` object of the group whose folder is `dir`.
pub fn read_group_attributes(dir: &Path) -> Result<Value, StoreError> {
    let path = dir.join("zarr.json");
    let text = std::fs::read_to_string(&path).map_err(|e| StoreError::io(&path, e))?;
    let doc: Value = serde_json::from_str(&text).map_err(|e| StoreError::json(&path, e))?;
    if doc.get("node_type").and_then(Value::as_str) != Some("group") {
        return Err(StoreError::NotAStore {
            path: dir.display().to_string(),
            reason: "zarr.json is not a Zarr v3 group".into(),
        });
    }
    Ok(doc.get("attributes").cloned().unwrap_or(Value::Null))
}

/// Replace `<dir>/zarr.json` with a group holding `attributes` (temp + rename).
pub fn write_group_attributes(dir: &Path, attributes: &Value) -> Result<(), StoreError> {
    let doc = json!({"zarr_format": 3, "node_type": "group", "attributes": attributes});
    let text = serde_json::to_string_pretty(&doc).expect("json values serialize");
    let path = dir.join("zarr.json");
    crate::atomic::write_bytes_atomically(&path, text.as_bytes())
        .map_err(|e| StoreError::io(&path, e))
}

pub fn read_root(root: &Path) -> Result<RootAttrs, StoreError> {
    let attrs = read_group_attributes(root)?;
    let Some(ours) = attrs.get("dsmstream") else {
        return Err(StoreError::NotAStore {
            path: root.display().to_string(),
            reason: "no \"dsmstream\" attributes in zarr.json".into(),
        });
    };
    let root_attrs: RootAttrs = serde_json::from_value(ours.clone())
        .map_err(|e| StoreError::json(&root.join("zarr.json"), e))?;
    if root_attrs.version != STORE_VERSION {
        return Err(StoreError::NotAStore {
            path: root.display().to_string(),
            reason: format!(
                "store version {} (this build reads {STORE_VERSION})",
                root_attrs.version
            ),
        });
    }
    Ok(root_attrs)
}

pub fn write_root(root: &Path, attrs: &RootAttrs) -> Result<(), StoreError> {
    write_group_attributes(root, &json!({ "dsmstream": attrs }))
}

pub fn read_dsm(group_dir: &Path) -> Result<DsmMeta, StoreError> {
    let attrs = read_group_attributes(group_dir)?;
    let ours = attrs.get("dsmstream").cloned().unwrap_or(Value::Null);
    serde_json::from_value(ours).map_err(|e| StoreError::json(&group_dir.join("zarr.json"), e))
}

/// The metadata of DSM `id` of the store at `root`, validated: a safe id that
/// matches its group, plausible numbers, consistent levels and chunk record,
/// and the collection's CRS (`crs`, when the catalog has one).
pub fn read_valid_dsm(root: &Path, id: &str, crs: Option<&Crs>) -> Result<DsmMeta, StoreError> {
    let dir = root.join(id);
    let file = dir.join("zarr.json");
    validate::check_id(id).map_err(|m| StoreError::invalid(&root.join("zarr.json"), m))?;
    let meta = read_dsm(&dir)?;
    if meta.id != id {
        return Err(StoreError::invalid(
            &file,
            format!("the group of DSM \"{id}\" says its id is \"{}\"", meta.id),
        ));
    }
    validate::check_dsm(&meta).map_err(|m| StoreError::invalid(&file, m))?;
    if let Some(crs) = crs {
        if !crs.same_as(&meta.crs) {
            return Err(StoreError::invalid(
                &file,
                format!(
                    "CRS {} differs from the collection's {}",
                    meta.crs.label(),
                    crs.label()
                ),
            ));
        }
    }
    Ok(meta)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    pub fn sample_meta(id: &str) -> DsmMeta {
        DsmMeta {
            id: id.into(),
            width: 1000,
            height: 600,
            geotransform: GeoTransform::north_up(630_000.0, 4_833_000.0, 0.5, 0.5),
            crs: Crs {
                epsg: Some(26917),
                ..Default::default()
            },
            nodata: Some(f64::NAN),
            valid_count: 123_456,
            height_stats: HeightStats {
                min: 74.5,
                max: 110.25,
                mean: 80.125,
                std: 3.5,
            },
            footprint: Bounds::from([630_010.0, 4_832_700.0, 630_500.0, 4_833_000.0]),
            levels: vec![
                LevelMeta {
                    width: 1000,
                    height: 600,
                    chunk: 512,
                },
                LevelMeta {
                    width: 500,
                    height: 300,
                    chunk: 512,
                },
            ],
            source: SourceInfo {
                path: "/data/a.tif".into(),
                size: 42,
                mtime_unix_ns: 1_700_000_000_123_456_789,
                side_files: Vec::new(),
            },
            source_dtype: "Float32".into(),
            storage: StorageSettings::default(),
            chunk_record: None,
            reprojected: None,
        }
    }

    #[test]
    fn dsm_attributes_round_trip_with_nan_nodata() {
        let dir = tempfile::tempdir().unwrap();
        let meta = sample_meta("a");
        write_group_attributes(dir.path(), &meta.to_attributes()).unwrap();
        let back = read_dsm(dir.path()).unwrap();
        assert!(back.nodata.unwrap().is_nan());
        let mut same = back.clone();
        same.nodata = meta.nodata;
        assert_eq!(format!("{same:?}"), format!("{meta:?}"));
        let attrs = read_group_attributes(dir.path()).unwrap();
        assert_eq!(attrs["dsmstream"]["nodata"], "nan");
        let ds = &attrs["multiscales"]["layout"];
        assert_eq!(ds[1]["asset"], "1");
        assert_eq!(ds[1]["spatial:shape"], json!([300, 500]));
        assert_eq!(ds[1]["spatial:transform"][0], 1.0);
        let mut m = meta.clone();
        m.nodata = Some(-9999.0);
        write_group_attributes(dir.path(), &m.to_attributes()).unwrap();
        assert_eq!(read_dsm(dir.path()).unwrap().nodata, Some(-9999.0));
        m.nodata = None;
        write_group_attributes(dir.path(), &m.to_attributes()).unwrap();
        assert_eq!(read_dsm(dir.path()).unwrap(), m);
    }

    #[test]
    fn footprint_is_written_as_the_array_it_always_was() {
        let meta = sample_meta("a");
        let text = serde_json::to_string(&meta.to_attributes()).unwrap();
        let array: [f64; 4] = [630_010.0, 4_832_700.0, 630_500.0, 4_833_000.0];
        let expected = format!("\"footprint\":{}", serde_json::to_string(&array).unwrap());
        assert!(text.contains(&expected), "{text}");
        assert!(text.contains("\"footprint\":[630010.0,4832700.0,630500.0,4833000.0]"));
        let dir = tempfile::tempdir().unwrap();
        write_group_attributes(dir.path(), &meta.to_attributes()).unwrap();
        assert_eq!(read_dsm(dir.path()).unwrap().footprint, Bounds::from(array));
    }

    #[test]
    fn root_attributes_round_trip_and_reject_foreign_groups() {
        let dir = tempfile::tempdir().unwrap();
        let attrs = RootAttrs {
            version: STORE_VERSION,
            crs: Some(sample_meta("a").crs),
            dsms: vec!["a".into(), "b".into()],
        };
        write_root(dir.path(), &attrs).unwrap();
        assert_eq!(read_root(dir.path()).unwrap(), attrs);
        write_group_attributes(dir.path(), &json!({"other": 1})).unwrap();
        let err = read_root(dir.path()).unwrap_err().to_string();
        assert!(err.contains("no \"dsmstream\" attributes"), "{err}");
        let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
        assert_eq!(leftovers.len(), 1, "only zarr.json remains");
    }

    #[test]
    fn compression_parses() {
        assert_eq!(Compression::parse("none"), Some(Compression::None));
        assert_eq!(
            Compression::parse("zstd:7"),
            Some(Compression::Zstd { level: 7 })
        );
        assert_eq!(Compression::parse("gzip"), None);
    }
}
