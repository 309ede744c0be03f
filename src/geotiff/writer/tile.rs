//! One tile's bytes: float32 samples through the TIFF floating-point predictor
//! (Predictor = 3, Adobe Technical Note 3), or UInt16 samples through the
//! horizontal differencing predictor (Predictor = 2), and zlib Deflate
//! (Compression = 8); the inverse for reading spilled tiles back, and the
//! no-data-aware 2x mean that builds an overview tile from its four children.
//!
//! Predictor 3, per tile row of `w` samples: write the bytes of every sample
//! grouped by significance (the most significant byte of all samples first,
//! whatever the file byte order), then replace each byte by its difference with
//! the previous one. GDAL, libtiff and the `tiff` crate all decode this layout.

use std::io::{Read, Write};

use flate2::read::ZlibDecoder;
use flate2::write::ZlibEncoder;
use flate2::Compression;

use super::{CogOptions, CogSample};

/// Deflate level; 6 is zlib's and GDAL's default.
const DEFLATE_LEVEL: u32 = 6;

/// The part of a tile inside the image (the rest is edge padding).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Valid {
    pub width: usize,
    pub height: usize,
}

/// Encode a `tile_size`² tile in the sample type of `options`.
pub(crate) fn encode_tile(
    values: &[f32],
    tile_size: usize,
    valid: Valid,
    options: &CogOptions,
) -> std::io::Result<Vec<u8>> {
    match options.sample {
        CogSample::Float32 => {
            encode_f32_tile(values, tile_size, valid.width, valid.height, options.nodata)
        }
        CogSample::UInt16 => encode_u16_tile(values, tile_size, valid),
    }
}

/// Decode a tile written by [`encode_tile`] with the same `options`.
pub(crate) fn decode_tile(
    bytes: &[u8],
    tile_size: usize,
    options: &CogOptions,
) -> std::io::Result<Vec<f32>> {
    match options.sample {
        CogSample::Float32 => decode_f32_tile(bytes, tile_size, options.nodata),
        CogSample::UInt16 => decode_u16_tile(bytes, tile_size),
    }
}

fn deflate(bytes: &[u8]) -> std::io::Result<Vec<u8>> {
    let mut encoder = ZlibEncoder::new(
        Vec::with_capacity(bytes.len() / 3),
        Compression::new(DEFLATE_LEVEL),
    );
    encoder.write_all(bytes)?;
    encoder.finish()
}

fn inflate(bytes: &[u8], expected: usize) -> std::io::Result<Vec<u8>> {
    let mut out = Vec::with_capacity(expected);
    ZlibDecoder::new(bytes).read_to_end(&mut out)?;
    if out.len() != expected {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "spilled tile inflates to {} bytes, expected {expected}",
                out.len()
            ),
        ));
    }
    Ok(out)
}

/// UInt16 tile: values rounded and clamped to 0..=65535, NaN and edge padding
/// 0; each row differenced sample by sample (predictor 2), little-endian.
fn encode_u16_tile(values: &[f32], tile_size: usize, valid: Valid) -> std::io::Result<Vec<u8>> {
    debug_assert_eq!(values.len(), tile_size * tile_size);
    let mut bytes = Vec::with_capacity(2 * tile_size * tile_size);
    for (row, src) in values.chunks_exact(tile_size).enumerate() {
        let mut prev = 0u16;
        for (col, &v) in src.iter().enumerate() {
            let inside = row < valid.height && col < valid.width && !v.is_nan();
            let count = if inside {
                v.round().clamp(0.0, u16::MAX as f32) as u16
            } else {
                0
            };
            bytes.extend_from_slice(&count.wrapping_sub(prev).to_le_bytes());
            prev = count;
        }
    }
    deflate(&bytes)
}

fn decode_u16_tile(bytes: &[u8], tile_size: usize) -> std::io::Result<Vec<f32>> {
    let raw = inflate(bytes, 2 * tile_size * tile_size)?;
    let mut values = Vec::with_capacity(tile_size * tile_size);
    for row in raw.chunks_exact(2 * tile_size) {
        let mut acc = 0u16;
        for pair in row.chunks_exact(2) {
            acc = acc.wrapping_add(u16::from_le_bytes([pair[0], pair[1]]));
            values.push(acc as f32);
        }
    }
    Ok(values)
}

/// Encode a `tile_size`² float32 tile: pixels outside `valid_w` x `valid_h` (edge
/// padding) and NaN pixels become `nodata`, then predictor 3 and Deflate.
fn encode_f32_tile(
    values: &[f32],
    tile_size: usize,
    valid_w: usize,
    valid_h: usize,
    nodata: f32,
) -> std::io::Result<Vec<u8>> {
    debug_assert_eq!(values.len(), tile_size * tile_size);
    let row_bytes = tile_size * 4;
    let mut shuffled = vec![0u8; row_bytes * tile_size];
    for (row, out) in shuffled.chunks_exact_mut(row_bytes).enumerate() {
        let src = &values[row * tile_size..(row + 1) * tile_size];
        for (col, &v) in src.iter().enumerate() {
            let v = if row >= valid_h || col >= valid_w || v.is_nan() {
                nodata
            } else {
                v
            };
            let be = v.to_bits().to_be_bytes();
            for (plane, byte) in be.iter().enumerate() {
                out[plane * tile_size + col] = *byte;
            }
        }
        for i in (1..row_bytes).rev() {
            out[i] = out[i].wrapping_sub(out[i - 1]);
        }
    }
    deflate(&shuffled)
}

