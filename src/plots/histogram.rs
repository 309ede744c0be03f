//! Overlaid histograms of height differences: the first series filled, the
//! others as thick step outlines, each normalised to its share of samples per
//! bin (of all the series' samples, shown or not), over a range symmetric
//! about 0 that holds 97 % of them.

use std::path::Path;

use super::axes::{nice_step, Frame};
use super::canvas::{Align, Canvas, Color, BLACK, GREY, WHITE};
use super::{percentile, PlotError};

/// One set of values with its legend label and colour.
pub struct Series<'a> {
    pub label: String,
    pub values: &'a [f32],
    pub colour: Color,
}

const BINS: usize = 101;

/// Draw the histograms to `path` (PNG, 1000 x 620).
pub fn histogram_png(
    path: &Path,
    series: &[Series],
    x_label: &str,
    title: &str,
) -> Result<(), PlotError> {
    let p97 = percentile(
        series
            .iter()
            .flat_map(|s| s.values.iter().map(|v| (*v as f64).abs())),
        97.0,
    );
    if !p97.is_finite() {
        return Err(PlotError(format!("{}: no values to draw", path.display())));
    }
    let step = nice_step((p97 / 4.0).max(1e-3));
    let range = (p97 / step).ceil() * step;
    let width_bin = 2.0 * range / BINS as f64;
    let shares: Vec<Vec<f64>> = series
        .iter()
        .map(|s| {
            let mut h = vec![0.0; BINS];
            let mut n = 0usize;
            for &v in s.values {
                if v.is_nan() {
                    continue;
                }
                n += 1;
                let k = ((v as f64 + range) / width_bin).floor();
                if k >= 0.0 && (k as usize) < BINS {
                    h[k as usize] += 1.0;
                }
            }
            h.iter().map(|c| 100.0 * c / n.max(1) as f64).collect()
        })
        .collect();
    let top_share = shares
        .iter()
        .flatten()
        .copied()
        .fold(0.0f64, f64::max)
        .max(1e-9);
    let (cw, ch) = (1000i64, 620i64);
    let mut c = Canvas::new(cw as u32, ch as u32);
    c.text(cw / 2, 14, title, BLACK, 2, Align::Centre);
    let frame = Frame {
        left: 110,
        top: 60,
        width: cw - 110 - 40,
        height: ch - 60 - 110,
        x_range: (-range, range),
        y_range: (0.0, top_share * 1.08),
    };
    for (k, (s, h)) in series.iter().zip(&shares).enumerate() {
        let mut prev: Option<(f64, f64)> = None;
        for (b, &share) in h.iter().enumerate() {
            let x0 = -range + b as f64 * width_bin;
            let (px0, py) = frame.to_px(x0, share);
            let (px1, base) = frame.to_px(x0 + width_bin, 0.0);
            if k == 0 {
                // a light tint of the series colour
                let fill = [0, 1, 2].map(|i| ((s.colour[i] as u16 + 2 * 255) / 3) as u8);
                c.fill_rect(
                    px0.round() as i64,
                    py.round() as i64,
                    (px1 - px0).round().max(1.0) as i64,
                    (base - py).round() as i64,
                    fill,
                );
            }
            if let Some(p) = prev {
                c.line(p, (px0, py), s.colour, 2, None);
            }
            c.line((px0, py), (px1, py), s.colour, 2, None);
            prev = Some((px1, py));
        }
    }
    frame.draw_x_grid(&mut c);
    frame.draw_axes(&mut c, x_label, "share of samples per bin (%)");
    let widest = series
        .iter()
        .map(|s| Canvas::text_width(&s.label, 1))
        .max()
        .unwrap_or(0);
    let (lx, ly) = (frame.left + 8, frame.top + 6);
    let box_h = 20 * series.len() as i64 + 8;
    c.fill_rect(lx, ly, widest + 50, box_h, WHITE);
    c.rect(lx, ly, widest + 50, box_h, GREY);
    for (k, s) in series.iter().enumerate() {
        let y = frame.top + 12 + 20 * k as i64;
        let x = frame.left + 14;
        c.fill_rect(x, y, 26, 10, s.colour);
        c.text(x + 34, y + 1, &s.label, BLACK, 1, Align::Left);
    }
    c.save(path)
}
