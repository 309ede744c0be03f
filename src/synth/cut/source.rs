//! The source side of a cut: one streaming pass for the heights and the valid
//! pixels of each window ([`scan_source`]), the rows of the source a tile can
//! reach with bilinear heights ([`SourceRows`]), and the rendering of written
//! pixels through M ([`render_cut_window`]).

use super::{SourceScan, TileSpec};
use crate::geo::GeoTransform;
use crate::geotiff::reader::GeoTiffReader;
use crate::synth::tiles::solve_written_height;
use crate::synth::SynthError;

/// A source position this close to a pixel centre (in pixels) takes that pixel.
const SNAP_PX: f64 = 1e-6;
/// Rows per read of the statistics pass.
const SCAN_BAND_ROWS: u64 = 256;

/// One pass over the source in bands: mean, min and max valid height, and the
/// valid pixels inside each `size` square window.
pub fn scan_source(
    reader: &mut GeoTiffReader,
    windows: &[[i64; 2]],
    size: i64,
) -> Result<SourceScan, SynthError> {
    let (width, height) = (reader.info().width, reader.info().height);
    let (mut sum, mut n) = (0.0f64, 0u64);
    let (mut min_m, mut max_m) = (f64::INFINITY, f64::NEG_INFINITY);
    let mut window_valid = vec![0u64; windows.len()];
    let mut band = Vec::new();
    for row0 in (0..height).step_by(SCAN_BAND_ROWS as usize) {
        let rows = SCAN_BAND_ROWS.min(height - row0);
        reader.read_rows_into(row0, rows, &mut band)?;
        for v in band.iter().filter(|v| v.is_finite()) {
            let v = *v as f64;
            sum += v;
            n += 1;
            min_m = min_m.min(v);
            max_m = max_m.max(v);
        }
        for (w, count) in windows.iter().zip(&mut window_valid) {
            let r_lo = w[1].max(row0 as i64);
            let r_hi = (w[1] + size).min((row0 + rows) as i64);
            let (c_lo, c_hi) = (w[0].max(0), (w[0] + size).min(width as i64));
            for r in r_lo..r_hi {
                let line = (r - row0 as i64) as usize * width as usize;
                let cells = &band[line + c_lo.max(0) as usize..line + c_hi.max(c_lo) as usize];
                *count += cells.iter().filter(|v| v.is_finite()).count() as u64;
            }
        }
    }
    if n == 0 {
        return Err(SynthError::BadSource(format!(
            "{}: no valid height in the source",
            reader.info().path.display()
        )));
    }
    Ok(SourceScan {
        mean_m: sum / n as f64,
        min_m,
        max_m,
        window_valid,
    })
}

/// Full-width rows [row0, row0 + rows) of the source; NaN = no data.
pub(super) struct SourceRows {
    pub geotransform: GeoTransform,
    pub width: i64,
    pub row0: i64,
    pub rows: i64,
    pub data: Vec<f32>,
}

impl SourceRows {
    fn at(&self, col: i64, row: i64) -> f64 {
        let r = row - self.row0;
        if col < 0 || col >= self.width || r < 0 || r >= self.rows {
            return f64::NAN;
        }
        self.data[(r * self.width + col) as usize] as f64
    }

    /// Bilinear height at (x, y) from the pixels with a nonzero weight, NaN
    /// unless all of them are valid.
    pub(super) fn bilinear(&self, x: f64, y: f64) -> f64 {
        let (col, row) = self.geotransform.world_to_pixel(x, y);
        let (Some((i0, fu)), Some((j0, fv))) = (split_px(col - 0.5), split_px(row - 0.5)) else {
            return f64::NAN;
        };
        let mut acc = 0.0;
        for (dj, wv) in [(0, 1.0 - fv), (1, fv)] {
            for (di, wu) in [(0, 1.0 - fu), (1, fu)] {
                if wu * wv == 0.0 {
                    continue;
                }
                let z = self.at(i0 + di, j0 + dj);
                if z.is_nan() {
                    return f64::NAN;
                }
                acc += wu * wv * z;
            }
        }
        acc
    }
}

