//! The synthetic world: a height function evaluated at any CRS point (x, y)
//! without materialising the scene. Terrain is a few octaves of value noise
//! (tens of metres of relief) around a base elevation; buildings and trees
//! come from per-cell draws ([`super::objects`]); lakes are no-data polygons
//! drawn per 512 m cell. Every query touches one object cell and one lake
//! cell, so a 20000 x 20000 DSM can be made tile by tile in bounded memory.
//!
//! `true_height` is the noise-free, change-free surface (the ground truth for
//! fuse); `height_in_epoch` adds the changed buildings present in one epoch
//! (one tile). Noise, outliers and voids are added per pixel by the tile cutter.

use serde::{Deserialize, Serialize};

use super::objects::{generate_cell, Cell, ObjectParams, CELL_M};
use crate::rng::{derive_seed, hash2, unit_f64, SplitMix64};

/// Edge of a lake cell in metres; at most one lake per cell, wholly inside it.
const LAKE_CELL_M: f64 = 512.0;

/// Terrain octaves: (wavelength m, amplitude m) before `relief_scale`.
const OCTAVES: [(f64, f64); 4] = [(900.0, 16.0), (320.0, 7.0), (110.0, 2.5), (37.0, 0.6)];

/// What the world looks like; stored in truth.json so it can be rebuilt.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct SurfaceParams {
    pub seed: u64,
    pub base_elevation_m: f64,
    /// Multiplies the terrain octave amplitudes (1.0: about +-25 m of relief).
    pub relief_scale: f64,
    /// Fraction of 512 m cells holding a lake (no-data polygon).
    pub lake_cells: f64,
    pub objects: ObjectParams,
    /// Lakes are flat water (the terrain height at the lake's centre, minus
    /// 1 m) instead of no-data.
    #[serde(default)]
    pub flat_water: bool,
}

impl Default for SurfaceParams {
    fn default() -> Self {
        SurfaceParams {
            seed: 0,
            base_elevation_m: 200.0,
            relief_scale: 1.0,
            lake_cells: 0.2,
            objects: ObjectParams::default(),
            flat_water: false,
        }
    }
}

/// A lake: a star-shaped polygon around its centre.
#[derive(Clone, Debug)]
struct Lake {
    cx: f64,
    cy: f64,
    r_max: f64,
    vertices: Vec<(f64, f64)>,
    /// Water level when lakes are flat water.
    level_m: f64,
}

impl Lake {
    fn contains(&self, x: f64, y: f64) -> bool {
        if (x - self.cx).powi(2) + (y - self.cy).powi(2) > self.r_max * self.r_max {
            return false;
        }
        // Even-odd ray casting.
        let mut inside = false;
        let n = self.vertices.len();
        for k in 0..n {
            let (xa, ya) = self.vertices[k];
            let (xb, yb) = self.vertices[(k + 1) % n];
            if (ya > y) != (yb > y) && x < xa + (y - ya) / (yb - ya) * (xb - xa) {
                inside = !inside;
            }
        }
        inside
    }
}

/// The world's height function (immutable, shared by threads).
#[derive(Clone, Debug)]
pub struct Surface {
    params: SurfaceParams,
    terrain_seeds: [u64; 4],
    object_seed: u64,
    lake_seed: u64,
    change_seed: u64,
}

impl Surface {
    pub fn new(params: SurfaceParams) -> Self {
        let s = params.seed;
        Surface {
            params,
            terrain_seeds: [0, 1, 2, 3].map(|k| derive_seed(s, 100 + k)),
            object_seed: derive_seed(s, 200),
            lake_seed: derive_seed(s, 300),
            change_seed: derive_seed(s, 400),
        }
    }

    pub fn params(&self) -> &SurfaceParams {
        &self.params
    }

    /// Bare-earth elevation (no objects, no lakes).
    pub fn terrain(&self, x: f64, y: f64) -> f64 {
        let mut h = self.params.base_elevation_m;
        for (k, (wavelength, amp)) in OCTAVES.iter().enumerate() {
            h += amp
                * self.params.relief_scale
                * value_noise(self.terrain_seeds[k], x / wavelength, y / wavelength);
        }
        h
    }

    /// Noise-free, change-free surface height; NaN on lakes.
    pub fn true_height(&self, x: f64, y: f64) -> f64 {
        self.sampler().true_height(x, y)
    }

