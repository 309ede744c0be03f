//! Maps of signed height differences: samples binned into cells (mean per
//! cell), panels side by side on one diverging colour scale, symmetric about 0
//! at the 98th percentile of |dh|, with a shared colour bar in metres.

use std::path::Path;

use super::axes::{colour_bar, nice_step, Frame};
use super::canvas::{Align, Canvas, BLACK, LIGHT_GREY};
use super::colormap::ColorMap;
use super::{percentile, PlotError};
use crate::geo::Bounds;

/// Cell means over a box, row-major from the top; NaN = no sample.
#[derive(Clone, Debug)]
pub struct MapGrid {
    /// The box the cells tile (CRS units).
    pub bounds: Bounds,
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
}

impl MapGrid {
    /// Bin (x, y, value) samples (NaN values skipped) into at most
    /// `max_cells` cells along the long side of `bounds`.
    pub fn bin(
        samples: impl Iterator<Item = (f64, f64, f32)>,
        bounds: Bounds,
        max_cells: usize,
    ) -> MapGrid {
        let (dx, dy) = (bounds.width(), bounds.height());
        let cell = dx.max(dy) / max_cells.max(1) as f64;
        let width = ((dx / cell).ceil() as usize).max(1);
        let height = ((dy / cell).ceil() as usize).max(1);
        let mut sum = vec![0.0f64; width * height];
        let mut count = vec![0u32; width * height];
        for (x, y, v) in samples {
            if v.is_nan() {
                continue;
            }
            let c = ((x - bounds.min_x) / cell).floor();
            let r = ((bounds.max_y - y) / cell).floor();
            if c < 0.0 || r < 0.0 || c >= width as f64 || r >= height as f64 {
                continue;
            }
            let k = r as usize * width + c as usize;
            sum[k] += v as f64;
            count[k] += 1;
        }
        let values = sum
            .iter()
            .zip(&count)
            .map(|(s, &n)| {
                if n == 0 {
                    f32::NAN
                } else {
                    (s / n as f64) as f32
                }
            })
            .collect();
        MapGrid {
            bounds,
            width,
            height,
            values,
        }
    }
}

/// Draw the panels (title, grid) side by side to `path` (PNG).
pub fn diff_map_png(
    path: &Path,
    panels: &[(&str, &MapGrid)],
    value_label: &str,
    title: &str,
) -> Result<(), PlotError> {
    if panels.is_empty() {
        return Err(PlotError(format!("{}: nothing to draw", path.display())));
    }
    let p98 = percentile(
        panels
            .iter()
            .flat_map(|(_, g)| g.values.iter().map(|v| (*v as f64).abs())),
        98.0,
    );
    let vmax = if p98.is_finite() && p98 > 0.0 {
        let step = nice_step(p98 / 4.0);
        (p98 / step).ceil() * step
    } else {
        1.0
    };
    let b = panels[0].1.bounds;
    let (dx, dy) = (b.width(), b.height());
    let side = 480.0;
    let scale = (side / dx).min(side / dy);
    let (pw, ph) = ((dx * scale).round() as i64, (dy * scale).round() as i64);
    let gap = 120;
    let (left0, top) = (120, 80);
    let cw = left0 + panels.len() as i64 * (pw + gap) + 40;
    let ch = top + ph + 90;
    let mut c = Canvas::new(cw as u32, ch.max(420) as u32);
    c.text(cw / 2, 14, title, BLACK, 2, Align::Centre);
    for (k, (name, grid)) in panels.iter().enumerate() {
        let frame = Frame {
            left: left0 + k as i64 * (pw + gap),
            top,
            width: pw,
            height: ph,
            x_range: (grid.bounds.min_x, grid.bounds.max_x),
            y_range: (grid.bounds.min_y, grid.bounds.max_y),
        };
        for py in 0..ph {
            for px in 0..pw {
                let col = (px as f64 / pw as f64 * grid.width as f64) as usize;
                let row = (py as f64 / ph as f64 * grid.height as f64) as usize;
                let v =
                    grid.values[row.min(grid.height - 1) * grid.width + col.min(grid.width - 1)];
                let colour = if v.is_nan() {
                    LIGHT_GREY
                } else {
                    ColorMap::Diverging.at(0.5 + v as f64 / (2.0 * vmax))
                };
                c.set(frame.left + px, top + py, colour);
            }
        }
        c.text(frame.left + pw / 2, top - 22, name, BLACK, 2, Align::Centre);
        frame.draw_axes(&mut c, "easting (m)", "northing (m)");
    }
    colour_bar(
        &mut c,
        cw - 150 - 40 + 60,
        top,
        ph.clamp(200, 480),
        ColorMap::Diverging,
        (-vmax, vmax),
        value_label,
    );
    c.text(left0, ch - 22, "grey: no sample", BLACK, 1, Align::Left);
    c.save(path)
}
