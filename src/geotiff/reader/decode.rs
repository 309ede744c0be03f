//! One block (strip or tile) of band 1 to `f32`: a pool of `tiff` decoders over
//! one shared memory map (each rayon task borrows one, so blocks decode in
//! parallel), the conversion of every sample type to `f32` with no-data -> NaN
//! (compared in the stored type, as GDAL's no-data mask does), and the mapping
//! of `tiff` errors to [`GeoTiffError`].

use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::{TiffError, TiffFormatError, TiffUnsupportedError};

use super::layout::BlockLayout;
use super::{GeoTiffError, SampleType};

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

/// A decoder positioned on the first IFD. Limits are lifted: block sizes were
/// checked against the file length, and one giant strip is legal.
pub(super) fn new_decoder(map: &MapBytes) -> Result<TiffDecoder, TiffError> {
    Ok(Decoder::new(Cursor::new(map.clone()))?.with_limits(Limits::unlimited()))
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
    buffer: DecodingResult,
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
        let idle = Mutex::new(vec![Worker {
            decoder: first,
            buffer: DecodingResult::U8(Vec::new()),
        }]);
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

    /// Block (bx, by) of band 1 as `f32`, clipped to the image (w * h values).
    pub fn decode(&self, bx: u64, by: u64) -> Result<Vec<f32>, GeoTiffError> {
        let l = &self.layout;
        let (w, h) = l.block_data_dims(bx, by);
        let pixels = (w * h) as usize;
        let index = l.block_index(bx, by);
        if l.byte_counts[index] == 0 {
            // A sparse block (GDAL SPARSE_OK): no-data, or 0 without a no-data value.
            return Ok(vec![
                if self.nodata.is_some() { f32::NAN } else { 0.0 };
                pixels
            ]);
        }
        let popped = self.idle.lock().unwrap_or_else(|p| p.into_inner()).pop();
        let mut worker = match popped {
            Some(w) => w,
            None => Worker {
                decoder: new_decoder(&self.map).map_err(|e| tiff_error(&self.path, e))?,
                buffer: DecodingResult::U8(Vec::new()),
            },
        };
        let stride = l.samples_in_block;
        let pixel_bytes = stride * l.sample_type.bytes();
        // Decode whole padded tile rows (row stride = tile width): one read per
        // tile, and it avoids the `tiff` crate's row-by-row padding skip, which
        // loses the LZW end code on some edge tiles (tiff 0.11.3).
        let row_bytes = l.block_width as usize * pixel_bytes;
        let decoded =
            worker
                .decoder
                .read_chunk_to_buffer(&mut worker.buffer, index as u32, row_bytes);
        let result = match decoded {
            Ok(()) => {
                let bytes = worker.buffer.as_buffer(0);
                let bytes = bytes.as_bytes();
                let mut out = vec![0f32; pixels];
                for (y, out_row) in out.chunks_exact_mut(w as usize).enumerate() {
                    let src = &bytes[y * row_bytes..y * row_bytes + w as usize * pixel_bytes];
                    convert(src, l.sample_type, stride, self.nodata, out_row);
                }
                Ok(out)
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

/// A stored sample type: native-endian bytes to `f32`, and the exact no-data value.
trait Sample: Copy + PartialEq {
    const SIZE: usize;
    fn read(b: &[u8]) -> Self;
    fn to_f32(self) -> f32;
    /// The no-data value in this type, None when it cannot occur (as GDAL).
    fn exact(v: f64) -> Option<Self>;
}

macro_rules! int_sample {
    ($($t:ty),*) => {$(
        impl Sample for $t {
            const SIZE: usize = std::mem::size_of::<$t>();
            #[inline(always)]
            fn read(b: &[u8]) -> Self {
                <$t>::from_ne_bytes(b[..Self::SIZE].try_into().unwrap())
            }
            #[inline(always)]
            fn to_f32(self) -> f32 {
                self as f32
            }
            fn exact(v: f64) -> Option<Self> {
                let in_range = v >= <$t>::MIN as f64 && v <= <$t>::MAX as f64;
                (v.fract() == 0.0 && in_range).then(|| v as $t)
            }
        }
    )*};
}
int_sample!(u8, i8, u16, i16, u32, i32);

impl Sample for f32 {
    const SIZE: usize = 4;
    #[inline(always)]
    fn read(b: &[u8]) -> Self {
        f32::from_ne_bytes(b[..4].try_into().unwrap())
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
    fn exact(v: f64) -> Option<Self> {
        (!v.is_nan()).then_some(v as f32)
    }
}

impl Sample for f64 {
    const SIZE: usize = 8;
    #[inline(always)]
    fn read(b: &[u8]) -> Self {
        f64::from_ne_bytes(b[..8].try_into().unwrap())
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
    fn exact(v: f64) -> Option<Self> {
        (!v.is_nan()).then_some(v)
    }
}

fn convert_as<T: Sample>(bytes: &[u8], stride: usize, nodata: Option<f64>, out: &mut [f32]) {
    let pixel_bytes = T::SIZE * stride;
    let pixels = bytes.chunks_exact(pixel_bytes);
    match nodata.and_then(T::exact) {
        Some(nd) => out.iter_mut().zip(pixels).for_each(|(o, px)| {
            let v = T::read(px);
            *o = if v == nd { f32::NAN } else { v.to_f32() };
        }),
        None => out
            .iter_mut()
            .zip(pixels)
            .for_each(|(o, px)| *o = T::read(px).to_f32()),
    }
}

/// Band 1 of `bytes` (native-endian samples, `stride` per pixel) into `out`.
pub(super) fn convert(
    bytes: &[u8],
    ty: SampleType,
    stride: usize,
    nodata: Option<f64>,
    out: &mut [f32],
) {
    match ty {
        SampleType::U8 => convert_as::<u8>(bytes, stride, nodata, out),
        SampleType::I8 => convert_as::<i8>(bytes, stride, nodata, out),
        SampleType::U16 => convert_as::<u16>(bytes, stride, nodata, out),
        SampleType::I16 => convert_as::<i16>(bytes, stride, nodata, out),
        SampleType::U32 => convert_as::<u32>(bytes, stride, nodata, out),
        SampleType::I32 => convert_as::<i32>(bytes, stride, nodata, out),
        SampleType::F32 => convert_as::<f32>(bytes, stride, nodata, out),
        SampleType::F64 => convert_as::<f64>(bytes, stride, nodata, out),
    }
}