    /// An evaluator with a small cache of cells (one per thread).
    pub fn sampler(&self) -> Sampler<'_> {
        Sampler {
            surface: self,
            cells: vec![None; 64],
            lakes: vec![None; 8],
        }
    }

    fn lake(&self, i: i64, j: i64) -> Option<Lake> {
        let mut rng = SplitMix64::new(hash2(self.lake_seed, i, j));
        if !rng.chance(self.params.lake_cells) {
            return None;
        }
        let r_max = rng.range(25.0, 90.0);
        let margin = 100.0;
        let cx = i as f64 * LAKE_CELL_M + rng.range(margin, LAKE_CELL_M - margin);
        let cy = j as f64 * LAKE_CELL_M + rng.range(margin, LAKE_CELL_M - margin);
        let n = rng.int(7, 11);
        let vertices = (0..n)
            .map(|k| {
                let a = (k as f64 + rng.range(-0.3, 0.3)) / n as f64 * std::f64::consts::TAU;
                let r = r_max * rng.range(0.6, 1.0);
                (cx + r * a.cos(), cy + r * a.sin())
            })
            .collect();
        Some(Lake {
            cx,
            cy,
            r_max,
            vertices,
            level_m: self.terrain(cx, cy) - 1.0,
        })
    }

    /// True when the changed building of cell (i, j) stands in `epoch`.
    fn change_present(&self, epoch: u64, i: i64, j: i64) -> bool {
        unit_f64(hash2(self.change_seed ^ epoch, i, j)) < 0.5
    }
}

/// Smooth value noise in [-1, 1]: hashed lattice values, quintic interpolation.
fn value_noise(seed: u64, x: f64, y: f64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (i, j) = (fx as i64, fy as i64);
    let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
    let (u, v) = (fade(x - fx), fade(y - fy));
    let at = |a: i64, b: i64| unit_f64(hash2(seed, a, b)) * 2.0 - 1.0;
    let top = at(i, j) * (1.0 - u) + at(i + 1, j) * u;
    let bottom = at(i, j + 1) * (1.0 - u) + at(i + 1, j + 1) * u;
    top * (1.0 - v) + bottom * v
}

type CellSlot = Option<(i64, i64, Cell)>;
type LakeSlot = Option<(i64, i64, Option<Lake>)>;

/// Evaluates a [`Surface`] with a direct-mapped cache of recently used cells.
pub struct Sampler<'a> {
    surface: &'a Surface,
    cells: Vec<CellSlot>,
    lakes: Vec<LakeSlot>,
}

