//! From the first IFD's tags to what the reader needs: the block grid (strip
//! or tile size, offsets and byte counts of band 1's blocks, checked against
//! the file length), the sample type, and the GeoTIFF metadata. Refuses every
//! file the decoder cannot read correctly, naming the reason.

use std::io::{Read, Seek};
use std::path::Path;

use tiff::decoder::{ifd::Value, ChunkType, Decoder};
use tiff::tags::Tag;

use super::decode::tiff_error;
use super::direct::DirectCodec;
use super::lerc;
use super::{GeoTiffError, GeoTiffInfo, SampleType};
use crate::geotiff::gdal_metadata::BandMetadata;
use crate::geotiff::geokeys::{self, tag, GeoKeys};
use crate::geotiff::sidecar;

/// Block grid of band 1. Strips are blocks `width` wide.
#[derive(Clone, Debug)]
pub(super) struct BlockLayout {
    pub width: u64,
    pub height: u64,
    pub block_width: u64,
    pub block_height: u64,
    pub blocks_across: u64,
    /// Compressed size of each block of band 1, row-major (0 = sparse block).
    pub byte_counts: Vec<u64>,
    /// File offset of each block of band 1, row-major.
    pub offsets: Vec<u64>,
    /// Set when the blocks decode without the `tiff` crate (see `direct`).
    pub direct: Option<DirectCodec>,
    /// Set for LERC blocks, with what wraps each blob (see `lerc`).
    pub lerc: Option<lerc::Wrapping>,
    /// Samples interleaved per pixel in a decoded block (1 for planar files).
    pub samples_in_block: usize,
    pub sample_type: SampleType,
}

impl BlockLayout {
    pub fn block_index(&self, bx: u64, by: u64) -> usize {
        (by * self.blocks_across + bx) as usize
    }

    /// Width of the data in the block whose first column is `x0`.
    pub fn block_data_width(&self, x0: u64) -> u64 {
        self.block_width.min(self.width - x0)
    }

    /// (width, height) of the data in block (bx, by), edge blocks clipped.
    pub fn block_data_dims(&self, bx: u64, by: u64) -> (u64, u64) {
        let h = self.block_height.min(self.height - by * self.block_height);
        (self.block_data_width(bx * self.block_width), h)
    }
}

pub(super) struct ParsedTiff {
    pub info: GeoTiffInfo,
    pub layout: BlockLayout,
}

pub(super) fn check_magic(path: &Path, head: &[u8]) -> Result<(), GeoTiffError> {
    let ok = matches!(&head[..4], b"II*\0" | b"MM\0*" | b"II+\0" | b"MM\0+");
    if ok {
        return Ok(());
    }
    let shown: String = head[..4]
        .iter()
        .map(|&b| if b.is_ascii_graphic() { b as char } else { '.' })
        .collect();
    let detail = if &head[..4] == b"LASF" {
        // the most common mistake: a lidar file where a DSM was meant
        "a LAS/LAZ point cloud: grid it into a DSM GeoTIFF first, e.g. with PDAL's writers.gdal"
            .to_string()
    } else {
        format!("starts with {shown:?}")
    };
    Err(GeoTiffError::NotTiff {
        path: path.to_path_buf(),
        detail,
    })
}

/// TIFF compression code to a name (lower case for the ones we read).
pub(super) fn compression_name(code: u16) -> &'static str {
    match code {
        1 => "none",
        2 => "CCITT RLE",
        3 => "CCITT Group 3 fax",
        4 => "CCITT Group 4 fax",
        5 => "lzw",
        6 => "old-style JPEG",
        7 => "JPEG",
        8 | 32946 => "deflate",
        32773 => "packbits",
        34661 => "JBIG",
        34676 | 34677 => "SGI LogLuv",
        34712 => "JPEG 2000",
        34887 => "lerc",
        34925 => "LZMA",
        50000 => "zstd",
        50001 => "WebP",
        50002 | 52546 => "JPEG XL",
        _ => "unknown",
    }
}

