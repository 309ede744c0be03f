//! Where things land after correction: each DSM's corrected footprint, the
//! store level read for an output cell size, and the output grid (the union of
//! corrected footprints, snapped to the lattice of the finest DSM so an identity
//! pose reads input pixels without interpolation).

use rstar::{RTree, AABB};

use super::corrected::PoseXf;
use crate::geo::Bounds;
use crate::geo::GeoTransform;
use crate::plan::Footprint;
use crate::store::{DsmMeta, Store};

/// Relative tolerance when comparing cell sizes.
const GSD_TOLERANCE: f64 = 1e-6;

/// One DSM as fuse and eval see it after its pose.
#[derive(Clone, Debug)]
pub struct PlacedDsm {
    /// Store index.
    pub index: usize,
    /// [min_x, min_y, max_x, max_y] of the valid pixels after the pose.
    pub corrected_bounds: [f64; 4],
    /// Start height of the corrected-height iteration (mean height of the DSM).
    pub z_start_m: f64,
}

impl PlacedDsm {
    pub fn new(index: usize, meta: &DsmMeta, pose: &PoseXf) -> PlacedDsm {
        let s = &meta.height_stats;
        let z_range = if s.min.is_finite() && s.max.is_finite() {
            [s.min, s.max]
        } else {
            [0.0, 0.0]
        };
        PlacedDsm {
            index,
            corrected_bounds: pose.map_bounds(meta.footprint.to_array(), z_range),
            z_start_m: if s.mean.is_finite() { s.mean } else { 0.0 },
        }
    }
}

/// The coarsest store level whose cell is not coarser than `gsd_m`.
pub fn level_for(meta: &DsmMeta, gsd_m: f64) -> usize {
    let mut level = 0;
    while level + 1 < meta.levels.len()
        && meta.gsd_m() * (1u64 << (level + 1)) as f64 <= gsd_m * (1.0 + GSD_TOLERANCE)
    {
        level += 1;
    }
    level
}

/// A north-up output raster.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OutputGrid {
    pub width: u64,
    pub height: u64,
    pub geotransform: GeoTransform,
}

impl OutputGrid {
    /// The smallest grid of `gsd_m` cells covering `bounds`, its lines on the
    /// lattice through (anchor_x, anchor_y).
    pub fn covering(bounds: [f64; 4], gsd_m: f64, anchor: (f64, f64)) -> OutputGrid {
        let snap_down = |v: f64, a: f64| a + ((v - a) / gsd_m + GSD_TOLERANCE).floor() * gsd_m;
        let snap_up = |v: f64, a: f64| a + ((v - a) / gsd_m - GSD_TOLERANCE).ceil() * gsd_m;
        let x0 = snap_down(bounds[0], anchor.0);
        let x1 = snap_up(bounds[2], anchor.0);
        let y0 = snap_down(bounds[1], anchor.1);
        let y1 = snap_up(bounds[3], anchor.1);
        OutputGrid {
            width: (((x1 - x0) / gsd_m).round() as u64).max(1),
            height: (((y1 - y0) / gsd_m).round() as u64).max(1),
            geotransform: GeoTransform::north_up(x0, y1, gsd_m, gsd_m),
        }
    }

    pub fn gsd_m(&self) -> f64 {
        self.geotransform.gsd_x()
    }
}

/// Union of bounds.
pub fn union_bounds(bounds: impl IntoIterator<Item = [f64; 4]>) -> Option<[f64; 4]> {
    Bounds::union_all(bounds.into_iter().map(Bounds::from)).map(Bounds::to_array)
}

/// The finest level-0 cell of the store and the origin of a DSM that has it.
pub fn finest_lattice(store: &Store, dsms: &[usize]) -> Option<(f64, (f64, f64))> {
    dsms.iter()
        .map(|&i| &store.dsms()[i])
        .min_by(|a, b| a.gsd_m().total_cmp(&b.gsd_m()))
        .map(|m| (m.gsd_m(), (m.geotransform.0[0], m.geotransform.0[3])))
}

/// R-tree of corrected footprints: which DSMs touch a box or a point.
pub struct FootprintIndex {
    tree: RTree<Footprint>,
}

impl FootprintIndex {
    /// Index `placed[k].corrected_bounds`; queries return the slots k, sorted.
    pub fn new(placed: &[PlacedDsm]) -> FootprintIndex {
        FootprintIndex {
            tree: RTree::bulk_load(
                placed
                    .iter()
                    .enumerate()
                    .map(|(slot, p)| Footprint {
                        index: slot,
                        bounds: p.corrected_bounds.into(),
                    })
                    .collect(),
            ),
        }
    }

    /// Slots whose footprint intersects [min_x, min_y, max_x, max_y], ascending.
    pub fn touching(&self, b: [f64; 4]) -> Vec<usize> {
        let env = AABB::from_corners([b[0], b[1]], [b[2], b[3]]);
        let mut out: Vec<usize> = self
            .tree
            .locate_in_envelope_intersecting(env)
            .map(|e| e.index)
            .collect();
        out.sort_unstable();
        out
    }

    /// Slots whose footprint contains (x, y), ascending (appended to `out`).
    pub fn at_point(&self, x: f64, y: f64, out: &mut Vec<usize>) {
        out.clear();
        let env = AABB::from_point([x, y]);
        out.extend(
            self.tree
                .locate_in_envelope_intersecting(env)
                .map(|e| e.index),
        );
        out.sort_unstable();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::catalog::tests::sample_meta;
    use crate::store::LevelMeta;

    #[test]
    fn output_grid_snaps_to_the_anchor_lattice() {
        let g = OutputGrid::covering([10.2, 20.1, 30.9, 40.0], 0.5, (0.25, 0.0));
        assert_eq!(g.geotransform.0, [10.25 - 0.5, 0.5, 0.0, 40.0, 0.0, -0.5]);
        assert_eq!(g.width, ((31.25 - 9.75) / 0.5) as u64);
        assert_eq!(g.height, 40);
        // exact bounds do not grow
        let g = OutputGrid::covering([0.0, 0.0, 10.0, 5.0], 0.5, (0.0, 0.0));
        assert_eq!((g.width, g.height), (20, 10));
    }

    #[test]
    fn level_follows_the_requested_cell() {
        let mut m = sample_meta("a");
        m.levels = (0..4)
            .map(|k| LevelMeta {
                width: 1000 >> k,
                height: 600 >> k,
                chunk: 512,
            })
            .collect();
        assert_eq!(level_for(&m, 0.5), 0);
        assert_eq!(level_for(&m, 0.9), 0);
        assert_eq!(level_for(&m, 1.0), 1);
        assert_eq!(level_for(&m, 3.0), 2);
        assert_eq!(level_for(&m, 100.0), 3);
    }
}
