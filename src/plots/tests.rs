//! The pictures render, at the expected places, in the expected colours.

use super::canvas::{Align, Canvas, BLACK, WHITE};
use super::colormap::ColorMap;
use super::*;
use crate::geo::Bounds;

fn pixel(img: &image::RgbImage, x: u32, y: u32) -> [u8; 3] {
    img.get_pixel(x, y).0
}

#[test]
fn bins_average_samples_per_cell() {
    let samples = [
        (0.5, 9.5, 1.0f32),
        (0.6, 9.4, 3.0),
        (9.5, 0.5, -2.0),
        (5.0, 5.0, f32::NAN),
    ];
    let g = MapGrid::bin(
        samples.into_iter(),
        Bounds::from([0.0, 0.0, 10.0, 10.0]),
        10,
    );
    assert_eq!((g.width, g.height), (10, 10));
    assert_eq!(g.values[0], 2.0); // top-left cell: mean of 1 and 3
    assert_eq!(g.values[9 * 10 + 9], -2.0); // bottom-right
    assert_eq!(g.values.iter().filter(|v| !v.is_nan()).count(), 2);
}

#[test]
fn text_draws_glyph_pixels_and_sizes_add_up() {
    let mut c = Canvas::new(40, 20);
    c.text(1, 1, "1", BLACK, 2, Align::Left);
    // '1' has its stem in column 2 of the glyph: pixels (1 + 2*2, 1 + 2*row)
    assert_eq!(pixel(&c.img, 5, 5), BLACK);
    assert_eq!(pixel(&c.img, 1, 5), WHITE);
    assert_eq!(Canvas::text_width("abc", 1), 17);
    assert_eq!(Canvas::text_width("abc", 2), 34);
}

#[test]
fn every_plot_renders() {
    let dir = tempfile::tempdir().unwrap();
    let nodes: Vec<GraphNode> = (0..3)
        .map(|k| GraphNode {
            id: format!("t{k}"),
            bounds: Bounds::from([k as f64 * 50.0, 0.0, k as f64 * 50.0 + 100.0, 100.0]),
        })
        .collect();
    let edges = vec![
        GraphEdge {
            a: 0,
            b: 1,
            value_m: 0.1,
            dropped: false,
        },
        GraphEdge {
            a: 1,
            b: 2,
            value_m: 0.4,
            dropped: false,
        },
        GraphEdge {
            a: 0,
            b: 2,
            value_m: 2.0,
            dropped: true,
        },
    ];
    let p = dir.path().join("g.png");
    scene_graph_png(&p, &nodes, &edges, "residual (m)", "graph").unwrap();
    let img = image::open(&p).unwrap().to_rgb8();
    // the largest kept value (0.4, not the dropped 2.0) takes the top colour of
    // the scale: a whole edge of it, not only the colour bar's end
    let top = ColorMap::Viridis.at(1.0);
    let n = img.pixels().filter(|px| px.0 == top).count();
    assert!(n > 300, "{n} pixels of the top colour");

    let before: Vec<f32> = (0..1000).map(|k| (k % 50) as f32 / 10.0 - 2.5).collect();
    let after: Vec<f32> = before.iter().map(|v| v / 5.0).collect();
    let series = [
        Series {
            label: "before".into(),
            values: &before,
            colour: [230, 120, 30],
        },
        Series {
            label: "after".into(),
            values: &after,
            colour: [30, 90, 200],
        },
    ];
    let p = dir.path().join("h.png");
    histogram_png(&p, &series, "dh (m)", "hist").unwrap();
    let img = image::open(&p).unwrap().to_rgb8();
    assert!(img.pixels().any(|px| px.0 == [30, 90, 200]));

    let g = MapGrid::bin(
        (0..100).map(|k| {
            (
                (k % 10) as f64 + 0.5,
                (k / 10) as f64 + 0.5,
                (k % 10) as f32 - 4.5,
            )
        }),
        Bounds::from([0.0, 0.0, 10.0, 10.0]),
        10,
    );
    let p = dir.path().join("m.png");
    diff_map_png(&p, &[("before", &g), ("after", &g)], "dh (m)", "map").unwrap();
    let img = image::open(&p).unwrap().to_rgb8();
    // negative differences blue, positive red
    assert!(img.pixels().any(|px| px.0[2] as i32 > px.0[0] as i32 + 80));
    assert!(img.pixels().any(|px| px.0[0] as i32 > px.0[2] as i32 + 80));
    assert!(histogram_png(&dir.path().join("e.png"), &[], "x", "t").is_err());
}
