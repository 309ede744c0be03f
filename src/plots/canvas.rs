//! An RGB drawing surface over `image::RgbImage`: pixels, rectangles, thick
//! lines, dashed lines and text in the built-in bitmap font (horizontal or
//! rotated for a y-axis label), saved as PNG.

use std::path::Path;

use image::{Rgb, RgbImage};

use super::font;
use super::PlotError;

pub type Color = [u8; 3];

pub const WHITE: Color = [255, 255, 255];
pub const BLACK: Color = [0, 0, 0];
pub const GREY: Color = [150, 150, 150];
pub const LIGHT_GREY: Color = [225, 225, 225];

/// Horizontal text anchor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Align {
    Left,
    Centre,
    Right,
}

pub struct Canvas {
    pub img: RgbImage,
}

impl Canvas {
    pub fn new(width: u32, height: u32) -> Canvas {
        Canvas {
            img: RgbImage::from_pixel(width, height, Rgb(WHITE)),
        }
    }

    pub fn width(&self) -> u32 {
        self.img.width()
    }

    pub fn height(&self) -> u32 {
        self.img.height()
    }

    #[inline]
    pub fn set(&mut self, x: i64, y: i64, c: Color) {
        if x >= 0 && y >= 0 && (x as u32) < self.img.width() && (y as u32) < self.img.height() {
            self.img.put_pixel(x as u32, y as u32, Rgb(c));
        }
    }

    /// Mix `c` into the pixel with weight `alpha` (0..=1).
    #[inline]
    pub fn blend(&mut self, x: i64, y: i64, c: Color, alpha: f64) {
        if x >= 0 && y >= 0 && (x as u32) < self.img.width() && (y as u32) < self.img.height() {
            let p = self.img.get_pixel_mut(x as u32, y as u32);
            for (v, &target) in p.0.iter_mut().zip(&c) {
                *v = (*v as f64 * (1.0 - alpha) + target as f64 * alpha).round() as u8;
            }
        }
    }

    pub fn fill_rect(&mut self, x0: i64, y0: i64, w: i64, h: i64, c: Color) {
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                self.set(x, y, c);
            }
        }
    }

    pub fn rect(&mut self, x0: i64, y0: i64, w: i64, h: i64, c: Color) {
        for x in x0..x0 + w {
            self.set(x, y0, c);
            self.set(x, y0 + h - 1, c);
        }
        for y in y0..y0 + h {
            self.set(x0, y, c);
            self.set(x0 + w - 1, y, c);
        }
    }

    /// A line `thickness` pixels wide; with `dash` = Some(n), n on, n off.
    pub fn line(
        &mut self,
        (x0, y0): (f64, f64),
        (x1, y1): (f64, f64),
        c: Color,
        thickness: u32,
        dash: Option<u32>,
    ) {
        let len = ((x1 - x0).powi(2) + (y1 - y0).powi(2)).sqrt();
        let steps = (len.ceil() as i64).max(1);
        let r = thickness as f64 / 2.0;
        let ri = r.ceil() as i64;
        for s in 0..=steps {
            if let Some(d) = dash {
                if (s / d.max(1) as i64) % 2 == 1 {
                    continue;
                }
            }
            let t = s as f64 / steps as f64;
            let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
            for dy in -ri..=ri {
                for dx in -ri..=ri {
                    if ((dx * dx + dy * dy) as f64) <= r * r + 0.25 {
                        self.set(x.round() as i64 + dx, y.round() as i64 + dy, c);
                    }
                }
            }
        }
    }

    /// A quadratic Bezier curve from `a` to `b` bowed sideways by `bow` times
    /// its length (so edges between aligned nodes do not hide each other).
    pub fn arc(
        &mut self,
        a: (f64, f64),
        b: (f64, f64),
        bow: f64,
        c: Color,
        thickness: u32,
        dash: Option<u32>,
    ) {
        let (mx, my) = ((a.0 + b.0) / 2.0, (a.1 + b.1) / 2.0);
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let ctrl = (mx - dy * bow, my + dx * bow);
        let len = (dx * dx + dy * dy).sqrt();
        let segments = ((len / 6.0).ceil() as usize).clamp(1, 400);
        let point = |t: f64| {
            let u = 1.0 - t;
            (
                u * u * a.0 + 2.0 * u * t * ctrl.0 + t * t * b.0,
                u * u * a.1 + 2.0 * u * t * ctrl.1 + t * t * b.1,
            )
        };
        let mut prev = a;
        for k in 1..=segments {
            let next = point(k as f64 / segments as f64);
            let visible = dash.is_none_or(|_| k % 2 == 1);
            if visible {
                self.line(prev, next, c, thickness, None);
            }
            prev = next;
        }
    }

    /// Filled disc.
    pub fn disc(&mut self, (x, y): (f64, f64), radius: f64, c: Color) {
        let ri = radius.ceil() as i64;
        for dy in -ri..=ri {
            for dx in -ri..=ri {
                if ((dx * dx + dy * dy) as f64) <= radius * radius {
                    self.set(x.round() as i64 + dx, y.round() as i64 + dy, c);
                }
            }
        }
    }

    /// Width in pixels of `text` at `scale`.
    pub fn text_width(text: &str, scale: u32) -> i64 {
        let n = text.chars().count() as i64;
        (n * font::ADVANCE as i64 - 1).max(0) * scale as i64
    }

    /// Text with its top at `y`, anchored at `x` per `align`.
    pub fn text(&mut self, x: i64, y: i64, text: &str, c: Color, scale: u32, align: Align) {
        let w = Canvas::text_width(text, scale);
        let x0 = match align {
            Align::Left => x,
            Align::Centre => x - w / 2,
            Align::Right => x - w,
        };
        let s = scale as i64;
        for (k, ch) in text.chars().enumerate() {
            let g = font::glyph(ch);
            let gx = x0 + k as i64 * font::ADVANCE as i64 * s;
            for row in 0..font::HEIGHT {
                for col in 0..5 {
                    if font::pixel(&g, col, row) {
                        self.fill_rect(gx + col as i64 * s, y + row as i64 * s, s, s, c);
                    }
                }
            }
        }
    }

    /// Text rotated 90 degrees counter-clockwise (reads bottom to top), centred
    /// vertically on `y`, its left edge at `x`.
    pub fn text_up(&mut self, x: i64, y: i64, text: &str, c: Color, scale: u32) {
        let w = Canvas::text_width(text, scale);
        let s = scale as i64;
        let y_bottom = y + w / 2;
        for (k, ch) in text.chars().enumerate() {
            let g = font::glyph(ch);
            let along = k as i64 * font::ADVANCE as i64 * s;
            for row in 0..font::HEIGHT {
                for col in 0..5 {
                    if font::pixel(&g, col, row) {
                        let px = x + row as i64 * s;
                        let py = y_bottom - along - (col as i64 + 1) * s;
                        self.fill_rect(px, py, s, s, c);
                    }
                }
            }
        }
    }

    /// Writes the PNG through a temporary name (never a partial picture).
    pub fn save(&self, path: &Path) -> Result<(), PlotError> {
        crate::atomic::write_atomically(path, |out| {
            self.img
                .write_to(out, image::ImageFormat::Png)
                .map_err(std::io::Error::other)
        })
        .map_err(|e| PlotError(format!("{}: {e}", path.display())))
    }
}