fn sample_type(path: &Path, format: u16, bits: u16) -> Result<SampleType, GeoTiffError> {
    Ok(match (format, bits) {
        (1, 8) => SampleType::U8,
        (2, 8) => SampleType::I8,
        (1, 16) => SampleType::U16,
        (2, 16) => SampleType::I16,
        (1, 32) => SampleType::U32,
        (2, 32) => SampleType::I32,
        (3, 16) => SampleType::F16,
        (3, 32) => SampleType::F32,
        (3, 64) => SampleType::F64,
        _ => {
            let kind = match format {
                1 => "unsigned integer",
                2 => "signed integer",
                3 => "float",
                4 => "untyped (void)",
                5 => "complex integer",
                6 => "complex float",
                _ => "unknown",
            };
            return Err(GeoTiffError::UnsupportedSampleFormat {
                path: path.to_path_buf(),
                detail: format!("{bits}-bit {kind} (SampleFormat {format})"),
            });
        }
    })
}

fn value_to_f64s(v: Value) -> Option<Vec<f64>> {
    let one = |v: Value| -> Option<f64> {
        Some(match v {
            Value::Double(d) => d,
            Value::Float(f) => f64::from(f),
            Value::Short(s) => f64::from(s),
            Value::Unsigned(u) => f64::from(u),
            Value::Signed(i) => f64::from(i),
            Value::SignedShort(i) => f64::from(i),
            Value::Byte(b) => f64::from(b),
            _ => return None,
        })
    };
    match v {
        Value::List(items) => items.into_iter().map(one).collect(),
        other => one(other).map(|x| vec![x]),
    }
}

/// An ASCII tag as text, tolerant of missing NULs and non-UTF-8 bytes.
fn ascii_tag<R: Read + Seek>(
    path: &Path,
    d: &mut Decoder<R>,
    t: u16,
) -> Result<Option<String>, GeoTiffError> {
    let mut ifd = d.image_ifd();
    let Some(entry) = ifd.find_entry(Tag::Unknown(t)) else {
        return Ok(None);
    };
    let mut buf = vec![0u8; entry.count().min(1 << 24) as usize];
    ifd.find_tag_bytes(Tag::Unknown(t), &mut buf, 0)
        .map_err(|e| tiff_error(path, e))?;
    Ok(Some(String::from_utf8_lossy(&buf).into_owned()))
}

/// True when tag `t` is stored with TIFF type UNDEFINED (7): opaque bytes,
/// not numbers. GDAL (libgeotiff) ignores geo tags of that type; so do we.
fn is_undefined_type<R: Read + Seek>(d: &mut Decoder<R>, t: u16) -> bool {
    d.image_ifd()
        .find_entry(Tag::Unknown(t))
        .is_some_and(|e| e.field_type() == tiff::tags::Type::UNDEFINED)
}

fn f64_tag<R: Read + Seek>(
    path: &Path,
    d: &mut Decoder<R>,
    t: u16,
) -> Result<Option<Vec<f64>>, GeoTiffError> {
    if is_undefined_type(d, t) {
        return Ok(None);
    }
    let Some(v) = d
        .find_tag(Tag::Unknown(t))
        .map_err(|e| tiff_error(path, e))?
    else {
        return Ok(None);
    };
    value_to_f64s(v)
        .map(Some)
        .ok_or_else(|| GeoTiffError::BadGeoTags {
            path: path.to_path_buf(),
            detail: format!("tag {t} does not hold numbers"),
        })
}

fn u16s<R: Read + Seek>(
    path: &Path,
    d: &mut Decoder<R>,
    t: Tag,
    default: u16,
) -> Result<Vec<u16>, GeoTiffError> {
    Ok(d.find_tag_unsigned_vec::<u16>(t)
        .map_err(|e| tiff_error(path, e))?
        .unwrap_or_else(|| vec![default]))
}

/// The block grid of the IFD `d` is on: strips or tiles, their size, and
/// the offset and byte count of each block of band 1, checked to lie in the
/// file.
pub(super) struct BlockGrid {
    pub tiled: bool,
    pub block_width: u64,
    pub block_height: u64,
    pub offsets: Vec<u64>,
    pub byte_counts: Vec<u64>,
}

