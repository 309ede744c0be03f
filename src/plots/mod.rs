//! PNG pictures of a registration, drawn with the `image` crate and a built-in
//! bitmap font (no font files, no plotting dependency):
//! - [`scene_graph_png`]: DSM footprints and the pairs between them, edges
//!   coloured by a value in metres (the averaging residual), with a colour bar;
//! - [`diff_map_png`]: maps of signed height differences (before / after) on a
//!   diverging colour scale shared by the panels, with a colour bar in metres;
//! - [`histogram_png`]: overlaid histograms of height differences (share of
//!   samples per bin, so sets of different sizes compare);
//! - [`write_eval_plots`]: the pictures of an `eval` report, from the three.

pub mod axes;
pub mod canvas;
pub mod colormap;
pub mod font;
mod graph;
mod histogram;
mod map;
pub mod report;

pub use graph::{scene_graph_png, GraphEdge, GraphNode};
pub use histogram::{histogram_png, Series};
pub use map::{diff_map_png, MapGrid};
pub use report::write_eval_plots;

/// A plot could not be written (names the file).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct PlotError(pub String);

/// Percentile (0..=100) of the finite values, NaN when there are none.
pub(crate) fn percentile(values: impl Iterator<Item = f64>, q: f64) -> f64 {
    let mut v: Vec<f64> = values.filter(|v| v.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_unstable_by(f64::total_cmp);
    let pos = (q / 100.0 * (v.len() - 1) as f64).round() as usize;
    v[pos.min(v.len() - 1)]
}

#[cfg(test)]
mod tests;
