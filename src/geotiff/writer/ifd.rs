//! TIFF byte layout for the COG writer: the file header with GDAL's ghost area,
//! and Image File Directories (classic or BigTIFF) serialised at a known offset
//! with their out-of-line values right after the entries.
//!
//! The size of a directory depends only on its tags and value counts, never on
//! the values, so the writer can lay out every IFD first, then compute the final
//! tile offsets, then serialise again with the real values.

use super::CogSample;
use crate::geo::{Crs, GeoTransform};

/// TIFF field types used here.
#[derive(Clone, Debug)]
pub(crate) enum Value {
    Short(Vec<u16>),
    Long(Vec<u32>),
    Long8(Vec<u64>),
    Double(Vec<f64>),
    /// NUL terminator added when written.
    Ascii(String),
}

impl Value {
    fn type_code(&self) -> u16 {
        match self {
            Value::Short(_) => 3,
            Value::Long(_) => 4,
            Value::Long8(_) => 16,
            Value::Double(_) => 12,
            Value::Ascii(_) => 2,
        }
    }

    fn count(&self) -> u64 {
        match self {
            Value::Short(v) => v.len() as u64,
            Value::Long(v) => v.len() as u64,
            Value::Long8(v) => v.len() as u64,
            Value::Double(v) => v.len() as u64,
            Value::Ascii(s) => s.len() as u64 + 1,
        }
    }

