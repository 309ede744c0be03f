//! The 2x2 mean that builds each overview level from the one above: the
//! mean of the valid (non-NaN) pixels of each 2x2 block, summed in f64 in a
//! fixed order, NaN where none is valid (tools/scripts/check_zarr.py computes
//! the same and compares exactly).

/// Mean of the valid pixels of each 2x2 block of rows `a` and `b` (b = None for
/// a last odd row); output width = ceil(width / 2).
pub fn downsample_rows(a: &[f32], b: Option<&[f32]>, out: &mut Vec<f32>) {
    let w = a.len();
    let start = out.len();
    out.resize(start + w.div_ceil(2), 0.0);
    let dst = &mut out[start..start + w / 2];
    match b {
        Some(b) => {
            let b = &b[..w];
            for (j, o) in dst.iter_mut().enumerate() {
                let (a, b) = (&a[2 * j..2 * j + 2], &b[2 * j..2 * j + 2]);
                *o = mean_of_valid([a[0], a[1], b[0], b[1]]);
            }
            if w % 2 == 1 {
                out[start + w / 2] = mean_of_valid([a[w - 1], b[w - 1]]);
            }
        }
        None => {
            for (j, o) in dst.iter_mut().enumerate() {
                *o = mean_of_valid([a[2 * j], a[2 * j + 1]]);
            }
            if w % 2 == 1 {
                out[start + w / 2] = mean_of_valid([a[w - 1]]);
            }
        }
    }
}

/// Mean of the non-NaN `values` (summed in f64, in order), NaN when none.
/// Branch-free so the compiler vectorises it: adding 0.0 for a NaN leaves
/// the sum as skipping it would (the sum starts at +0.0 and so is never -0.0).
#[inline(always)]
fn mean_of_valid<const N: usize>(values: [f32; N]) -> f32 {
    let (mut sum, mut n) = (0.0f64, 0u32);
    for v in values {
        let valid = !v.is_nan();
        sum += if valid { v as f64 } else { 0.0 };
        n += u32::from(valid);
    }
    if n == 0 {
        f32::NAN
    } else {
        (sum / n as f64) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The former branchy implementation, the reference for bit equality.
    fn downsample_reference(a: &[f32], b: Option<&[f32]>) -> Vec<f32> {
        let w = a.len();
        let mut out = Vec::new();
        for j in 0..w.div_ceil(2) {
            let (mut sum, mut n) = (0.0f64, 0u32);
            let mut add = |v: f32| {
                if !v.is_nan() {
                    sum += v as f64;
                    n += 1;
                }
            };
            add(a[2 * j]);
            if 2 * j + 1 < w {
                add(a[2 * j + 1]);
            }
            if let Some(b) = b {
                add(b[2 * j]);
                if 2 * j + 1 < w {
                    add(b[2 * j + 1]);
                }
            }
            out.push(if n == 0 {
                f32::NAN
            } else {
                (sum / n as f64) as f32
            });
        }
        out
    }

    #[test]
    fn downsample_is_bit_identical_to_the_reference() {
        let mut seed = 3u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            match seed >> 61 {
                0 => f32::NAN,
                1 => -0.0,
                2 => 0.0,
                _ => ((seed >> 20) as f32 / (1u64 << 44) as f32 - 0.3) * 4000.0,
            }
        };
        for w in [1usize, 2, 3, 7, 64, 65] {
            let a: Vec<f32> = (0..w).map(|_| next()).collect();
            let b: Vec<f32> = (0..w).map(|_| next()).collect();
            for rows in [Some(&b[..]), None] {
                let mut got = vec![42.0];
                downsample_rows(&a, rows, &mut got);
                let want = downsample_reference(&a, rows);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got[1..]), bits(&want), "width {w}");
                assert_eq!(got[0], 42.0, "appends");
            }
        }
    }

    #[test]
    fn downsample_ignores_nan_and_handles_odd_edges() {
        let nan = f32::NAN;
        let a = [1.0, 3.0, nan, nan, 5.0];
        let b = [5.0, nan, nan, nan, 7.0];
        let mut out = Vec::new();
        downsample_rows(&a, Some(&b), &mut out);
        assert_eq!(out[0], 3.0);
        assert!(out[1].is_nan());
        assert_eq!(out[2], 6.0);
        out.clear();
        downsample_rows(&a, None, &mut out);
        assert_eq!((out[0], out[2]), (2.0, 5.0));
    }
}
