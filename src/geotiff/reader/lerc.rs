//! LERC blocks (TIFF compression 34887), as GDAL writes `COMPRESS=LERC`,
//! `LERC_DEFLATE` and `LERC_ZSTD` (ESRI's and many cloud elevation
//! products): each block is one Lerc2 blob, lossless or within the writer's
//! `MAX_Z_ERROR`, optionally wrapped in Deflate or Zstandard as the
//! LercParameters tag (50674: [LERC version, 0 none | 1 deflate | 2 zstd])
//! says. Blobs are decoded by `lerc-reader` (pure Rust); pixels the blob's
//! validity mask marks invalid are no-data.

use std::io::Read;

/// TIFF compression code of LERC.
pub(super) const COMPRESSION: u16 = 34887;
/// The LercParameters tag (GDAL / libtiff's TIFFTAG_LERC_PARAMETERS).
pub(super) const PARAMETERS_TAG: u16 = 50674;

/// What wraps each block's LERC blob.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Wrapping {
    None,
    Deflate,
    Zstd,
}

impl Wrapping {
    /// From the LercParameters tag's values (absent: no wrapping); `None`
    /// for an additional compression this reader does not know.
    pub fn from_parameters(values: Option<&[u64]>) -> Option<Wrapping> {
        match values.and_then(|v| v.get(1)).copied().unwrap_or(0) {
            0 => Some(Wrapping::None),
            1 => Some(Wrapping::Deflate),
            2 => Some(Wrapping::Zstd),
            _ => None,
        }
    }
}

/// One decoded block: `width` samples a row (the blob's, padding included),
/// `depth` samples a pixel (band 1 is the first), validity per pixel.
pub(super) struct Block {
    pub width: usize,
    pub height: usize,
    pub depth: usize,
    pub values: Vec<f64>,
    pub mask: Option<Vec<u8>>,
}

impl Block {
    /// Band 1 at (column, row) of the block; None where the mask says invalid.
    #[inline]
    pub fn get(&self, col: usize, row: usize) -> Option<f64> {
        let pixel = row * self.width + col;
        if self.mask.as_ref().is_some_and(|m| m[pixel] == 0) {
            return None;
        }
        Some(self.values[pixel * self.depth])
    }
}

/// Unwrap and decode one block's bytes; the message says what failed.
pub(super) fn decode(
    wrapping: Wrapping,
    stored: &[u8],
    scratch: &mut Vec<u8>,
) -> Result<Block, String> {
    let blob: &[u8] = match wrapping {
        Wrapping::None => stored,
        Wrapping::Deflate => {
            scratch.clear();
            flate2::read::ZlibDecoder::new(stored)
                .read_to_end(scratch)
                .map_err(|e| format!("its Deflate wrapping does not inflate: {e}"))?;
            scratch
        }
        Wrapping::Zstd => {
            scratch.clear();
            zstd::stream::read::Decoder::new(stored)
                .and_then(|mut d| d.read_to_end(scratch))
                .map_err(|e| format!("its Zstandard wrapping does not decode: {e}"))?;
            scratch
        }
    };
    let decoded = lerc_reader::decode_first_to_f64(blob).map_err(|e| format!("LERC: {e}"))?;
    let info = &decoded.info;
    let (width, height, depth) = (
        info.width as usize,
        info.height as usize,
        info.depth.max(1) as usize,
    );
    if decoded.pixels.len() < width * height * depth
        || decoded
            .mask
            .as_ref()
            .is_some_and(|m| m.len() < width * height)
    {
        return Err(format!(
            "LERC blob of {width} x {height} x {depth} holds {} samples",
            decoded.pixels.len()
        ));
    }
    Ok(Block {
        width,
        height,
        depth,
        values: decoded.pixels,
        mask: decoded.mask,
    })
}
