//! Direct block codec for the commonest DSM encoding: Deflate-compressed
//! 32-bit floats, one sample per pixel, with no predictor or the
//! floating-point predictor (3), as `gdal_translate -co COMPRESS=DEFLATE
//! -co PREDICTOR=3` and COGs of elevation write.
//!
//! The `tiff` crate decodes such a block through a streaming zlib reader over a
//! `BufReader` and, for predictor 3, copies every row into a fresh `Vec`
//! before un-shuffling it; then the reader converts the bytes to `f32` in a
//! third pass. Here the compressed bytes are inflated from the memory map in
//! one call into a reused buffer, and each row's predictor is undone and
//! written as `f32` (no-data -> NaN) straight into the caller's row: one
//! pass over the decoded bytes, no allocation per block. Any other encoding
//! goes through the `tiff` crate (see `decode`).
//!
//! Inflating is libdeflate's whole-buffer decoder (about 1.4x zlib-rs on
//! GDAL's predictor-3 tiles); a block it does not decode to exactly its size
//! is decoded again by zlib-rs, whose outcome (and error kind) is the answer,
//! so damaged files are reported as before.

use flate2::{Decompress, FlushDecompress, Status};

/// Why a block did not inflate (the message has no file name).
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) enum InflateError {
    /// The compressed bytes end before the block's data.
    Truncated(String),
    /// Invalid deflate data, or a stream shorter than the block.
    Corrupt(String),
}

/// How the blocks of a file are encoded, when this codec can decode them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct DirectCodec {
    /// TIFF predictor: 1 (none) or 3 (floating point).
    predictor: u16,
    /// The file's byte order (predictor 1 stores samples in it; predictor 3
    /// stores its byte planes most significant first whatever the order).
    little_endian: bool,
}

impl DirectCodec {
    /// The codec for these tags, None when the file needs the `tiff` crate.
    /// `compression` and `predictor` are the TIFF tag values, `float32` says
    /// the samples are 32-bit floats, `samples` is the samples per pixel in a block.
    pub fn for_tags(
        compression: u16,
        predictor: u16,
        float32: bool,
        samples: usize,
        little_endian: bool,
    ) -> Option<DirectCodec> {
        let deflate = matches!(compression, 8 | 32946);
        (deflate && float32 && samples == 1 && matches!(predictor, 1 | 3)).then_some(DirectCodec {
            predictor,
            little_endian,
        })
    }

    /// Inflate one block (`compressed`, a zlib stream) into `out`, which is
    /// resized to exactly `len` bytes; bytes past `len` are ignored, as the
    /// `tiff` crate does.
    pub fn inflate(
        &self,
        inflater: &mut Inflater,
        compressed: &[u8],
        out: &mut Vec<u8>,
        len: usize,
    ) -> Result<(), InflateError> {
        // Every byte is overwritten by a successful decode: no zeroing.
        out.resize(len, 0);
        match inflater.fast.zlib_decompress(compressed, out) {
            Ok(n) if n == len => Ok(()),
            _ => inflate_exact(&mut inflater.exact, compressed, out, len),
        }
    }

    /// One stored row (`row`: `stored_px` samples, decoded, predictor still
    /// applied; modified in place) to its first `out.len()` values as `f32`,
    /// samples equal to `nodata` (compared as `f32`, as GDAL does) -> NaN.
    pub fn row_to_f32(&self, row: &mut [u8], nodata: Option<f32>, out: &mut [f32]) {
        match self.predictor {
            3 => {
                undo_byte_differences(row);
                let n = row.len() / 4;
                let (p0, rest) = row.split_at(n);
                let (p1, rest) = rest.split_at(n);
                let (p2, p3) = rest.split_at(n);
                let values = out.iter_mut().zip(p0.iter().zip(p1).zip(p2.iter().zip(p3)));
                match nodata {
                    Some(nd) => values.for_each(|(o, ((&a, &b), (&c, &d)))| {
                        let v = f32::from_bits(u32::from_be_bytes([a, b, c, d]));
                        *o = if v == nd { f32::NAN } else { v };
                    }),
                    None => values.for_each(|(o, ((&a, &b), (&c, &d)))| {
                        *o = f32::from_bits(u32::from_be_bytes([a, b, c, d]));
                    }),
                }
            }
            _ => {
                let le = self.little_endian;
                let values = out.iter_mut().zip(row.chunks_exact(4));
                let read = |b: &[u8]| {
                    let b: [u8; 4] = b.try_into().expect("4 bytes");
                    f32::from_bits(if le {
                        u32::from_le_bytes(b)
                    } else {
                        u32::from_be_bytes(b)
                    })
                };
                match nodata {
                    Some(nd) => values.for_each(|(o, b)| {
                        let v = read(b);
                        *o = if v == nd { f32::NAN } else { v };
                    }),
                    None => values.for_each(|(o, b)| *o = read(b)),
                }
            }
        }
    }
}

