//! Pair planning: which DSMs overlap, by how much, and in which order to
//! register them.
//!
//! Footprints go into an R-tree, so candidate pairs cost O(N log N). The overlap
//! score s_ij is measured on an overview level (about `OVERLAP_LEVEL_PX` pixels
//! on the long side): the fraction of the smaller DSM's valid pixels that land on
//! valid pixels of the other. Pairs come out ordered along a Morton curve of the
//! DSM centres, so DSMs that share pairs are processed close in time and their
//! chunks stay in the cache.

use rstar::{RTree, RTreeObject, AABB};

use crate::geo::Bounds;
use crate::grid::Grid;

/// Long side, in pixels, of the overview used to score overlaps.
pub const OVERLAP_LEVEL_PX: u64 = 512;

/// One DSM as the planner sees it.
/// Also the entry of every footprint R-tree (plan, fuse, eval).
#[derive(Clone, Debug)]
pub struct Footprint {
    pub index: usize,
    /// The DSM's box in CRS units.
    pub bounds: Bounds,
}

impl RTreeObject for Footprint {
    type Envelope = AABB<[f64; 2]>;
    fn envelope(&self) -> Self::Envelope {
        let b = &self.bounds;
        AABB::from_corners([b.min_x, b.min_y], [b.max_x, b.max_y])
    }
}

/// A pair to register: `reference` < `moving` by index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlannedPair {
    pub reference: usize,
    pub moving: usize,
    /// s_ij in [0, 1].
    pub overlap: f64,
}

/// Candidate pairs whose footprints intersect with positive area, as (i, j), i < j,
/// in Morton order of the DSM centres.
pub fn candidate_pairs(footprints: &[Footprint]) -> Vec<(usize, usize)> {
    let tree = RTree::bulk_load(footprints.to_vec());
    let rank = morton_ranks(footprints);
    let mut pairs = Vec::new();
    for f in footprints {
        for other in tree.locate_in_envelope_intersecting(f.envelope()) {
            if other.index > f.index && f.bounds.overlaps(&other.bounds) {
                pairs.push((f.index, other.index));
            }
        }
    }
    pairs.sort_by_key(|&(i, j)| {
        let (a, b) = (rank[i].min(rank[j]), rank[i].max(rank[j]));
        (a, b, i, j)
    });
    pairs
}

/// Rank of each DSM along a Morton (Z-order) curve of footprint centres.
fn morton_ranks(footprints: &[Footprint]) -> Vec<usize> {
    let n = footprints.iter().map(|f| f.index + 1).max().unwrap_or(0);
    if footprints.is_empty() {
        return Vec::new();
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for f in footprints {
        let (x, y) = f.bounds.centre();
        let c = [x, y];
        for k in 0..2 {
            lo[k] = lo[k].min(c[k]);
            hi[k] = hi[k].max(c[k]);
        }
    }
    let mut keyed: Vec<(u64, usize)> = footprints
        .iter()
        .map(|f| {
            let (x, y) = f.bounds.centre();
            let c = [x, y];
            let q = |k: usize| (((c[k] - lo[k]) / (hi[k] - lo[k]).max(1e-9)) * 65535.0) as u32;
            (interleave(q(0)) | (interleave(q(1)) << 1), f.index)
        })
        .collect();
    keyed.sort();
    let mut rank = vec![0; n];
    for (r, (_, index)) in keyed.into_iter().enumerate() {
        rank[index] = r;
    }
    rank
}

fn interleave(v: u32) -> u64 {
    let mut x = v as u64 & 0xFFFF;
    x = (x | (x << 8)) & 0x00FF_00FF;
    x = (x | (x << 4)) & 0x0F0F_0F0F;
    x = (x | (x << 2)) & 0x3333_3333;
    x = (x | (x << 1)) & 0x5555_5555;
    x
}

/// The overview level of a DSM closest to `OVERLAP_LEVEL_PX` on its long side.
pub fn scoring_level(level_sizes: &[(u64, u64)]) -> usize {
    level_sizes
        .iter()
        .position(|&(w, h)| w.max(h) <= OVERLAP_LEVEL_PX)
        .unwrap_or(level_sizes.len().saturating_sub(1))
}

/// s_ij: valid pixels of `a` that land on valid pixels of `b`, over the valid
/// pixels of the smaller of the two (each counted inside the other's bounds too,
/// so a small DSM fully covered scores 1).
pub fn overlap_score<A: Grid + ?Sized, B: Grid + ?Sized>(a: &mut A, b: &mut B) -> f64 {
    let (both, valid_a) = covered(a, b);
    let (_, valid_b) = covered(b, a);
    let smaller = valid_a.min(valid_b);
    if smaller == 0 {
        return 0.0;
    }
    (both as f64 / smaller as f64).min(1.0)
}

/// (valid pixels of `a` on valid pixels of `b`, valid pixels of `a`).
fn covered<A: Grid + ?Sized, B: Grid + ?Sized>(a: &mut A, b: &mut B) -> (u64, u64) {
    let (gta, gtb) = (a.geotransform(), b.geotransform());
    let (mut both, mut valid) = (0u64, 0u64);
    for row in 0..a.height() {
        for col in 0..a.width() {
            if a.get(col, row).is_nan() {
                continue;
            }
            valid += 1;
            let (x, y) = gta.pixel_to_world(col as f64 + 0.5, row as f64 + 0.5);
            let (cb, rb) = gtb.world_to_pixel(x, y);
            if !b.get(cb.floor() as i64, rb.floor() as i64).is_nan() {
                both += 1;
            }
        }
    }
    (both, valid)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::GeoTransform;
    use crate::grid::MemGrid;

    fn fp(index: usize, x0: f64, y0: f64, size: f64) -> Footprint {
        Footprint {
            index,
            bounds: Bounds::from([x0, y0, x0 + size, y0 + size]),
        }
    }

    #[test]
    fn pairs_of_a_grid_of_tiles() {
        // 3 x 3 tiles of 100 m overlapping by 40 m: 12 edge neighbours + 8 diagonals
        let mut f = Vec::new();
        for r in 0..3 {
            for c in 0..3 {
                f.push(fp(r * 3 + c, c as f64 * 60.0, r as f64 * 60.0, 100.0));
            }
        }
        let pairs = candidate_pairs(&f);
        assert_eq!(pairs.len(), 20);
        assert!(pairs.iter().all(|&(i, j)| i < j));
        // touching edges only (zero area) are not pairs
        let g = vec![fp(0, 0.0, 0.0, 10.0), fp(1, 10.0, 0.0, 10.0)];
        assert!(candidate_pairs(&g).is_empty());
    }

    #[test]
    fn overlap_score_of_half_overlapping_tiles() {
        let a = MemGrid::from_fn(
            10,
            10,
            GeoTransform::north_up(0.0, 10.0, 1.0, 1.0),
            |_, _| 1.0,
        );
        let b = MemGrid::from_fn(
            10,
            10,
            GeoTransform::north_up(5.0, 10.0, 1.0, 1.0),
            |c, _| if c < 8 { 1.0 } else { f32::NAN },
        );
        let s = overlap_score(&mut a.clone(), &mut b.clone());
        // b has 80 valid pixels, 50 of them over a
        assert!((s - 50.0 / 80.0).abs() < 1e-12, "{s}");
        assert_eq!(s, overlap_score(&mut b.clone(), &mut a.clone()));
    }
}