/// Integer part and fraction of a pixel coordinate, snapped to the nearest
/// centre within [`SNAP_PX`]; None when not finite.
fn split_px(u: f64) -> Option<(i64, f64)> {
    if !u.is_finite() {
        return None;
    }
    let i = u.floor();
    let f = u - i;
    Some(if f < SNAP_PX {
        (i as i64, 0.0)
    } else if f > 1.0 - SNAP_PX {
        (i as i64 + 1, 0.0)
    } else {
        (i as i64, f)
    })
}

/// Pixels [col0, col0 + w) x [row0, row0 + h) of a written tile, row-major;
/// NaN outside the tile or where the source has no data.
pub(super) fn render_cut_window(
    source: &SourceRows,
    spec: &TileSpec,
    col0: u64,
    row0: u64,
    w: u64,
    h: u64,
) -> Vec<f32> {
    let mut out = Vec::with_capacity((w * h) as usize);
    for row in row0..row0 + h {
        for col in col0..col0 + w {
            if col >= spec.width || row >= spec.height {
                out.push(f32::NAN);
                continue;
            }
            let (xw, yw) = spec
                .geotransform
                .pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
            let z = solve_written_height(&spec.m_world, xw, yw, |x, y| source.bilinear(x, y));
            out.push(z as f32);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 4 x 3 source at 1 m, origin (100, 203): heights 10 * col + row, one hole.
    fn rows() -> SourceRows {
        let mut data: Vec<f32> = (0..3)
            .flat_map(|r| (0..4).map(move |c| (10 * c + r) as f32))
            .collect();
        data[4 + 3] = f32::NAN; // col 3, row 1
        SourceRows {
            geotransform: GeoTransform::north_up(100.0, 203.0, 1.0, 1.0),
            width: 4,
            row0: 0,
            rows: 3,
            data,
        }
    }

    #[test]
    fn bilinear_is_exact_at_centres_and_needs_every_weighted_neighbour() {
        let s = rows();
        // centre of (col 1, row 1) and within the snap distance of it
        assert_eq!(s.bilinear(101.5, 201.5), 11.0);
        assert_eq!(s.bilinear(101.5 + 1e-9, 201.5 - 1e-9), 11.0);
        // next to the hole: exact centre of (2, 1) is fine, halfway to (3, 1) is not
        assert_eq!(s.bilinear(102.5, 201.5), 21.0);
        assert!(s.bilinear(103.0, 201.5).is_nan());
        assert!(s.bilinear(103.5, 201.5).is_nan());
        // a plane is reproduced between centres
        let z = s.bilinear(100.75, 201.25);
        assert!((z - (10.0 * 0.25 + 1.25)).abs() < 1e-12, "{z}");
        // outside the rows held: no data
        assert!(s.bilinear(101.5, 203.5).is_nan());
        assert!(s.bilinear(99.4, 201.5).is_nan());
        assert!(s.bilinear(f64::NAN, 201.5).is_nan());
        assert_eq!(split_px(2.0 - 1e-9), Some((2, 0.0)));
        assert_eq!(split_px(-0.25), Some((-1, 0.75)));
    }

    #[test]
    fn identity_and_translation_copy_pixels() {
        let s = rows();
        let mut spec = TileSpec::unperturbed("t", 4, 3, s.geotransform, 0);
        let whole = render_cut_window(&s, &spec, 0, 0, 5, 3);
        for (k, v) in whole.iter().enumerate() {
            let (c, r) = (k % 5, k / 5);
            let want = if c < 4 { s.data[r * 4 + c] } else { f32::NAN };
            assert!(v.to_bits() == want.to_bits(), "({c}, {r}): {v} vs {want}");
        }
        // written tile moved by -(1, 0) m and M = T(1, 0, 0.5): pixel (c, r)
        // shows source pixel (c, r), 0.5 m lower
        spec.geotransform = GeoTransform::north_up(99.0, 203.0, 1.0, 1.0);
        spec.m_world = nalgebra::Matrix4::new_translation(&nalgebra::Vector3::new(1.0, 0.0, 0.5));
        let v = render_cut_window(&s, &spec, 0, 0, 2, 2);
        assert_eq!(v, vec![-0.5, 9.5, 0.5, 10.5]);
    }
}
