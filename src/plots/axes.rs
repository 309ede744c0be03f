//! Axes: "nice" tick values (1, 2, 5 x 10^k), tick labels, a plot frame that
//! maps data coordinates to pixels with ticks and axis labels, and a vertical
//! colour bar with its own ticks and unit label.

use super::canvas::{Align, Canvas, BLACK, GREY};
use super::colormap::ColorMap;

/// Label scale (font pixels to image pixels) for tick labels; titles use 2.
pub const TICK_SCALE: u32 = 1;

/// About `target` nice tick values covering [lo, hi].
pub fn nice_ticks(lo: f64, hi: f64, target: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let step = nice_step((hi - lo) / target.max(1) as f64);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| k as f64 * step).collect()
}

/// The nice number (1, 2, 5 x 10^k) nearest above `raw`.
pub fn nice_step(raw: f64) -> f64 {
    let mag = 10f64.powf(raw.log10().floor());
    let f = raw / mag;
    let n = if f <= 1.0 {
        1.0
    } else if f <= 2.0 {
        2.0
    } else if f <= 5.0 {
        5.0
    } else {
        10.0
    };
    n * mag
}

/// Tick label with as many decimals as the tick step needs.
pub fn format_tick(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 {
        0
    } else {
        (-step.log10()).ceil().clamp(0.0, 6.0) as usize
    };
    let s = format!("{v:.decimals$}");
    if s.starts_with("-") && s.trim_start_matches(['-', '0', '.']).is_empty() {
        s[1..].to_string()
    } else {
        s
    }
}

/// A rectangle of the canvas showing data [x0, x1] x [y0, y1] (y up).
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub left: i64,
    pub top: i64,
    pub width: i64,
    pub height: i64,
    pub x_range: (f64, f64),
    pub y_range: (f64, f64),
}

impl Frame {
    pub fn to_px(&self, x: f64, y: f64) -> (f64, f64) {
        let (x0, x1) = self.x_range;
        let (y0, y1) = self.y_range;
        (
            self.left as f64 + (x - x0) / (x1 - x0) * self.width as f64,
            self.top as f64 + (y1 - y) / (y1 - y0) * self.height as f64,
        )
    }

    /// Border, ticks with labels on the left and bottom, and axis labels.
    pub fn draw_axes(&self, c: &mut Canvas, x_label: &str, y_label: &str) {
        c.rect(self.left, self.top, self.width, self.height, BLACK);
        let bottom = self.top + self.height;
        let xt = nice_ticks(
            self.x_range.0,
            self.x_range.1,
            (self.width / 110).max(2) as usize,
        );
        let xs = if xt.len() > 1 { xt[1] - xt[0] } else { 1.0 };
        for v in &xt {
            let (px, _) = self.to_px(*v, self.y_range.0);
            let px = px.round() as i64;
            c.fill_rect(px, bottom, 1, 5, BLACK);
            c.text(
                px,
                bottom + 8,
                &format_tick(*v, xs),
                BLACK,
                TICK_SCALE,
                Align::Centre,
            );
        }
        let yt = nice_ticks(
            self.y_range.0,
            self.y_range.1,
            (self.height / 70).max(2) as usize,
        );
        let ys = if yt.len() > 1 { yt[1] - yt[0] } else { 1.0 };
        let mut widest = 0;
        for v in &yt {
            let (_, py) = self.to_px(self.x_range.0, *v);
            let py = py.round() as i64;
            let label = format_tick(*v, ys);
            widest = widest.max(Canvas::text_width(&label, TICK_SCALE));
            c.fill_rect(self.left - 5, py, 5, 1, BLACK);
            c.text(
                self.left - 8,
                py - 3,
                &label,
                BLACK,
                TICK_SCALE,
                Align::Right,
            );
        }
        c.text(
            self.left + self.width / 2,
            bottom + 24,
            x_label,
            BLACK,
            TICK_SCALE,
            Align::Centre,
        );
        c.text_up(
            self.left - widest - 24,
            self.top + self.height / 2,
            y_label,
            BLACK,
            TICK_SCALE,
        );
    }

    /// Light vertical grid lines at the x ticks.
    pub fn draw_x_grid(&self, c: &mut Canvas) {
        let xt = nice_ticks(
            self.x_range.0,
            self.x_range.1,
            (self.width / 110).max(2) as usize,
        );
        for v in xt {
            let (px, _) = self.to_px(v, self.y_range.0);
            for y in self.top..self.top + self.height {
                if y % 4 < 2 {
                    c.set(px.round() as i64, y, GREY);
                }
            }
        }
    }
}

/// A vertical colour bar for values lo..hi at (left, top), with ticks and a
/// label (units) rotated beside it.
#[allow(clippy::too_many_arguments)]
pub fn colour_bar(
    c: &mut Canvas,
    left: i64,
    top: i64,
    height: i64,
    map: ColorMap,
    (lo, hi): (f64, f64),
    label: &str,
) {
    let width = 18;
    for y in 0..height {
        let t = 1.0 - y as f64 / (height - 1).max(1) as f64;
        c.fill_rect(left, top + y, width, 1, map.at(t));
    }
    c.rect(left, top, width, height, BLACK);
    let ticks = nice_ticks(lo, hi, 6);
    let step = if ticks.len() > 1 {
        ticks[1] - ticks[0]
    } else {
        1.0
    };
    let mut widest = 0;
    for v in ticks {
        let y = top + ((hi - v) / (hi - lo) * (height - 1) as f64).round() as i64;
        c.fill_rect(left + width, y, 4, 1, BLACK);
        let text = format_tick(v, step);
        widest = widest.max(Canvas::text_width(&text, TICK_SCALE));
        c.text(
            left + width + 7,
            y - 3,
            &text,
            BLACK,
            TICK_SCALE,
            Align::Left,
        );
    }
    c.text_up(
        left + width + 14 + widest,
        top + height / 2,
        label,
        BLACK,
        TICK_SCALE,
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_nice() {
        assert_eq!(
            nice_ticks(0.0, 1.0, 5),
            vec![0.0, 0.2, 0.4, 0.6000000000000001, 0.8, 1.0]
        );
        assert_eq!(nice_ticks(-3.2, 3.2, 4), vec![-2.0, 0.0, 2.0]);
        assert_eq!(nice_step(0.031), 0.05);
        assert_eq!(format_tick(0.6000000000000001, 0.2), "0.6");
        assert_eq!(format_tick(-0.0001, 0.05), "0.00");
        assert_eq!(format_tick(4_800_000.0, 50.0), "4800000");
    }
}
