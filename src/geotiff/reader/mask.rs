//! GDAL's internal mask band: a second full-resolution IFD of the file with
//! NewSubfileType 4 (a transparency mask), 1 bit (or 8 bits) a pixel, 0
//! where the raster has no data (`GDAL_TIFF_INTERNAL_MASK`, `gdal_translate
//! -mask`, `write_mask` in rasterio). GDAL's mask band then replaces the
//! no-data value: masked pixels hold anything (often 0), so they must
//! become NaN, not heights. Its blocks are decoded here from the memory map
//! (the `tiff` crate does not read transparency masks): none, Deflate, LZW,
//! PackBits or ZSTD, no predictor.

use std::io::Read;
use std::path::{Path, PathBuf};

use tiff::tags::Tag;

use super::decode::{new_decoder, tiff_error, MapBytes};
use super::GeoTiffError;

/// NewSubfileType of a full-resolution transparency mask (bit 2 set, not a
/// reduced-resolution overview).
const SUBFILE_MASK: u32 = 4;

/// The mask IFD's block grid and codec, and the last block row decoded.
pub(super) struct MaskBand {
    path: PathBuf,
    map: MapBytes,
    width: u64,
    height: u64,
    block_width: u64,
    block_height: u64,
    blocks_across: u64,
    bits: u16,
    compression: u16,
    offsets: Vec<u64>,
    byte_counts: Vec<u64>,
    /// (block row, one byte per pixel: 1 valid, 0 masked; `width` a row).
    kept: Option<(u64, Vec<u8>)>,
}

impl MaskBand {
    /// The file's internal mask for a `width` x `height` band 1, if it has one.
    pub fn find(
        path: &Path,
        map: &MapBytes,
        width: u64,
        height: u64,
    ) -> Result<Option<MaskBand>, GeoTiffError> {
        let terr = |e| tiff_error(path, e);
        let layout = |detail: String| GeoTiffError::UnsupportedLayout {
            path: path.to_path_buf(),
            detail,
        };
        let mut d = new_decoder(map).map_err(terr)?;
        while d.more_images() {
            // Band 1 was read already: an IFD after it the decoder cannot
            // parse (an exotic overview) ends the search, not the file.
            if let Err(e) = d.next_image() {
                tracing::debug!(path = %path.display(), error = %e, "IFD after the first not read");
                break;
            }
            let subfile = d
                .find_tag_unsigned::<u32>(Tag::NewSubfileType)
                .map_err(terr)?;
            if subfile != Some(SUBFILE_MASK)
                || d.dimensions().map_err(terr)? != (width as u32, height as u32)
            {
                continue;
            }
            let short = |d: &mut super::decode::TiffDecoder, t: Tag, default: u16| {
                d.find_tag_unsigned::<u16>(t).map(|v| v.unwrap_or(default))
            };
            let bits = short(&mut d, Tag::BitsPerSample, 1).map_err(terr)?;
            let compression = short(&mut d, Tag::Compression, 1).map_err(terr)?;
            let predictor = short(&mut d, Tag::Predictor, 1).map_err(terr)?;
            if !matches!(bits, 1 | 8) || predictor != 1 {
                return Err(layout(format!(
                    "an internal mask of {bits} bits a pixel with predictor {predictor}"
                )));
            }
            if !matches!(compression, 1 | 5 | 8 | 32946 | 32773 | 50000) {
                return Err(layout(format!(
                    "an internal mask compressed with {} (TIFF code {compression})",
                    super::layout::compression_name(compression)
                )));
            }
            let file_len = map.as_ref().len() as u64;
            let grid = super::layout::read_block_grid(path, &mut d, width, height, file_len)?;
            return Ok(Some(MaskBand {
                path: path.to_path_buf(),
                map: map.clone(),
                width,
                height,
                block_width: grid.block_width,
                block_height: grid.block_height,
                blocks_across: width.div_ceil(grid.block_width),
                bits,
                compression,
                offsets: grid.offsets,
                byte_counts: grid.byte_counts,
                kept: None,
            }));
        }
        Ok(None)
    }

    /// Set to NaN every value of rows `row0 ..` (`out`, `width` a row) the
    /// mask marks as no data.
    pub fn apply(&mut self, row0: u64, out: &mut [f32]) -> Result<(), GeoTiffError> {
        let width = self.width as usize;
        let rows = (out.len() / width.max(1)) as u64;
        for row in row0..row0 + rows {
            let block_row = row / self.block_height;
            if self.kept.as_ref().is_none_or(|(r, _)| *r != block_row) {
                self.kept = Some((block_row, self.decode_block_row(block_row)?));
            }
            let (_, valid) = self.kept.as_ref().expect("just decoded");
            let at = (row - block_row * self.block_height) as usize * width;
            let target = &mut out[(row - row0) as usize * width..][..width];
            for (v, &ok) in target.iter_mut().zip(&valid[at..at + width]) {
                if ok == 0 {
                    *v = f32::NAN;
                }
            }
        }
        Ok(())
    }