    fn bytes(&self) -> Vec<u8> {
        match self {
            Value::Short(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Value::Long(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Value::Long8(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Value::Double(v) => v.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Value::Ascii(s) => s.bytes().chain(std::iter::once(0)).collect(),
        }
    }
}

/// One tag of a directory.
#[derive(Clone, Debug)]
pub(crate) struct Entry {
    pub tag: u16,
    pub value: Value,
}

/// Bytes before the first IFD: the TIFF header, then GDAL's "ghost" structural
/// metadata: IFDs before the data, tiles row-major, each tile framed by its size
/// and its last 4 bytes (what GDAL's COG driver writes; GDAL then reports LAYOUT=COG).
pub(crate) fn header(first_ifd_offset: u64, bigtiff: bool) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(b"II");
    if bigtiff {
        out.extend_from_slice(&43u16.to_le_bytes());
        out.extend_from_slice(&8u16.to_le_bytes());
        out.extend_from_slice(&0u16.to_le_bytes());
        out.extend_from_slice(&first_ifd_offset.to_le_bytes());
    } else {
        out.extend_from_slice(&42u16.to_le_bytes());
        out.extend_from_slice(&(first_ifd_offset as u32).to_le_bytes());
    }
    let body = "LAYOUT=IFDS_BEFORE_DATA\nBLOCK_ORDER=ROW_MAJOR\n\
                BLOCK_LEADER=SIZE_AS_UINT4\nBLOCK_TRAILER=LAST_4_BYTES_REPEATED\n\
                KNOWN_INCOMPATIBLE_EDITION=NO\n";
    out.extend_from_slice(
        format!(
            "GDAL_STRUCTURAL_METADATA_SIZE={:06} bytes\n{body}",
            body.len()
        )
        .as_bytes(),
    );
    pad_to_8(&mut out);
    out
}

/// Length of [`header`] (it does not depend on the offset value).
pub(crate) fn header_len(bigtiff: bool) -> u64 {
    header(0, bigtiff).len() as u64
}

fn pad_to_8(buf: &mut Vec<u8>) {
    while !buf.len().is_multiple_of(8) {
        buf.push(0);
    }
}

/// Serialise one IFD that will sit at file offset `at`, its out-of-line values
/// following the entries; `next` is the next IFD's offset (0 = last). Entries
/// must be sorted by tag. The result length is a multiple of 8.
pub(crate) fn serialize_ifd(entries: &[Entry], at: u64, next: u64, bigtiff: bool) -> Vec<u8> {
    debug_assert!(entries.windows(2).all(|w| w[0].tag < w[1].tag));
    let (entry_len, inline_cap, count_len) = if bigtiff { (20, 8, 8) } else { (12, 4, 2) };
    let next_len = if bigtiff { 8 } else { 4 };
    let fixed = count_len + entries.len() * entry_len + next_len;
    let mut out = Vec::with_capacity(fixed);
    let mut extra: Vec<u8> = Vec::new();
    let mut extra_at = at + fixed as u64;
    extra_at += (8 - extra_at % 8) % 8;
    let extra_base = extra_at;

    if bigtiff {
        out.extend_from_slice(&(entries.len() as u64).to_le_bytes());
    } else {
        out.extend_from_slice(&(entries.len() as u16).to_le_bytes());
    }
    for e in entries {
        out.extend_from_slice(&e.tag.to_le_bytes());
        out.extend_from_slice(&e.value.type_code().to_le_bytes());
        if bigtiff {
            out.extend_from_slice(&e.value.count().to_le_bytes());
        } else {
            out.extend_from_slice(&(e.value.count() as u32).to_le_bytes());
        }
        let mut data = e.value.bytes();
        if data.len() <= inline_cap {
            data.resize(inline_cap, 0);
            out.extend_from_slice(&data);
        } else {
            let offset = extra_base + extra.len() as u64;
            if bigtiff {
                out.extend_from_slice(&offset.to_le_bytes());
            } else {
                out.extend_from_slice(&(offset as u32).to_le_bytes());
            }
            extra.extend_from_slice(&data);
            pad_to_8(&mut extra);
        }
    }
    if bigtiff {
        out.extend_from_slice(&next.to_le_bytes());
    } else {
        out.extend_from_slice(&(next as u32).to_le_bytes());
    }
    out.resize((extra_base - at) as usize, 0);
    out.extend_from_slice(&extra);
    out
}

/// Tags describing one image (full resolution or overview) of the COG.
pub(crate) struct ImageTags<'a> {
    pub width: u64,
    pub height: u64,
    pub tile_size: u32,
    pub overview: bool,
    pub tile_offsets: &'a [u64],
    pub tile_byte_counts: &'a [u64],
    /// Written on the full-resolution image only.
    pub geo: Option<(&'a GeoTransform, &'a Crs)>,
    /// GDAL_NODATA, written for Float32 only.
    pub nodata: f32,
    pub sample: CogSample,
    /// GDAL_METADATA XML (the full-resolution image only).
    pub metadata: Option<String>,
}

/// GDAL_NODATA text: "nan" for NaN, else the shortest decimal that round-trips.
pub(crate) fn nodata_ascii(nodata: f32) -> String {
    if nodata.is_nan() {
        "nan".to_string()
    } else {
        format!("{nodata}")
    }
}

/// The directory entries of one image, sorted by tag.
pub(crate) fn image_entries(t: &ImageTags<'_>, bigtiff: bool) -> Vec<Entry> {
    let offsets = |v: &[u64]| {
        if bigtiff {
            Value::Long8(v.to_vec())
        } else {
            Value::Long(v.iter().map(|&x| x as u32).collect())
        }
    };
    // (BitsPerSample, Predictor, SampleFormat)
    let (bits, predictor, format) = match t.sample {
        CogSample::Float32 => (32, 3, 3),
        CogSample::UInt16 => (16, 2, 1),
    };
    let mut e = vec![
        Entry {
            tag: 254,
            value: Value::Long(vec![u32::from(t.overview)]),
        },
        Entry {
            tag: 256,
            value: Value::Long(vec![t.width as u32]),
        },
        Entry {
            tag: 257,
            value: Value::Long(vec![t.height as u32]),
        },
        Entry {
            tag: 258,
            value: Value::Short(vec![bits]),
        },
        Entry {
            tag: 259,
            value: Value::Short(vec![8]),
        },
        Entry {
            tag: 262,
            value: Value::Short(vec![1]),
        },
        Entry {
            tag: 277,
            value: Value::Short(vec![1]),
        },
        Entry {
            tag: 284,
            value: Value::Short(vec![1]),
        },
        Entry {
            tag: 317,
            value: Value::Short(vec![predictor]),
        },
        Entry {
            tag: 322,
            value: Value::Long(vec![t.tile_size]),
        },
        Entry {
            tag: 323,
            value: Value::Long(vec![t.tile_size]),
        },
        Entry {
            tag: 324,
            value: offsets(t.tile_offsets),
        },
        Entry {
            tag: 325,
            value: offsets(t.tile_byte_counts),
        },
        Entry {
            tag: 339,
            value: Value::Short(vec![format]),
        },
    ];
    if let Some((gt, crs)) = t.geo {
        e.extend(geo_entries(gt, crs));
    }
    if let Some(xml) = &t.metadata {
        e.push(Entry {
            tag: 42112,
            value: Value::Ascii(xml.clone()),
        });
    }
    if t.sample == CogSample::Float32 {
        e.push(Entry {
            tag: 42113,
            value: Value::Ascii(nodata_ascii(t.nodata)),
        });
    }
    e
}

/// ModelPixelScale + ModelTiepoint (north-up) or ModelTransformation, and the
/// GeoKey directory: the CRS's raw keys when it has them (raster type forced to
/// pixel-is-area, which is what the tiepoint means), else a minimal directory.
fn geo_entries(gt: &GeoTransform, crs: &Crs) -> Vec<Entry> {
    let g = &gt.0;
    let mut e = Vec::new();
    if g[2] == 0.0 && g[4] == 0.0 {
        e.push(Entry {
            tag: 33550,
            value: Value::Double(vec![g[1], -g[5], 0.0]),
        });
        e.push(Entry {
            tag: 33922,
            value: Value::Double(vec![0.0, 0.0, 0.0, g[0], g[3], 0.0]),
        });
    } else {
        let m = vec![
            g[1], g[2], 0.0, g[0], g[4], g[5], 0.0, g[3], 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
        ];
        e.push(Entry {
            tag: 34264,
            value: Value::Double(m),
        });
    }
    let keys = if crs.geokeys.len() >= 4 {
        let mut keys = crs.geokeys.clone();
        for k in keys[4..].chunks_exact_mut(4) {
            if k[0] == 1025 && k[1] == 0 {
                k[3] = 1;
            }
        }
        keys
    } else {
        minimal_geokeys(crs)
    };
    e.push(Entry {
        tag: 34735,
        value: Value::Short(keys),
    });
    if crs.geokeys.len() >= 4 && !crs.geo_doubles.is_empty() {
        e.push(Entry {
            tag: 34736,
            value: Value::Double(crs.geo_doubles.clone()),
        });
    }
    if crs.geokeys.len() >= 4 {
        if let Some(ascii) = &crs.geo_ascii {
            e.push(Entry {
                tag: 34737,
                value: Value::Ascii(ascii.clone()),
            });
        }
    }
    e
}

/// Model type (1 projected, 2 geographic), raster type 1 (pixel-is-area) and the
/// EPSG code as ProjectedCSTypeGeoKey (3072) or GeographicTypeGeoKey (2048).
pub(crate) fn minimal_geokeys(crs: &Crs) -> Vec<u16> {
    let mut keys: Vec<[u16; 4]> = Vec::new();
    if crs.epsg.is_some() {
        keys.push([1024, 0, 1, if crs.is_geographic { 2 } else { 1 }]);
    }
    keys.push([1025, 0, 1, 1]);
    if let Some(code) = crs.epsg {
        let key = if crs.is_geographic { 2048 } else { 3072 };
        keys.push([key, 0, 1, code.min(u16::MAX as u32) as u16]);
    }
    let mut out = vec![1, 1, 0, keys.len() as u16];
    out.extend(keys.iter().flatten());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ifd_size_does_not_depend_on_values() {
        for bigtiff in [false, true] {
            let crs = Crs {
                epsg: Some(32617),
                ..Default::default()
            };
            let gt = GeoTransform::north_up(500_000.0, 4_800_000.0, 0.5, 0.5);
            let make = |v: &'static [u64; 12]| ImageTags {
                width: 1000,
                height: 700,
                tile_size: 256,
                overview: false,
                tile_offsets: v,
                tile_byte_counts: v,
                geo: Some((&gt, &crs)),
                nodata: f32::NAN,
                sample: CogSample::Float32,
                metadata: None,
            };
            let a = serialize_ifd(&image_entries(&make(&[0; 12]), bigtiff), 16, 0, bigtiff);
            let big = &[3_000_000_000; 12];
            let b = serialize_ifd(&image_entries(&make(big), bigtiff), 16, 999, bigtiff);
            assert_eq!(a.len(), b.len());
            assert_eq!(a.len() % 8, 0);
        }
    }

    #[test]
    fn minimal_geokeys_name_the_projected_code() {
        let crs = Crs {
            epsg: Some(32617),
            ..Default::default()
        };
        assert_eq!(
            minimal_geokeys(&crs),
            vec![1, 1, 0, 3, 1024, 0, 1, 1, 1025, 0, 1, 1, 3072, 0, 1, 32617]
        );
        assert_eq!(nodata_ascii(-9999.0), "-9999");
        assert_eq!(nodata_ascii(f32::NAN), "nan");
    }

    #[test]
    fn header_fits_before_300_bytes() {
        assert!(header_len(false) < 300 && header_len(true) < 300);
        assert_eq!(header_len(false) % 8, 0);
        assert_eq!(&header(8, false)[..4], b"II*\0");
    }
}