/// Read [`BlockGrid`] of a `width` x `height` image from the current IFD.
pub(super) fn read_block_grid<R: Read + Seek>(
    path: &Path,
    d: &mut Decoder<R>,
    width: u64,
    height: u64,
    file_len: u64,
) -> Result<BlockGrid, GeoTiffError> {
    let tiled = d.get_chunk_type() == ChunkType::Tile;
    let (bw, bh) = d.chunk_dimensions();
    let (block_width, block_height) = if tiled {
        (u64::from(bw), u64::from(bh))
    } else {
        (width, u64::from(bh).min(height))
    };
    let (offsets_tag, counts_tag) = if tiled {
        (Tag::TileOffsets, Tag::TileByteCounts)
    } else {
        (Tag::StripOffsets, Tag::StripByteCounts)
    };
    let mut offsets = d
        .find_tag_unsigned_vec::<u64>(offsets_tag)
        .map_err(|e| tiff_error(path, e))?
        .unwrap_or_default();
    let mut byte_counts = d
        .find_tag_unsigned_vec::<u64>(counts_tag)
        .map_err(|e| tiff_error(path, e))?
        .unwrap_or_default();
    let blocks_across = width.div_ceil(block_width);
    let blocks_down = height.div_ceil(block_height);
    let n = (blocks_across * blocks_down) as usize;
    if offsets.len() < n || byte_counts.len() < n {
        return Err(GeoTiffError::Corrupt {
            path: path.to_path_buf(),
            detail: format!(
                "{n} blocks but {} offsets and {} byte counts",
                offsets.len(),
                byte_counts.len()
            ),
        });
    }
    offsets.truncate(n);
    byte_counts.truncate(n);
    for (i, (&o, &c)) in offsets.iter().zip(&byte_counts).enumerate() {
        if c > 0 && o.checked_add(c).is_none_or(|e| e > file_len) {
            return Err(GeoTiffError::Truncated {
                path: path.to_path_buf(),
                detail: format!(
                    "block {i} spans bytes {o}..{} but the file has {file_len} bytes",
                    o.saturating_add(c)
                ),
            });
        }
    }
    Ok(BlockGrid {
        tiled,
        block_width,
        block_height,
        offsets,
        byte_counts,
    })
}

/// Read and validate the first IFD.
pub(super) fn parse<R: Read + Seek>(
    path: &Path,
    d: &mut Decoder<R>,
    file_len: u64,
    bigtiff: bool,
    little_endian: bool,
) -> Result<ParsedTiff, GeoTiffError> {
    let p = || path.to_path_buf();
    let terr = |e| tiff_error(path, e);
    let layout_err = |detail: String| GeoTiffError::UnsupportedLayout { path: p(), detail };
    let (w, h) = d.dimensions().map_err(terr)?;
    let (width, height) = (u64::from(w), u64::from(h));
    if width == 0 || height == 0 {
        return Err(GeoTiffError::ZeroSize {
            path: p(),
            width,
            height,
        });
    }
    let compression = u16s(path, d, Tag::Compression, 1)?[0];
    if !matches!(
        compression,
        1 | 5 | 8 | 32946 | 32773 | 50000 | lerc::COMPRESSION
    ) {
        return Err(GeoTiffError::UnsupportedCompression {
            path: p(),
            name: compression_name(compression).to_string(),
            code: compression,
        });
    }
    let lerc = if compression == lerc::COMPRESSION {
        let parameters = d
            .find_tag_unsigned_vec::<u64>(Tag::Unknown(lerc::PARAMETERS_TAG))
            .map_err(terr)?;
        let wrapping = lerc::Wrapping::from_parameters(parameters.as_deref());
        Some(
            wrapping.ok_or_else(|| GeoTiffError::UnsupportedCompression {
                path: p(),
                name: format!(
                    "LERC with additional compression {} (LercParameters)",
                    parameters.unwrap_or_default().get(1).copied().unwrap_or(0)
                ),
                code: compression,
            })?,
        )
    } else {
        None
    };
    let bits = u16s(path, d, Tag::BitsPerSample, 1)?;
    let formats = u16s(path, d, Tag::SampleFormat, 1)?;
    let band_count = u16s(path, d, Tag::SamplesPerPixel, 1)?[0];
    let sample_type = sample_type(path, formats[0], bits[0])?;
    if bits.iter().any(|&b| b != bits[0]) || formats.iter().any(|&f| f != formats[0]) {
        return Err(layout_err(format!(
            "bands of different types (bits {bits:?}, formats {formats:?})"
        )));
    }
    let photometric = u16s(path, d, Tag::PhotometricInterpretation, 1)?[0];
    if photometric != 1 {
        let what = match photometric {
            0 => "MinIsWhite (inverted grey)",
            2 => "RGB colour",
            3 => "palette colour",
            5 => "CMYK",
            6 => "YCbCr",
            _ => "non-greyscale",
        };
        return Err(layout_err(format!(
            "{what} image (photometric {photometric}), not an elevation raster"
        )));
    }
    let predictor = u16s(path, d, Tag::Predictor, 1)?[0];
    match (predictor, sample_type) {
        (1 | 2, _) | (3, SampleType::F16 | SampleType::F32 | SampleType::F64) => {}
        _ => {
            return Err(layout_err(format!(
                "predictor {predictor} with {} samples",
                sample_type.gdal_name()
            )))
        }
    }
    let planar = u16s(path, d, Tag::PlanarConfiguration, 1)?[0];
    let BlockGrid {
        tiled,
        block_width,
        block_height,
        offsets,
        byte_counts,
    } = read_block_grid(path, d, width, height, file_len)?;
    let blocks_across = width.div_ceil(block_width);

    let pam = sidecar::pam(path)?;
    let georef = read_georeferencing(path, d, pam.as_ref())?;
    let mut nodata =
        ascii_tag(path, d, tag::GDAL_NODATA)?.and_then(|s| geokeys::parse_gdal_nodata(&s));
    let mut band = ascii_tag(path, d, tag::GDAL_METADATA)?
        .map(|xml| BandMetadata::parse(xml.trim_end_matches('\0')))
        .unwrap_or_default();
    if let Some(pam) = &pam {
        // as GDAL: the side file's band values where the file has none
        nodata = nodata.or(pam.band.nodata);
        if !band.rescales() {
            band.scale = pam.band.scale.unwrap_or(band.scale);
            band.offset = pam.band.offset.unwrap_or(band.offset);
        }
        band.unit = band.unit.or_else(|| pam.band.unit.clone());
    }
    let samples_in_block = if planar == 2 {
        1
    } else {
        usize::from(band_count)
    };
    let float32 = sample_type == SampleType::F32;
    let layout = BlockLayout {
        width,
        height,
        block_width,
        block_height,
        blocks_across,
        byte_counts,
        offsets,
        lerc,
        direct: DirectCodec::for_tags(
            compression,
            predictor,
            float32,
            samples_in_block,
            little_endian,
        ),
        samples_in_block,
        sample_type,
    };
    let info = GeoTiffInfo {
        path: p(),
        width,
        height,
        sample_type,
        compression: match lerc {
            Some(lerc::Wrapping::Deflate) => "lerc_deflate",
            Some(lerc::Wrapping::Zstd) => "lerc_zstd",
            _ => compression_name(compression),
        }
        .to_string(),
        tiled,
        block_width: block_width as u32,
        block_height: block_height as u32,
        bigtiff,
        geotransform: georef.geotransform,
        crs: georef.crs,
        nodata,
        band_count,
        predictor,
        pixel_is_point: georef.pixel_is_point,
        band,
        internal_mask: false,
        georeferenced_by: georef.georeferenced_by,
    };
    Ok(ParsedTiff { info, layout })
}