impl Sampler<'_> {
    /// Noise-free, change-free height; NaN on lakes.
    pub fn true_height(&mut self, x: f64, y: f64) -> f64 {
        self.height(x, y, None)
    }

    /// Height as seen in `epoch` (a tile's change seed): the true surface plus
    /// the changed buildings standing in that epoch; NaN on lakes.
    pub fn height_in_epoch(&mut self, x: f64, y: f64, epoch: u64) -> f64 {
        self.height(x, y, Some(epoch))
    }

    fn height(&mut self, x: f64, y: f64, epoch: Option<u64>) -> f64 {
        if let Some(level_m) = self.on_lake(x, y) {
            return if self.surface.params.flat_water {
                level_m
            } else {
                f64::NAN
            };
        }
        let s = self.surface;
        let ground = s.terrain(x, y);
        let (i, j) = ((x / CELL_M).floor() as i64, (y / CELL_M).floor() as i64);
        let cell = self.cell(i, j);
        let mut h = ground;
        for b in &cell.buildings {
            if let Some(roof) = b.roof_at(x, y) {
                h = h.max(roof);
            }
        }
        for t in &cell.trees {
            if let Some(crown) = t.crown_at(x, y) {
                h = h.max(ground + crown);
            }
        }
        if let (Some(epoch), Some(b)) = (epoch, &cell.changed) {
            if let Some(roof) = b.roof_at(x, y) {
                if s.change_present(epoch, i, j) {
                    h = h.max(roof);
                }
            }
        }
        h
    }

    /// The water level of the lake at (x, y), if any.
    fn on_lake(&mut self, x: f64, y: f64) -> Option<f64> {
        let (i, j) = (
            (x / LAKE_CELL_M).floor() as i64,
            (y / LAKE_CELL_M).floor() as i64,
        );
        let slot = (hash2(0, i, j) % self.lakes.len() as u64) as usize;
        if !matches!(&self.lakes[slot], Some((a, b, _)) if *a == i && *b == j) {
            self.lakes[slot] = Some((i, j, self.surface.lake(i, j)));
        }
        let Some((_, _, lake)) = &self.lakes[slot] else {
            unreachable!("slot just filled")
        };
        lake.as_ref()
            .filter(|l| l.contains(x, y))
            .map(|l| l.level_m)
    }

    fn cell(&mut self, i: i64, j: i64) -> &Cell {
        let slot = (hash2(1, i, j) % self.cells.len() as u64) as usize;
        if !matches!(&self.cells[slot], Some((a, b, _)) if *a == i && *b == j) {
            let s = self.surface;
            let cell = generate_cell(s.object_seed, i, j, &s.params.objects, |x, y| {
                s.terrain(x, y)
            });
            self.cells[slot] = Some((i, j, cell));
        }
        match &self.cells[slot] {
            Some((_, _, cell)) => cell,
            None => unreachable!("slot just filled"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(seed: u64) -> SurfaceParams {
        SurfaceParams {
            seed,
            ..Default::default()
        }
    }

    #[test]
    fn surface_is_deterministic_and_cache_independent() {
        let a = Surface::new(params(11));
        let b = Surface::new(params(11));
        let c = Surface::new(params(12));
        let mut sa = a.sampler();
        let mut differs = 0;
        for k in 0..5000 {
            let (x, y) = (
                500_000.0 + (k as f64 * 7.31) % 900.0,
                4_800_000.0 - k as f64 * 0.77,
            );
            let (ha, hb) = (sa.true_height(x, y), b.true_height(x, y));
            assert!(
                ha.to_bits() == hb.to_bits(),
                "cached vs uncached at ({x},{y})"
            );
            let hc = c.true_height(x, y);
            if !(ha == hc || (ha.is_nan() && hc.is_nan())) {
                differs += 1;
            }
        }
        assert!(differs > 4500, "another seed gives another world");
    }

    #[test]
    fn scene_has_relief_buildings_trees_and_lakes() {
        let s = Surface::new(params(3));
        let mut sampler = s.sampler();
        let (mut lake, mut tall, mut n) = (0, 0, 0);
        let (mut lo, mut hi) = (f64::MAX, f64::MIN);
        for r in 0..400 {
            for c in 0..400 {
                let (x, y) = (500_000.0 + c as f64 * 10.0, 4_800_000.0 - r as f64 * 10.0);
                let h = sampler.true_height(x, y);
                let g = s.terrain(x, y);
                lo = lo.min(g);
                hi = hi.max(g);
                n += 1;
                if h.is_nan() {
                    lake += 1;
                } else if h - g > 2.5 {
                    tall += 1;
                }
            }
        }
        let (lake, tall) = (lake as f64 / n as f64, tall as f64 / n as f64);
        assert!(
            hi - lo > 15.0 && hi - lo < 80.0,
            "terrain relief {}",
            hi - lo
        );
        assert!(lake > 0.002 && lake < 0.15, "lake fraction {lake}");
        assert!(tall > 0.1 && tall < 0.6, "object fraction {tall}");
    }

    /// With `flat_water`, lakes are one level each instead of no-data.
    #[test]
    fn flat_water_lakes_are_level() {
        let nan_lakes = Surface::new(SurfaceParams {
            lake_cells: 1.0,
            ..params(6)
        });
        let flat = Surface::new(SurfaceParams {
            lake_cells: 1.0,
            flat_water: true,
            ..params(6)
        });
        let mut levels = Vec::new();
        for k in 0..40_000 {
            let (x, y) = (
                500_000.0 + (k % 200) as f64 * 10.0,
                4_800_000.0 - (k / 200) as f64 * 10.0,
            );
            if nan_lakes.true_height(x, y).is_nan() {
                levels.push(flat.true_height(x, y));
            } else {
                assert_eq!(nan_lakes.true_height(x, y), flat.true_height(x, y));
            }
        }
        assert!(levels.len() > 100, "some lake in view ({})", levels.len());
        assert!(levels.iter().all(|h| h.is_finite()));
        let mut distinct = levels.clone();
        distinct.sort_by(f64::total_cmp);
        distinct.dedup();
        // 2 km x 2 km hold at most 25 lake cells, one level each.
        assert!(distinct.len() <= 25, "one level per lake: {distinct:?}");
    }

    #[test]
    fn changed_buildings_differ_between_epochs_only() {
        let s = Surface::new(params(5));
        let mut sampler = s.sampler();
        let (mut diff_epochs, mut above_truth) = (0, 0);
        for r in 0..300 {
            for c in 0..300 {
                let (x, y) = (500_000.0 + c as f64 * 2.0, 4_800_000.0 - r as f64 * 2.0);
                let truth = sampler.true_height(x, y);
                let (e1, e2) = (
                    sampler.height_in_epoch(x, y, 1),
                    sampler.height_in_epoch(x, y, 2),
                );
                if truth.is_nan() {
                    assert!(e1.is_nan() && e2.is_nan());
                    continue;
                }
                assert!(e1 >= truth && e2 >= truth, "changes only add buildings");
                diff_epochs += usize::from(e1 != e2);
                above_truth += usize::from(e1 > truth);
            }
        }
        assert!(diff_epochs > 100, "epochs differ somewhere ({diff_epochs})");
        assert!(
            above_truth < 90_000 / 10,
            "changes are a small part ({above_truth})"
        );
    }
}
