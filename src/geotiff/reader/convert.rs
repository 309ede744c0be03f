//! Stored samples to `f32`: every sample type band 1 can have, read from
//! native-endian bytes, with no-data -> NaN compared in the stored type (as
//! GDAL's no-data mask does; half floats: see [`half_nodata`]).

use half::f16;

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

/// The half-float samples that mean no-data `v`: `v` itself when a half
/// float holds it exactly, else the two half floats about it. GDAL (3.10)
/// writes a Float32 band with NBITS=16 by truncating each value, -9999 to
/// -9992, and keeps -9999 as the no-data value, so its own reading calls
/// those pixels heights of -9992 m; here they are no-data, as the writer
/// meant (no height lies within a half float's step of a no-data value).
/// A NaN no-data value needs no match: NaN samples stay NaN.
fn half_nodata(v: f64) -> [Option<u16>; 2] {
    if v.is_nan() {
        return [None, None];
    }
    let near = f16::from_f64(v);
    if near.to_f64() == v {
        return [Some(near.to_bits()), None];
    }
    // The neighbour on v's other side: one step of the magnitude (the bit
    // pattern of a half float's magnitude is monotonic, infinity included).
    let toward_zero = near.to_f64().abs() > v.abs();
    let bits = near.to_bits();
    let other = if toward_zero { bits - 1 } else { bits + 1 };
    [Some(bits), (other & 0x7fff <= 0x7c00).then_some(other)]
}

fn convert_half(bytes: &[u8], stride: usize, nodata: Option<f64>, out: &mut [f32]) {
    let pixels = bytes.chunks_exact(2 * stride);
    let nd = nodata.map_or([None, None], half_nodata);
    out.iter_mut().zip(pixels).for_each(|(o, px)| {
        let bits = u16::from_ne_bytes([px[0], px[1]]);
        *o = if nd.contains(&Some(bits)) {
            f32::NAN
        } else {
            f16::from_bits(bits).to_f32()
        };
    });
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
        SampleType::F16 => convert_half(bytes, stride, nodata, out),
        SampleType::F32 => convert_as::<f32>(bytes, stride, nodata, out),
        SampleType::F64 => convert_as::<f64>(bytes, stride, nodata, out),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn half_bytes(values: &[f32]) -> Vec<u8> {
        values
            .iter()
            .flat_map(|&v| f16::from_f32(v).to_ne_bytes())
            .collect()
    }

    #[test]
    fn half_floats_read_exactly_and_their_no_data_is_nan() {
        let bytes = half_bytes(&[100.0625, 250.5, -9999.0, 0.5]);
        let mut out = [0.0f32; 4];
        convert(&bytes, SampleType::F16, 1, Some(0.5), &mut out);
        assert_eq!(out[..2], [100.0625, 250.5]);
        assert_eq!(out[2], -10000.0, "nearest half float of -9999");
        assert!(out[3].is_nan(), "0.5 is a half float: exact no-data");
    }

    #[test]
    fn a_no_data_value_no_half_float_holds_matches_both_neighbours() {
        // -9999 lies between the half floats -9992 (GDAL's truncation) and
        // -10000 (the nearest); -9984 and -10008 are heights.
        let [a, b] = half_nodata(-9999.0).map(|h| f16::from_bits(h.unwrap()).to_f32());
        assert_eq!((a.min(b), a.max(b)), (-10000.0, -9992.0));
        let bytes = half_bytes(&[-9992.0, -10000.0, -9984.0, -10008.0, 12.0]);
        let mut out = [0.0f32; 5];
        convert(&bytes, SampleType::F16, 1, Some(-9999.0), &mut out);
        assert!(out[0].is_nan() && out[1].is_nan(), "{out:?}");
        assert_eq!(out[2..], [-9984.0, -10008.0, 12.0]);
        // Beyond the half floats' range: the largest finite and infinity.
        let [a, b] = half_nodata(-3.4028234663852886e38).map(|h| f16::from_bits(h.unwrap()));
        assert_eq!((a.to_f32(), b.to_f32()), (f32::NEG_INFINITY, -65504.0));
        assert_eq!(half_nodata(f64::NAN), [None, None]);
    }

    #[test]
    fn half_floats_of_a_two_band_pixel_take_band_one() {
        let bytes = half_bytes(&[1.5, 99.0, 2.5, 99.0]);
        let mut out = [0.0f32; 2];
        convert(&bytes, SampleType::F16, 2, None, &mut out);
        assert_eq!(out, [1.5, 2.5]);
    }
}
