//! One output tile: find the DSMs whose corrected footprint touches it, read
//! each one's corrected height at every output pixel centre (through the chunk
//! cache), and combine them per pixel with the chosen [`FuseMethod`].

use super::corrected::{CorrectedSurface, PoseXf};
use super::layout::{level_for, FootprintIndex, OutputGrid, PlacedDsm};
use super::{FuseError, FuseMethod};
use crate::cache::ChunkCache;
use crate::store::{Store, StoreGrid};

/// Everything a worker needs to render any tile of one output grid (shared by `&`).
pub struct TileRenderer<'a> {
    pub store: &'a Store,
    pub cache: &'a ChunkCache,
    pub poses: &'a [PoseXf],
    /// The DSMs that may contribute, with their corrected footprints.
    pub placed: Vec<PlacedDsm>,
    /// Store level read for each entry of `placed`.
    pub levels: Vec<usize>,
    pub index: FootprintIndex,
    pub grid: OutputGrid,
    pub tile_size: usize,
    pub method: FuseMethod,
}

/// A rendered tile: `tile_size`² values (NaN = no-data) and its valid pixel count.
pub struct RenderedTile {
    pub data: Vec<f32>,
    pub valid_pixels: u64,
}

impl<'a> TileRenderer<'a> {
    pub fn new(
        store: &'a Store,
        cache: &'a ChunkCache,
        poses: &'a [PoseXf],
        placed: Vec<PlacedDsm>,
        grid: OutputGrid,
        tile_size: usize,
        method: FuseMethod,
    ) -> TileRenderer<'a> {
        let gsd = grid.gsd_m();
        let levels = placed
            .iter()
            .map(|p| level_for(&store.dsms()[p.index], gsd))
            .collect();
        TileRenderer {
            store,
            cache,
            poses,
            index: FootprintIndex::new(&placed),
            placed,
            levels,
            grid,
            tile_size,
            method,
        }
    }

    /// Render tile (tx, ty) of the output grid.
    pub fn render(&self, tx: u64, ty: u64) -> Result<RenderedTile, FuseError> {
        let t = self.tile_size;
        let gsd = self.grid.gsd_m();
        let g = self.grid.geotransform.0;
        let (col0, row0) = (tx * t as u64, ty * t as u64);
        let w = (self.grid.width - col0).min(t as u64) as usize;
        let h = (self.grid.height - row0).min(t as u64) as usize;
        let x0 = g[0] + col0 as f64 * gsd;
        let y_top = g[3] - row0 as f64 * gsd;
        let bounds = [x0, y_top - h as f64 * gsd, x0 + w as f64 * gsd, y_top];
        let slots = self.index.touching(bounds);
        // Each DSM is sampled over its own window only, and the valid values are
        // gathered per pixel (in slot order): memory follows the data in the
        // tile, not the number of DSMs touching it times the tile's area.
        let mut windows = Vec::with_capacity(slots.len());
        for &slot in &slots {
            if let Some(window) = self.sample_dsm(slot, x0, y_top, w, h)? {
                windows.push(window);
            }
        }
        let mut start = vec![0usize; w * h + 1];
        for window in &windows {
            window.for_each_valid(w, |p, _| start[p + 1] += 1);
        }
        for p in 0..w * h {
            start[p + 1] += start[p];
        }
        let mut flat = vec![0f32; start[w * h]];
        let mut next = start.clone();
        for window in &windows {
            window.for_each_valid(w, |p, v| {
                flat[next[p]] = v;
                next[p] += 1;
            });
        }
        drop(windows);
        let mut data = vec![f32::NAN; t * t];
        let mut valid_pixels = 0;
        for r in 0..h {
            for c in 0..w {
                let p = r * w + c;
                let v = self.method.combine(&mut flat[start[p]..start[p + 1]]);
                valid_pixels += u64::from(!v.is_nan());
                data[r * t + c] = v;
            }
        }
        Ok(RenderedTile { data, valid_pixels })
    }

    /// Corrected heights of one DSM at the pixel centres of the part of a w x h
    /// window (top-left corner at (x0, y_top)) under its footprint; None when
    /// its footprint misses the window.
    fn sample_dsm(
        &self,
        slot: usize,
        x0: f64,
        y_top: f64,
        w: usize,
        h: usize,
    ) -> Result<Option<Window>, FuseError> {
        let placed = &self.placed[slot];
        let gsd = self.grid.gsd_m();
        let b = placed.corrected_bounds;
        let c_lo = (((b[0] - x0) / gsd).floor().max(0.0) as usize).min(w);
        let c_hi = (((b[2] - x0) / gsd).ceil().max(0.0) as usize).min(w);
        let r_lo = (((y_top - b[3]) / gsd).floor().max(0.0) as usize).min(h);
        let r_hi = (((y_top - b[1]) / gsd).ceil().max(0.0) as usize).min(h);
        if c_lo >= c_hi || r_lo >= r_hi {
            return Ok(None);
        }
        let grid = StoreGrid::new(self.store, self.cache, placed.index, self.levels[slot])?;
        let pose = &self.poses[placed.index];
        let mut surface = CorrectedSurface::new(grid, pose, placed.z_start_m);
        let mut values = Vec::with_capacity((c_hi - c_lo) * (r_hi - r_lo));
        for r in r_lo..r_hi {
            let y = y_top - (r as f64 + 0.5) * gsd;
            for c in c_lo..c_hi {
                let x = x0 + (c as f64 + 0.5) * gsd;
                values.push(surface.height_at(x, y) as f32);
            }
        }
        if let Some(error) = surface.grid_mut().take_chunk_error() {
            return Err(self.store.chunk_error(placed.index, error).into());
        }
        Ok(Some(Window {
            cols: c_lo..c_hi,
            rows: r_lo..r_hi,
            values,
        }))
    }
}

