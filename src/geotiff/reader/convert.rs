//! Stored samples to `f32`: every sample type band 1 can have, read from
//! native-endian bytes, with no-data -> NaN compared in the stored type (as
//! GDAL's no-data mask does).

use super::SampleType;

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
