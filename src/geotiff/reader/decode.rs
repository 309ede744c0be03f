//! One block (strip or tile) of band 1 to `f32`: a pool of `tiff` decoders over
//! one shared memory map (each rayon task borrows one, so blocks decode in
//! parallel), the conversion of every sample type to `f32` with no-data -> NaN
//! (compared in the stored type, as GDAL's no-data mask does), and the mapping
//! of `tiff` errors to [`GeoTiffError`].

use std::io::Cursor;
use std::marker::PhantomData;
use std::ops::RangeInclusive;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;
use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::{TiffError, TiffFormatError, TiffUnsupportedError};

use super::convert::convert;
use super::direct::{DirectCodec, InflateError, Inflater};
use super::layout::BlockLayout;
use super::lerc;
use super::GeoTiffError;

/// The file's bytes, shared by every decoder.
#[derive(Clone)]
pub(super) struct MapBytes(Arc<memmap2::Mmap>);

impl MapBytes {
    pub fn new(map: memmap2::Mmap) -> MapBytes {
        MapBytes(Arc::new(map))
    }
}

impl AsRef<[u8]> for MapBytes {
    fn as_ref(&self) -> &[u8] {
        &self.0
    }
}

pub(super) type TiffDecoder = Decoder<Cursor<MapBytes>>;

/// A decoder positioned on the first IFD. The compressed-size limit is lifted
/// (block sizes were checked against the file length, and one giant strip is
/// legal); tag values keep the default 256 MiB cap.
pub(super) fn new_decoder(map: &MapBytes) -> Result<TiffDecoder, TiffError> {
    let mut limits = Limits::default();
    limits.intermediate_buffer_size = usize::MAX;
    Ok(Decoder::new(Cursor::new(map.clone()))?.with_limits(limits))
}

/// Resize `buf` to `len` values, or say the file asks for more memory than there is.
pub(super) fn try_resize<T: Clone>(
    path: &Path,
    buf: &mut Vec<T>,
    len: usize,
    fill: T,
) -> Result<(), GeoTiffError> {
    if len > buf.len() && buf.try_reserve(len - buf.len()).is_err() {
        let bytes = len.saturating_mul(std::mem::size_of::<T>());
        return Err(GeoTiffError::TooLarge {
            path: path.to_path_buf(),
            bytes: bytes as u64,
        });
    }
    buf.resize(len, fill);
    Ok(())
}

/// Map a `tiff` crate error to ours, naming the file.
pub(super) fn tiff_error(path: &Path, e: TiffError) -> GeoTiffError {
    let path = path.to_path_buf();
    match e {
        TiffError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => {
            GeoTiffError::Truncated {
                path,
                detail: "data ends early".into(),
            }
        }
        TiffError::FormatError(
            TiffFormatError::TiffSignatureNotFound | TiffFormatError::TiffSignatureInvalid,
        ) => GeoTiffError::NotTiff {
            path,
            detail: "bad TIFF header".into(),
        },
        TiffError::FormatError(TiffFormatError::InvalidDimensions(w, h)) => {
            GeoTiffError::ZeroSize {
                path,
                width: u64::from(w),
                height: u64::from(h),
            }
        }
        TiffError::UnsupportedError(TiffUnsupportedError::UnsupportedSampleFormat(f)) => {
            GeoTiffError::UnsupportedSampleFormat {
                path,
                detail: format!("{f:?}"),
            }
        }
        TiffError::UnsupportedError(u) => GeoTiffError::UnsupportedLayout {
            path,
            detail: u.to_string(),
        },
        other => GeoTiffError::Corrupt {
            path,
            detail: other.to_string().replace('\n', " "),
        },
    }
}

struct Worker {
    decoder: TiffDecoder,
    /// Inflate state of the direct codec.
    inflater: Inflater,
    /// Decoded bytes of a block whose data fills its rows.
    bytes: Vec<u8>,
    /// Decoded padded rows of a right-edge tile.
    padded: DecodingResult,
}

/// Rows `first_row ..` of the image, `width` values each, written by many
/// blocks at once. Each block writes only its own rows x columns, so writes
/// never overlap.
pub(super) struct RowSink<'a> {
    ptr: *mut f32,
    width: usize,
    first_row: u64,
    end_row: u64,
    _buf: PhantomData<&'a mut [f32]>,
}

// SAFETY: the sink is a `&mut [f32]` split into disjoint per-block regions;
// see `write_segment`.
unsafe impl Send for RowSink<'_> {}
unsafe impl Sync for RowSink<'_> {}

impl<'a> RowSink<'a> {
    pub fn new(buf: &'a mut [f32], width: usize, first_row: u64) -> RowSink<'a> {
        let rows = (buf.len() / width.max(1)) as u64;
        RowSink {
            ptr: buf.as_mut_ptr(),
            width,
            first_row,
            end_row: first_row + rows,
            _buf: PhantomData,
        }
    }

    /// Let `fill` write columns `x0 .. x0 + n` of image row `row`.
    ///
    /// # Safety
    /// No other call may write the same (row, column) while this one runs:
    /// each block of the image calls it only for its own rows and columns,
    /// and each block is decoded by one task.
    unsafe fn write_segment(&self, row: u64, x0: usize, n: usize, fill: impl FnOnce(&mut [f32])) {
        assert!(row >= self.first_row && row < self.end_row && x0 + n <= self.width);
        let start = (row - self.first_row) as usize * self.width + x0;
        // SAFETY: in bounds (asserted) and not aliased (the caller's contract).
        fill(unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), n) });
    }
}