/// One DSM's corrected heights over its part of an output tile.
struct Window {
    cols: std::ops::Range<usize>,
    rows: std::ops::Range<usize>,
    /// Row-major over `rows` x `cols`; NaN where the DSM has no data.
    values: Vec<f32>,
}

impl Window {
    /// Calls `f(pixel index in a tile of width w, value)` for every valid value.
    fn for_each_valid(&self, w: usize, mut f: impl FnMut(usize, f32)) {
        let width = self.cols.len();
        for (k, r) in self.rows.clone().enumerate() {
            let row = &self.values[k * width..(k + 1) * width];
            for (c, &v) in self.cols.clone().zip(row) {
                if !v.is_nan() {
                    f(r * w + c, v);
                }
            }
        }
    }
}

impl FuseMethod {
    /// Combine the valid values of one pixel (reordered in place); NaN when none
    /// (0 for `Count`).
    pub fn combine(self, values: &mut [f32]) -> f32 {
        if let FuseMethod::Count = self {
            return values.len() as f32;
        }
        if values.is_empty() || (self == FuseMethod::Spread && values.len() < 2) {
            return f32::NAN;
        }
        match self {
            FuseMethod::Median => median_in_place(values),
            FuseMethod::Mean => {
                (values.iter().map(|&v| v as f64).sum::<f64>() / values.len() as f64) as f32
            }
            FuseMethod::Min => values.iter().copied().fold(f32::INFINITY, f32::min),
            FuseMethod::Max => values.iter().copied().fold(f32::NEG_INFINITY, f32::max),
            FuseMethod::Spread => {
                let (lo, hi) = values
                    .iter()
                    .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                        (lo.min(v), hi.max(v))
                    });
                hi - lo
            }
            FuseMethod::Count => unreachable!(),
        }
    }
}

/// Median of a non-empty slice (mean of the two middle values for even counts).
fn median_in_place(values: &mut [f32]) -> f32 {
    values.sort_unstable_by(f32::total_cmp);
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        ((values[n / 2 - 1] as f64 + values[n / 2] as f64) / 2.0) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn methods_combine_valid_values() {
        let v = [3.0f32, 1.0, 2.0, 10.0];
        let run = |m: FuseMethod, v: &[f32]| m.combine(&mut v.to_vec());
        assert_eq!(run(FuseMethod::Median, &v), 2.5);
        assert_eq!(run(FuseMethod::Median, &v[..3]), 2.0);
        assert_eq!(run(FuseMethod::Mean, &v), 4.0);
        assert_eq!(run(FuseMethod::Min, &v), 1.0);
        assert_eq!(run(FuseMethod::Max, &v), 10.0);
        assert_eq!(run(FuseMethod::Count, &v), 4.0);
        assert!(run(FuseMethod::Median, &[]).is_nan());
        assert_eq!(run(FuseMethod::Count, &[]), 0.0);
        assert_eq!(run(FuseMethod::Spread, &v), 9.0);
        assert!(run(FuseMethod::Spread, &v[..1]).is_nan());
    }
}
