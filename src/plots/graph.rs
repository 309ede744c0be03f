//! The scene graph over the DSM footprints: outlines, centres with ids, and an
//! edge per pair coloured by a value in metres (viridis, colour bar at the
//! right); dropped edges dashed grey. Equal scale in x and y, CRS axes.

use std::path::Path;

use super::axes::{colour_bar, Frame};
use super::canvas::{Align, Canvas, BLACK, GREY};
use super::colormap::ColorMap;
use super::PlotError;
use crate::geo::Bounds;

/// Sideways bow of edge curves, as a fraction of their length.
const EDGE_BOW: f64 = 0.12;

/// Tableau-10 hues for footprints (edges use viridis).
const FOOTPRINT_HUES: [[u8; 3]; 10] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
];

/// One DSM: its id and (corrected) footprint.
#[derive(Clone, Debug)]
pub struct GraphNode {
    pub id: String,
    pub bounds: Bounds,
}

/// One pair between nodes `a` and `b` (indices into the node list).
#[derive(Clone, Debug)]
pub struct GraphEdge {
    pub a: usize,
    pub b: usize,
    /// Colour value in metres (NaN: drawn grey).
    pub value_m: f64,
    /// Rejected by the averaging: dashed.
    pub dropped: bool,
}

/// Draw the graph to `path` (PNG, 1100 x 850).
pub fn scene_graph_png(
    path: &Path,
    nodes: &[GraphNode],
    edges: &[GraphEdge],
    value_label: &str,
    title: &str,
) -> Result<(), PlotError> {
    let b = Bounds::union_all(nodes.iter().map(|n| n.bounds))
        .filter(|b| b.to_array().iter().all(|v| v.is_finite()));
    let Some(b) = b else {
        return Err(PlotError(format!(
            "{}: no footprint to draw",
            path.display()
        )));
    };
    // equal scale: fit the data box (padded 3 %) into at most 800 x 640 px
    let pad = 0.03 * b.width().max(b.height());
    let (dx, dy) = (b.width() + 2.0 * pad, b.height() + 2.0 * pad);
    let scale = (800.0 / dx).min(640.0 / dy);
    let (w, h) = ((dx * scale) as i64, (dy * scale) as i64);
    let (cw, ch) = (120 + w.max(500) + 190, 70 + h.max(300) + 90);
    let mut c = Canvas::new(cw as u32, ch as u32);
    c.text(cw / 2, 14, title, BLACK, 2, Align::Centre);
    let frame = Frame {
        left: 120 + (w.max(500) - w) / 2,
        top: 70 + (h.max(300) - h) / 2,
        width: w,
        height: h,
        x_range: (b.min_x - pad, b.max_x + pad),
        y_range: (b.min_y - pad, b.max_y + pad),
    };
    // footprints: a light tint and an outline each, in a cycle of distinct hues
    for (k, n) in nodes.iter().enumerate() {
        let hue = FOOTPRINT_HUES[k % FOOTPRINT_HUES.len()];
        let (x0, y0) = frame.to_px(n.bounds.min_x, n.bounds.max_y);
        let (x1, y1) = frame.to_px(n.bounds.max_x, n.bounds.min_y);
        let (x0, y0, x1, y1) = (x0 as i64, y0 as i64, x1 as i64, y1 as i64);
        for y in y0..y1 {
            for x in x0..x1 {
                let edge = x == x0 || x == x1 - 1 || y == y0 || y == y1 - 1;
                c.blend(x, y, hue, if edge { 0.7 } else { 0.06 });
            }
        }
    }
    // the colour scale covers the kept edges (dropped ones are grey)
    let finite: Vec<f64> = edges
        .iter()
        .filter(|e| !e.dropped)
        .map(|e| e.value_m)
        .filter(|v| v.is_finite())
        .collect();
    let vmax = finite.iter().copied().fold(0.0f64, f64::max).max(1e-3);
    let centre = |n: &GraphNode| {
        let (x, y) = n.bounds.centre();
        frame.to_px(x, y)
    };
    let thickness = if edges.len() > 200 { 2 } else { 4 };
    let mut order: Vec<&GraphEdge> = edges.iter().collect();
    // dropped first, then by value so the largest residuals stay visible on top
    order.sort_by(|a, b| {
        (!a.dropped, a.value_m)
            .partial_cmp(&(!b.dropped, b.value_m))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    for e in order {
        let (p, q) = (centre(&nodes[e.a]), centre(&nodes[e.b]));
        let colour = if e.dropped || !e.value_m.is_finite() {
            GREY
        } else {
            ColorMap::Viridis.at(e.value_m / vmax)
        };
        let dash = (colour == GREY).then_some(1);
        c.arc(
            p,
            q,
            EDGE_BOW,
            colour,
            if dash.is_some() { 2 } else { thickness },
            dash,
        );
    }
    let label_ids = nodes.len() <= 60;
    for n in nodes {
        let p = centre(n);
        c.disc(p, 4.0, BLACK);
        if label_ids {
            c.text(p.0 as i64 + 6, p.1 as i64 + 5, &n.id, BLACK, 1, Align::Left);
        }
    }
    frame.draw_axes(&mut c, "easting (m)", "northing (m)");
    colour_bar(
        &mut c,
        cw - 150,
        frame.top.max(80),
        (h - 40).clamp(200, 500),
        ColorMap::Viridis,
        (0.0, vmax),
        value_label,
    );
    let legend_y = ch - 28;
    c.line(
        (120.0, legend_y as f64),
        (150.0, legend_y as f64),
        GREY,
        2,
        Some(6),
    );
    c.text(156, legend_y - 3, "dropped edge", BLACK, 1, Align::Left);
    c.rect(260, legend_y - 6, 24, 12, GREY);
    c.text(290, legend_y - 3, "DSM footprint", BLACK, 1, Align::Left);
    c.save(path)
}