fn read_georeferencing<R: Read + Seek>(
    path: &Path,
    d: &mut Decoder<R>,
    pam: Option<&sidecar::Pam>,
) -> Result<sidecar::Georeferencing, GeoTiffError> {
    let gk = |e| GeoTiffError::from_geokeys(path, e);
    let scale = f64_tag(path, d, tag::MODEL_PIXEL_SCALE)?;
    let tiepoint = f64_tag(path, d, tag::MODEL_TIEPOINT)?;
    let transformation = f64_tag(path, d, tag::MODEL_TRANSFORMATION)?;
    let directory = if is_undefined_type(d, tag::GEO_KEY_DIRECTORY) {
        Vec::new()
    } else {
        d.find_tag_unsigned_vec::<u16>(Tag::Unknown(tag::GEO_KEY_DIRECTORY))
            .map_err(|e| tiff_error(path, e))?
            .unwrap_or_default()
    };
    let doubles = f64_tag(path, d, tag::GEO_DOUBLE_PARAMS)?.unwrap_or_default();
    let ascii = ascii_tag(path, d, tag::GEO_ASCII_PARAMS)?;
    let keys = if directory.is_empty() {
        GeoKeys::default()
    } else {
        GeoKeys::parse(&directory, &doubles, ascii.as_deref().unwrap_or("")).map_err(gk)?
    };
    let pixel_is_point = keys.pixel_is_point();
    let in_tags = sidecar::InTags {
        transform: geokeys::geotransform_from_tags(
            scale.as_deref(),
            tiepoint.as_deref(),
            transformation.as_deref(),
            pixel_is_point,
        ),
        crs: geokeys::crs_from_tags(&directory, &doubles, ascii.as_deref()).map_err(gk)?,
        names_a_crs: !directory.is_empty(),
        pixel_is_point,
    };
    sidecar::with_side_files(path, pam, in_tags)
}