/// Decodes blocks of one file; `Sync`, so rayon tasks share it by `&`.
pub(super) struct BlockDecoder {
    path: PathBuf,
    map: MapBytes,
    layout: BlockLayout,
    nodata: Option<f64>,
    idle: Mutex<Vec<Worker>>,
}

impl BlockDecoder {
    pub fn new(
        path: &Path,
        map: MapBytes,
        layout: BlockLayout,
        nodata: Option<f64>,
        first: TiffDecoder,
    ) -> Self {
        let idle = Mutex::new(vec![Worker::new(first)]);
        BlockDecoder {
            path: path.to_path_buf(),
            map,
            layout,
            nodata,
            idle,
        }
    }

    pub fn layout(&self) -> &BlockLayout {
        &self.layout
    }

    /// Decode every block of these block rows into `sink`, in parallel.
    pub fn decode_block_rows(
        &self,
        block_rows: RangeInclusive<u64>,
        sink: &RowSink<'_>,
    ) -> Result<(), GeoTiffError> {
        let across = self.layout.blocks_across;
        let (r0, r1) = (*block_rows.start(), *block_rows.end());
        let blocks = (r1 + 1 - r0) * across;
        (0..blocks)
            .into_par_iter()
            .try_for_each(|i| self.decode_into(i % across, r0 + i / across, sink))
    }

    /// Decode block (bx, by) of band 1 and write its rows that fall in `sink`.
    fn decode_into(&self, bx: u64, by: u64, sink: &RowSink<'_>) -> Result<(), GeoTiffError> {
        let l = &self.layout;
        let (w, h) = l.block_data_dims(bx, by);
        let (x0, top) = ((bx * l.block_width) as usize, by * l.block_height);
        let rows = top.max(sink.first_row)..(top + h).min(sink.end_row);
        let index = l.block_index(bx, by);
        if l.byte_counts[index] == 0 {
            // A sparse block (GDAL SPARSE_OK): no-data, or 0 without a no-data value.
            let fill = if self.nodata.is_some() { f32::NAN } else { 0.0 };
            for row in rows {
                // SAFETY: this task owns block (bx, by).
                unsafe { sink.write_segment(row, x0, w as usize, |seg| seg.fill(fill)) };
            }
            return Ok(());
        }
        if let Some(wrapping) = l.lerc {
            return self.decode_lerc(wrapping, (bx, by), sink);
        }
        let popped = self.idle.lock().unwrap_or_else(|p| p.into_inner()).pop();
        let mut worker = match popped {
            Some(w) => w,
            None => Worker::new(new_decoder(&self.map).map_err(|e| tiff_error(&self.path, e))?),
        };
        if let Some(codec) = l.direct {
            let result = self.decode_direct(codec, &mut worker, (bx, by), sink);
            self.idle
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .push(worker);
            return result;
        }
        let stride = l.samples_in_block;
        let pixel_bytes = stride * l.sample_type.bytes();
        let data_row_bytes = w as usize * pixel_bytes;
        // A right-edge tile is decoded as whole padded rows: the `tiff` crate's
        // row-by-row padding skip loses the LZW end code on some edge tiles
        // (tiff 0.11.3). Other blocks decode into a reused buffer.
        let decoded = if w == l.block_width {
            let len = data_row_bytes * h as usize;
            if let Err(e) = try_resize(&self.path, &mut worker.bytes, len, 0) {
                self.idle
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .push(worker);
                return Err(e);
            }
            let Worker { decoder, bytes, .. } = &mut worker;
            decoder
                .read_chunk_bytes(index as u32, &mut bytes[..len])
                .map(|()| data_row_bytes)
        } else {
            let padded_row_bytes = l.block_width as usize * pixel_bytes;
            let Worker {
                decoder, padded, ..
            } = &mut worker;
            decoder
                .read_chunk_to_buffer(padded, index as u32, padded_row_bytes)
                .map(|()| padded_row_bytes)
        };
        let result = match decoded {
            Ok(row_bytes) => {
                let padded_buf;
                let bytes = if w == l.block_width {
                    &worker.bytes[..]
                } else {
                    padded_buf = worker.padded.as_buffer(0);
                    padded_buf.as_bytes()
                };
                for row in rows {
                    let at = (row - top) as usize * row_bytes;
                    let src = &bytes[at..at + data_row_bytes];
                    // SAFETY: this task owns block (bx, by).
                    unsafe {
                        sink.write_segment(row, x0, w as usize, |seg| {
                            convert(src, l.sample_type, stride, self.nodata, seg)
                        })
                    };
                }
                Ok(())
            }
            Err(e) => Err(block_error(&self.path, e, bx, by)),
        };
        self.idle
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(worker);
        result
    }
}