/// The decoders of one worker: libdeflate first, zlib-rs for the blocks it
/// does not decode cleanly.
pub(super) struct Inflater {
    fast: libdeflater::Decompressor,
    exact: Decompress,
}

impl Default for Inflater {
    fn default() -> Inflater {
        Inflater {
            fast: libdeflater::Decompressor::new(),
            exact: Decompress::new(true),
        }
    }
}

/// zlib-rs's reading of a block: Ok once `len` bytes are decoded, else why not.
fn inflate_exact(
    inflater: &mut Decompress,
    compressed: &[u8],
    out: &mut [u8],
    len: usize,
) -> Result<(), InflateError> {
    inflater.reset(true);
    let status = inflater
        .decompress(compressed, out, FlushDecompress::Finish)
        .map_err(|e| InflateError::Corrupt(format!("deflate stream does not decode: {e}")))?;
    let produced = inflater.total_out() as usize;
    match status {
        _ if produced >= len => Ok(()),
        Status::StreamEnd => Err(InflateError::Corrupt(format!(
            "the deflate stream ends after {produced} of {len} decoded bytes"
        ))),
        Status::Ok | Status::BufError => Err(InflateError::Truncated(format!(
            "data ends early ({produced} of {len} decoded bytes)"
        ))),
    }
}

/// Undo the byte-wise horizontal differencing of predictor 3 (one sample per
/// pixel): each byte is the running sum of the stored differences.
fn undo_byte_differences(row: &mut [u8]) {
    // SAFETY: SSE2 is part of the x86-64 baseline, so every x86-64 CPU has it.
    #[cfg(target_arch = "x86_64")]
    let (mut acc, row) = unsafe { prefix_sums_sse2(row) };
    #[cfg(not(target_arch = "x86_64"))]
    let mut acc = 0u8;
    for b in row.iter_mut() {
        acc = acc.wrapping_add(*b);
        *b = acc;
    }
}

/// The running byte sums of the whole 16-byte groups of `row`, in place,
/// with SSE2 (part of every x86-64): a byte-at-a-time running sum is a chain
/// of dependent additions, ~60 % of the predictor's time; here each group
/// takes four shifted additions and one carry from the group before. Returns
/// the last sum and the bytes left (fewer than 16) for the scalar loop.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse2")]
fn prefix_sums_sse2(row: &mut [u8]) -> (u8, &mut [u8]) {
    use std::arch::x86_64::*;
    let mut groups = row.chunks_exact_mut(16);
    let mut carry = _mm_setzero_si128();
    for group in &mut groups {
        let at = group.as_mut_ptr().cast::<__m128i>();
        // SAFETY: `group` is 16 readable bytes; the load is unaligned.
        let mut x = unsafe { _mm_loadu_si128(at) };
        x = _mm_add_epi8(x, _mm_slli_si128::<1>(x));
        x = _mm_add_epi8(x, _mm_slli_si128::<2>(x));
        x = _mm_add_epi8(x, _mm_slli_si128::<4>(x));
        x = _mm_add_epi8(x, _mm_slli_si128::<8>(x));
        x = _mm_add_epi8(x, carry);
        // SAFETY: `group` is 16 writable bytes; the store is unaligned.
        unsafe { _mm_storeu_si128(at, x) };
        // Broadcast byte 15: pair it up, spread its word, take the high half.
        let words = _mm_shufflehi_epi16::<0xFF>(_mm_unpackhi_epi8(x, x));
        carry = _mm_unpackhi_epi64(words, words);
    }
    let last = _mm_cvtsi128_si32(carry) as u8;
    (last, groups.into_remainder())
}

#[cfg(test)]
mod tests {
    use super::*;
    use flate2::{write::ZlibEncoder, Compression};
    use std::io::Write;