/// Decode a tile written by [`encode_f32_tile`]; samples equal to `nodata` become NaN.
fn decode_f32_tile(bytes: &[u8], tile_size: usize, nodata: f32) -> std::io::Result<Vec<f32>> {
    let row_bytes = tile_size * 4;
    let mut shuffled = inflate(bytes, row_bytes * tile_size)?;
    let mut values = Vec::with_capacity(tile_size * tile_size);
    for row in shuffled.chunks_exact_mut(row_bytes) {
        for i in 1..row_bytes {
            row[i] = row[i].wrapping_add(row[i - 1]);
        }
        for col in 0..tile_size {
            let be = [
                row[col],
                row[tile_size + col],
                row[2 * tile_size + col],
                row[3 * tile_size + col],
            ];
            let v = f32::from_bits(u32::from_be_bytes(be));
            values.push(if v == nodata { f32::NAN } else { v });
        }
    }
    Ok(values)
}

/// The overview tile made from its four children (`[top-left, top-right,
/// bottom-left, bottom-right]`, None = outside the level): each output pixel is
/// the mean of the valid (non-NaN) pixels of its 2x2 block, NaN if none is valid.
pub(crate) fn downsample_2x(children: [Option<&[f32]>; 4], tile_size: usize) -> Vec<f32> {
    let half = tile_size / 2;
    let mut out = vec![f32::NAN; tile_size * tile_size];
    for (quadrant, child) in children.iter().enumerate() {
        let Some(child) = child else { continue };
        let (off_c, off_r) = ((quadrant % 2) * half, (quadrant / 2) * half);
        for r in 0..half {
            let top = &child[(2 * r) * tile_size..(2 * r + 1) * tile_size];
            let bottom = &child[(2 * r + 1) * tile_size..(2 * r + 2) * tile_size];
            let dst = &mut out[(off_r + r) * tile_size + off_c..][..half];
            for (c, d) in dst.iter_mut().enumerate() {
                let block = [top[2 * c], top[2 * c + 1], bottom[2 * c], bottom[2 * c + 1]];
                let (mut sum, mut n) = (0.0f64, 0u32);
                for v in block {
                    if !v.is_nan() {
                        sum += v as f64;
                        n += 1;
                    }
                }
                if n > 0 {
                    *d = (sum / n as f64) as f32;
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_decode_round_trip_keeps_values_and_pads() {
        let t = 16;
        let values: Vec<f32> = (0..t * t)
            .map(|i| {
                if i % 7 == 0 {
                    f32::NAN
                } else {
                    i as f32 * 0.37 - 20.0
                }
            })
            .collect();
        let bytes = encode_f32_tile(&values, t, 10, 12, -9999.0).unwrap();
        let back = decode_f32_tile(&bytes, t, -9999.0).unwrap();
        for r in 0..t {
            for c in 0..t {
                let (v, b) = (values[r * t + c], back[r * t + c]);
                if r >= 12 || c >= 10 || v.is_nan() {
                    assert!(b.is_nan(), "({c},{r}) should be no-data, got {b}");
                } else {
                    assert_eq!(v, b);
                }
            }
        }
    }

    #[test]
    fn predictor_layout_is_big_endian_byte_planes() {
        // One row of two samples: bytes 3f 80 00 00 (1.0) and 40 00 00 00 (2.0)
        // shuffle to 3f 40 80 00 00 00 00 00, then differences.
        let t = 16;
        let mut values = vec![0.0f32; t * t];
        values[0] = 1.0;
        values[1] = 2.0;
        let bytes = encode_f32_tile(&values, t, t, t, f32::NAN).unwrap();
        let mut raw = Vec::new();
        ZlibDecoder::new(&bytes[..]).read_to_end(&mut raw).unwrap();
        assert_eq!(raw[0], 0x3f);
        assert_eq!(raw[1], 0x40u8.wrapping_sub(0x3f));
        assert_eq!(raw[2], 0x00u8.wrapping_sub(0x40));
        assert_eq!(
            raw[t], 0x80,
            "second plane starts after t zero-difference bytes"
        );
    }

    #[test]
    fn u16_tiles_round_clamp_and_zero_no_data() {
        let t = 16;
        let mut values: Vec<f32> = (0..t * t).map(|i| (i % 5) as f32).collect();
        values[1] = f32::NAN;
        values[2] = 2.6;
        values[3] = 70_000.0;
        values[4] = -3.0;
        let options = CogOptions {
            sample: CogSample::UInt16,
            ..Default::default()
        };
        let valid = Valid {
            width: 10,
            height: 12,
        };
        let bytes = encode_tile(&values, t, valid, &options).unwrap();
        let back = decode_tile(&bytes, t, &options).unwrap();
        assert_eq!(&back[..5], &[0.0, 0.0, 3.0, 65535.0, 0.0]);
        for r in 0..t {
            for c in 5..t {
                let want = if r < 12 && c < 10 {
                    values[r * t + c]
                } else {
                    0.0
                };
                assert_eq!(back[r * t + c], want, "({c},{r})");
            }
        }
    }

    #[test]
    fn downsample_ignores_nan_and_missing_children() {
        let t = 4;
        let mut a = vec![1.0f32; t * t];
        a[0] = f32::NAN; // block (0,0) = {NaN, 1, 1, 1} -> 1
        a[2] = 5.0; // block (1,0) = {5, 1, 1, 1} -> 2
        a[2 * t] = f32::NAN;
        a[2 * t + 1] = f32::NAN;
        a[3 * t] = f32::NAN;
        a[3 * t + 1] = f32::NAN; // block (0,1) all NaN -> NaN
        let out = downsample_2x([Some(&a), None, None, Some(&a)], t);
        assert_eq!(out[0], 1.0);
        assert_eq!(out[1], 2.0);
        assert!(out[t].is_nan());
        assert!(out[2].is_nan(), "missing top-right child gives NaN");
        assert_eq!(out[2 * t + 2], 1.0);
        assert_eq!(out[2 * t + 3], 2.0);
    }
}