/// Block (bx, by) of band 1 as stored: its data size (edge blocks
/// clipped), its first column and row in the image, and its bytes in the map.
struct StoredBlock<'m> {
    w: u64,
    h: u64,
    x0: usize,
    top: u64,
    bytes: &'m [u8],
}

impl BlockDecoder {
    fn stored_block(&self, bx: u64, by: u64) -> StoredBlock<'_> {
        let l = &self.layout;
        let (w, h) = l.block_data_dims(bx, by);
        let index = l.block_index(bx, by);
        let (offset, count) = (l.offsets[index] as usize, l.byte_counts[index] as usize);
        StoredBlock {
            w,
            h,
            x0: (bx * l.block_width) as usize,
            top: by * l.block_height,
            bytes: &self.map.as_ref()[offset..offset + count],
        }
    }

    /// [`decode_into`](Self::decode_into) for a block the direct codec reads
    /// (a non-sparse block): inflate it from the map, then undo the predictor
    /// and convert each needed row straight into `sink`.
    fn decode_direct(
        &self,
        codec: DirectCodec,
        worker: &mut Worker,
        (bx, by): (u64, u64),
        sink: &RowSink<'_>,
    ) -> Result<(), GeoTiffError> {
        let l = &self.layout;
        let StoredBlock {
            w,
            h,
            x0,
            top,
            bytes: compressed,
        } = self.stored_block(bx, by);
        let row_bytes = l.block_width as usize * 4;
        let len = row_bytes.saturating_mul(h as usize);
        try_resize(&self.path, &mut worker.bytes, len, 0)?;
        let Worker {
            inflater, bytes, ..
        } = worker;
        codec
            .inflate(inflater, compressed, bytes, len)
            .map_err(|e| {
                let path = self.path.clone();
                match e {
                    InflateError::Truncated(m) => GeoTiffError::Truncated {
                        path,
                        detail: format!("block ({bx}, {by}): {m}"),
                    },
                    InflateError::Corrupt(m) => GeoTiffError::Corrupt {
                        path,
                        detail: format!("block ({bx}, {by}) does not decode: {m}"),
                    },
                }
            })?;
        let nodata = self.nodata.and_then(|v| (!v.is_nan()).then_some(v as f32));
        for row in top.max(sink.first_row)..(top + h).min(sink.end_row) {
            let at = (row - top) as usize * row_bytes;
            let src = &mut bytes[at..at + row_bytes];
            // SAFETY: this task owns block (bx, by).
            unsafe {
                sink.write_segment(row, x0, w as usize, |seg| {
                    codec.row_to_f32(src, nodata, seg)
                })
            };
        }
        Ok(())
    }
}

impl BlockDecoder {
    /// [`decode_into`](Self::decode_into) for a LERC block (not sparse):
    /// unwrap and decode its blob from the map, then write band 1 of each
    /// needed row into `sink`, masked pixels and no-data as NaN.
    fn decode_lerc(
        &self,
        wrapping: lerc::Wrapping,
        (bx, by): (u64, u64),
        sink: &RowSink<'_>,
    ) -> Result<(), GeoTiffError> {
        let StoredBlock {
            w,
            h,
            x0,
            top,
            bytes: stored,
        } = self.stored_block(bx, by);
        let corrupt = |detail: String| GeoTiffError::Corrupt {
            path: self.path.clone(),
            detail: format!("block ({bx}, {by}) does not decode: {detail}"),
        };
        let block = lerc::decode(wrapping, stored, &mut Vec::new()).map_err(corrupt)?;
        if block.width < w as usize || block.height < h as usize {
            return Err(corrupt(format!(
                "its LERC blob is {} x {}, the block {w} x {h}",
                block.width, block.height
            )));
        }
        let nodata = self.nodata.and_then(|v| (!v.is_nan()).then_some(v as f32));
        for row in top.max(sink.first_row)..(top + h).min(sink.end_row) {
            let r = (row - top) as usize;
            // SAFETY: this task owns block (bx, by).
            unsafe {
                sink.write_segment(row, x0, w as usize, |seg| {
                    for (c, out) in seg.iter_mut().enumerate() {
                        *out = match block.get(c, r).map(|v| v as f32) {
                            Some(v) if Some(v) != nodata => v,
                            _ => f32::NAN,
                        };
                    }
                })
            };
        }
        Ok(())
    }
}

impl Worker {
    fn new(decoder: TiffDecoder) -> Worker {
        Worker {
            decoder,
            inflater: Inflater::default(),
            bytes: Vec::new(),
            padded: DecodingResult::U8(Vec::new()),
        }
    }
}

fn block_error(path: &Path, e: TiffError, bx: u64, by: u64) -> GeoTiffError {
    match tiff_error(path, e) {
        GeoTiffError::Truncated { path, detail } => GeoTiffError::Truncated {
            path,
            detail: format!("block ({bx}, {by}): {detail}"),
        },
        GeoTiffError::Corrupt { path, detail } => GeoTiffError::Corrupt {
            path,
            detail: format!("block ({bx}, {by}) does not decode: {detail}"),
        },
        other => other,
    }
}