    /// Encode `values` (rows of `n`) with predictor 3, as GDAL does.
    fn predictor3(values: &[f32], n: usize) -> Vec<u8> {
        let mut out = Vec::new();
        for row in values.chunks(n) {
            let mut planes = vec![0u8; 4 * n];
            for (j, v) in row.iter().enumerate() {
                for (k, b) in v.to_bits().to_be_bytes().iter().enumerate() {
                    planes[k * n + j] = *b;
                }
            }
            let mut prev = 0u8;
            for b in planes.iter_mut() {
                let d = b.wrapping_sub(prev);
                prev = *b;
                *b = d;
            }
            out.extend(planes);
        }
        out
    }

    fn zlib(bytes: &[u8]) -> Vec<u8> {
        let mut e = ZlibEncoder::new(Vec::new(), Compression::default());
        e.write_all(bytes).unwrap();
        e.finish().unwrap()
    }

    #[test]
    fn predictor_3_rows_decode_to_their_values_with_nodata_as_nan() {
        let (n, rows) = (6, 3);
        let values: Vec<f32> = (0..n * rows)
            .map(|i| {
                if i == 4 {
                    -9999.0
                } else {
                    100.0 + i as f32 * 0.37
                }
            })
            .collect();
        let codec = DirectCodec::for_tags(8, 3, true, 1, true).unwrap();
        let (mut inflater, mut buf) = (Inflater::default(), Vec::new());
        codec
            .inflate(
                &mut inflater,
                &zlib(&predictor3(&values, n)),
                &mut buf,
                4 * n * rows,
            )
            .unwrap();
        let mut out = vec![0.0f32; 5]; // the last column is padding
        for (r, row) in buf.chunks_mut(4 * n).enumerate() {
            codec.row_to_f32(row, Some(-9999.0), &mut out);
            for (j, v) in out.iter().enumerate() {
                let want = values[r * n + j];
                if want == -9999.0 {
                    assert!(v.is_nan());
                } else {
                    assert_eq!(*v, want);
                }
            }
        }
    }

    #[test]
    fn plain_rows_honour_the_byte_order_and_short_streams_are_errors() {
        let values = [1.5f32, -2.25, 3.0];
        let be: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        let codec = DirectCodec::for_tags(32946, 1, true, 1, false).unwrap();
        let (mut inflater, mut buf) = (Inflater::default(), Vec::new());
        codec
            .inflate(&mut inflater, &zlib(&be), &mut buf, 12)
            .unwrap();
        let mut out = [0.0f32; 3];
        codec.row_to_f32(&mut buf, None, &mut out);
        assert_eq!(out, values);
        let err = codec
            .inflate(&mut inflater, &zlib(&be), &mut buf, 16)
            .unwrap_err();
        assert!(
            matches!(&err, InflateError::Corrupt(m) if m.contains("12 of 16")),
            "{err:?}"
        );
        let truncated = &zlib(&be)[..6];
        let err = codec.inflate(&mut inflater, truncated, &mut buf, 12);
        assert!(matches!(err, Err(InflateError::Truncated(_))), "{err:?}");
        let garbage = [0x78, 0x9c, 0xff, 0xff, 0xff, 0xff];
        let err = codec.inflate(&mut inflater, &garbage, &mut buf, 12);
        assert!(matches!(err, Err(InflateError::Corrupt(_))), "{err:?}");
    }

    #[test]
    fn running_byte_sums_match_the_scalar_definition() {
        let mut seed = 1u32;
        for len in [0, 1, 15, 16, 17, 31, 64, 1024, 1027] {
            let row: Vec<u8> = (0..len)
                .map(|_| {
                    seed = seed.wrapping_mul(1664525).wrapping_add(1013904223);
                    (seed >> 24) as u8
                })
                .collect();
            let mut want = row.clone();
            let mut acc = 0u8;
            for b in want.iter_mut() {
                acc = acc.wrapping_add(*b);
                *b = acc;
            }
            let mut got = row;
            undo_byte_differences(&mut got);
            assert_eq!(got, want, "length {len}");
        }
    }

    #[test]
    fn other_encodings_are_left_to_the_tiff_crate() {
        assert!(DirectCodec::for_tags(5, 3, true, 1, true).is_none()); // LZW
        assert!(DirectCodec::for_tags(8, 2, true, 1, true).is_none()); // predictor 2
        assert!(DirectCodec::for_tags(8, 3, false, 1, true).is_none()); // f64 / ints
        assert!(DirectCodec::for_tags(8, 1, true, 2, true).is_none()); // 2 bands chunky
    }
}