    /// One byte a pixel (1 valid, 0 masked) for every row of block row `by`.
    fn decode_block_row(&self, by: u64) -> Result<Vec<u8>, GeoTiffError> {
        let rows = self.block_height.min(self.height - by * self.block_height) as usize;
        let width = self.width as usize;
        let mut valid = vec![1u8; width * rows];
        let row_bytes = (self.block_width as usize * usize::from(self.bits)).div_ceil(8);
        for bx in 0..self.blocks_across {
            let index = (by * self.blocks_across + bx) as usize;
            let (offset, count) = (
                self.offsets[index] as usize,
                self.byte_counts[index] as usize,
            );
            let x0 = (bx * self.block_width) as usize;
            let w = (self.block_width as usize).min(width - x0);
            if count == 0 {
                // a sparse mask block: GDAL reads it as all masked
                for r in 0..rows {
                    valid[r * width + x0..][..w].fill(0);
                }
                continue;
            }
            let stored = &self.map.as_ref()[offset..offset + count];
            let bytes =
                unpack(self.compression, stored).map_err(|detail| GeoTiffError::Corrupt {
                    path: self.path.clone(),
                    detail: format!("internal mask block ({bx}, {by}) does not decode: {detail}"),
                })?;
            // a tile holds block_height rows; a strip its own
            let block_rows = bytes.len() / row_bytes.max(1);
            if block_rows < rows {
                return Err(GeoTiffError::Corrupt {
                    path: self.path.clone(),
                    detail: format!(
                        "internal mask block ({bx}, {by}) holds {block_rows} rows of {rows}"
                    ),
                });
            }
            for r in 0..rows {
                let src = &bytes[r * row_bytes..][..row_bytes];
                let dst = &mut valid[r * width + x0..][..w];
                for (x, v) in dst.iter_mut().enumerate() {
                    let set = match self.bits {
                        1 => src[x / 8] & (0x80 >> (x % 8)) != 0,
                        _ => src[x] != 0,
                    };
                    *v = u8::from(set);
                }
            }
        }
        Ok(valid)
    }
}

/// The decompressed bytes of one stored block.
fn unpack(compression: u16, stored: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    match compression {
        1 => out.extend_from_slice(stored),
        8 | 32946 => {
            flate2::read::ZlibDecoder::new(stored)
                .read_to_end(&mut out)
                .map_err(|e| e.to_string())?;
        }
        50000 => {
            zstd::stream::read::Decoder::new(stored)
                .and_then(|mut d| d.read_to_end(&mut out))
                .map_err(|e| e.to_string())?;
        }
        5 => {
            out = weezl::decode::Decoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8)
                .decode(stored)
                .map_err(|e| e.to_string())?;
        }
        32773 => out = unpack_bits(stored)?,
        other => return Err(format!("compression {other}")),
    }
    Ok(out)
}

/// PackBits (TIFF compression 32773): a header byte n, then n + 1 literal
/// bytes (n 0..=127), or one byte repeated 1 - n times (n -127..=-1); -128 is
/// skipped.
fn unpack_bits(mut stored: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    while let Some((&n, rest)) = stored.split_first() {
        let n = n as i8;
        stored = rest;
        if n >= 0 {
            let take = n as usize + 1;
            let literal = stored.get(..take).ok_or("PackBits literal past the end")?;
            out.extend_from_slice(literal);
            stored = &stored[take..];
        } else if n != -128 {
            let (&byte, rest) = stored.split_first().ok_or("PackBits run past the end")?;
            out.extend(std::iter::repeat_n(byte, 1 + (-(n as i16)) as usize));
            stored = rest;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packbits_literals_and_runs() {
        // the example of the TIFF 6.0 specification
        let packed = [
            0xFE, 0xAA, 0x02, 0x80, 0x00, 0x2A, 0xFD, 0xAA, 0x03, 0x80, 0x00, 0x2A, 0x22, 0xF7,
            0xAA,
        ];
        let unpacked = [
            0xAA, 0xAA, 0xAA, 0x80, 0x00, 0x2A, 0xAA, 0xAA, 0xAA, 0xAA, 0x80, 0x00, 0x2A, 0x22,
            0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA, 0xAA,
        ];
        assert_eq!(unpack_bits(&packed).unwrap(), unpacked);
        assert!(unpack_bits(&[0x05, 0x01]).is_err());
    }

    /// Each mask codec GDAL or another writer may use gives back the bytes
    /// its encoder was given (GDAL itself deflates masks: its fixtures test
    /// that path against GDAL's reading).
    #[test]
    fn every_mask_codec_round_trips() {
        use std::io::Write;
        let bits: Vec<u8> = (0..400u32)
            .map(|k| (k.wrapping_mul(2_654_435_761) >> 24) as u8)
            .collect();
        let mut zlib = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        zlib.write_all(&bits).unwrap();
        let lzw = weezl::encode::Encoder::with_tiff_size_switch(weezl::BitOrder::Msb, 8)
            .encode(&bits)
            .unwrap();
        let literal: Vec<u8> = (bits.chunks(128))
            .flat_map(|c| std::iter::once(c.len() as u8 - 1).chain(c.iter().copied()))
            .collect();
        for (code, stored) in [
            (1, bits.clone()),
            (8, zlib.finish().unwrap()),
            (5, lzw),
            (50000, zstd::encode_all(&bits[..], 3).unwrap()),
            (32773, literal),
        ] {
            assert_eq!(unpack(code, &stored).unwrap(), bits, "compression {code}");
        }
        assert!(unpack(7, &bits).is_err());
        assert!(unpack(8, &bits[..10]).is_err());
    }
}
