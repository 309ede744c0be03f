//! Query points for DSM-ICP: valid pixels of the moving DSM inside the overlap,
//! spatially stratified (one per cell of a regular grid) and seeded, so the same
//! inputs always give the same samples.

use nalgebra::Vector3;

use crate::geo::Bounds;
use crate::grid::Grid;
use crate::nn::PixelFrame;
use crate::rng::SplitMix64;

/// The sampled query points, in the local frame.
#[derive(Clone, Debug, Default)]
pub struct Samples {
    pub points: Vec<Vector3<f64>>,
    /// Cells tried (a cell whose pixels are all no-data gives no point).
    pub cells: usize,
}

/// Pixel rectangle [col0, col1) x [row0, row1) of `grid` covered by the world
/// box; None when it is empty.
pub fn pixel_window<G: Grid + ?Sized>(grid: &G, world_box: &Bounds) -> Option<[i64; 4]> {
    let gt = grid.geotransform();
    let (c0, r0) = gt.world_to_pixel(world_box.min_x, world_box.max_y);
    let (c1, r1) = gt.world_to_pixel(world_box.max_x, world_box.min_y);
    let col0 = (c0.ceil() as i64).max(0);
    let row0 = (r0.ceil() as i64).max(0);
    let col1 = (c1.floor() as i64).min(grid.width());
    let row1 = (r1.floor() as i64).min(grid.height());
    (col1 > col0 && row1 > row0).then_some([col0, row0, col1, row1])
}

/// About `count` valid pixels of `grid` inside `world_box`, one per stratum.
pub fn sample_overlap<G: Grid + ?Sized>(
    grid: &mut G,
    frame: &PixelFrame,
    world_box: &Bounds,
    count: usize,
    seed: u64,
) -> Samples {
    let Some([col0, row0, col1, row1]) = pixel_window(grid, world_box) else {
        return Samples::default();
    };
    // Strata of a fractional edge, so the count is close to `count` (an
    // integer edge would round 2.2 px up to 3 and halve the samples).
    let area = ((col1 - col0) * (row1 - row0)) as f64;
    let cell_px = (area / count.max(1) as f64).sqrt().max(1.0);
    let edges = |start: i64, end: i64| -> Vec<i64> {
        let n = (((end - start) as f64 / cell_px).ceil() as i64).max(1);
        (0..=n)
            .map(|i| start + ((i as f64 * cell_px).round() as i64).min(end - start))
            .collect::<Vec<_>>()
    };
    let (col_edges, row_edges) = (edges(col0, col1), edges(row0, row1));
    let mut rng = SplitMix64::new(seed);
    let mut samples = Samples::default();
    for rows in row_edges.windows(2) {
        let (row, cell_h) = (rows[0], rows[1] - rows[0]);
        if cell_h <= 0 {
            continue;
        }
        for cols in col_edges.windows(2) {
            let (col, cell_w) = (cols[0], cols[1] - cols[0]);
            if cell_w <= 0 {
                continue;
            }
            samples.cells += 1;
            for _attempt in 0..4 {
                let c = col + rng.below(cell_w as u64) as i64;
                let r = row + rng.below(cell_h as u64) as i64;
                let h = grid.get(c, r);
                if !h.is_nan() {
                    samples.points.push(frame.pixel_point(c, r, h));
                    break;
                }
            }
        }
    }
    samples
}
