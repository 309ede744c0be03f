//! The objects standing on the synthetic terrain: buildings (rectangles,
//! rotated rectangles, L-shapes; flat or gabled roofs; 3-60 m), trees (smooth
//! domes of 5-20 m) and the "changed" buildings that exist only in some tiles.
//!
//! The world is cut into square cells (`CELL_M`); every cell draws its own
//! objects from a hash of (seed, cell), and each object lies wholly inside its
//! cell, so the height at a point needs only that point's cell: O(1).

use crate::rng::{hash2, SplitMix64};

/// Edge of an object cell in metres (a city block).
pub const CELL_M: f64 = 64.0;
/// Clear margin kept between objects and the cell border (streets), metres.
const MARGIN_M: f64 = 3.0;

/// An axis-aligned rectangle in a building's local frame.
#[derive(Clone, Copy, Debug)]
struct Part {
    cu: f64,
    cv: f64,
    half_u: f64,
    half_v: f64,
}

/// A building: one or two rectangular parts in a rotated local frame.
#[derive(Clone, Debug)]
pub struct Building {
    cx: f64,
    cy: f64,
    cos: f64,
    sin: f64,
    parts: [Part; 2],
    n_parts: usize,
    /// Ground elevation the building stands on (terrain at its centre).
    pub base_m: f64,
    /// Eave height above `base_m`.
    height_m: f64,
    /// Gable rise above the eave (0 = flat roof).
    gable_rise_m: f64,
}

impl Building {
    /// Absolute roof height at (x, y), or None outside the footprint.
    #[inline]
    pub fn roof_at(&self, x: f64, y: f64) -> Option<f64> {
        let (dx, dy) = (x - self.cx, y - self.cy);
        let u = self.cos * dx + self.sin * dy;
        let v = -self.sin * dx + self.cos * dy;
        let mut best: Option<f64> = None;
        for p in &self.parts[..self.n_parts] {
            let (du, dv) = ((u - p.cu).abs(), (v - p.cv).abs());
            if du <= p.half_u && dv <= p.half_v {
                // The ridge runs along the longer side of the part.
                let across = if p.half_u >= p.half_v {
                    dv / p.half_v
                } else {
                    du / p.half_u
                };
                let h = self.base_m + self.height_m + self.gable_rise_m * (1.0 - across);
                best = Some(best.map_or(h, |b: f64| b.max(h)));
            }
        }
        best
    }
}

/// A tree crown: a smooth dome of `height_m` above the ground.
#[derive(Clone, Copy, Debug)]
pub struct Tree {
    cx: f64,
    cy: f64,
    radius_m: f64,
    height_m: f64,
}

impl Tree {
    /// Crown height above the ground at (x, y), or None outside the crown.
    #[inline]
    pub fn crown_at(&self, x: f64, y: f64) -> Option<f64> {
        let d2 = ((x - self.cx).powi(2) + (y - self.cy).powi(2)) / (self.radius_m * self.radius_m);
        (d2 < 1.0).then(|| self.height_m * (1.0 - d2).powf(0.6))
    }
}

/// Densities of the object generator (fractions of cells).
#[derive(Clone, Copy, Debug, serde::Serialize, serde::Deserialize)]
pub struct ObjectParams {
    /// Fraction of cells with one or two buildings.
    pub building_cells: f64,
    /// Fraction of cells that are groves of trees.
    pub tree_cells: f64,
    /// Fraction of cells holding a building that appears only in some tiles.
    pub changed_cells: f64,
}

impl Default for ObjectParams {
    fn default() -> Self {
        ObjectParams {
            building_cells: 0.55,
            tree_cells: 0.25,
            changed_cells: 0.08,
        }
    }
}

/// Everything one cell holds.
#[derive(Clone, Debug, Default)]
pub struct Cell {
    pub buildings: Vec<Building>,
    pub trees: Vec<Tree>,
    /// A building present only in tiles whose hash says so (see `Surface`).
    pub changed: Option<Building>,
}

/// Draw the contents of cell (i, j); `ground` gives the terrain height.
pub fn generate_cell(
    seed: u64,
    i: i64,
    j: i64,
    params: &ObjectParams,
    ground: impl Fn(f64, f64) -> f64,
) -> Cell {
    let mut rng = SplitMix64::new(hash2(seed, i, j));
    let (x0, y0) = (i as f64 * CELL_M, j as f64 * CELL_M);
    let mut cell = Cell::default();
    let kind = rng.next_f64();
    if kind < params.building_cells {
        if rng.chance(0.4) {
            // Two buildings, one per half of the cell.
            let split_x = rng.chance(0.5);
            for k in 0..2 {
                let off = k as f64 * CELL_M / 2.0;
                let (bx0, by0, bx1, by1) = if split_x {
                    (x0 + off, y0, x0 + off + CELL_M / 2.0, y0 + CELL_M)
                } else {
                    (x0, y0 + off, x0 + CELL_M, y0 + off + CELL_M / 2.0)
                };
                cell.buildings
                    .push(random_building(&mut rng, [bx0, by0, bx1, by1], &ground));
            }
        } else {
            let b = random_building(&mut rng, [x0, y0, x0 + CELL_M, y0 + CELL_M], &ground);
            cell.buildings.push(b);
        }
        for _ in 0..rng.int(0, 2) {
            cell.trees.push(random_tree(&mut rng, x0, y0));
        }
    } else if kind < params.building_cells + params.tree_cells {
        for _ in 0..rng.int(2, 9) {
            cell.trees.push(random_tree(&mut rng, x0, y0));
        }
    }
    if rng.chance(params.changed_cells) {
        let b = random_building(&mut rng, [x0, y0, x0 + CELL_M, y0 + CELL_M], &ground);
        cell.changed = Some(b);
    }
    cell
}

fn random_tree(rng: &mut SplitMix64, x0: f64, y0: f64) -> Tree {
    let radius_m = rng.range(2.0, 6.0);
    let lo = MARGIN_M + radius_m;
    Tree {
        cx: x0 + rng.range(lo, CELL_M - lo),
        cy: y0 + rng.range(lo, CELL_M - lo),
        radius_m,
        height_m: rng.range(5.0, 20.0),
    }
}

/// A building inside the box [x0, y0, x1, y1] (minus the street margin).
fn random_building(
    rng: &mut SplitMix64,
    bbox: [f64; 4],
    ground: &impl Fn(f64, f64) -> f64,
) -> Building {
    let room_u = (bbox[2] - bbox[0]) / 2.0 - MARGIN_M;
    let room_v = (bbox[3] - bbox[1]) / 2.0 - MARGIN_M;
    let shape = rng.next_f64();
    let angle = if shape < 0.45 {
        0.0
    } else if shape < 0.7 {
        rng.range(-0.8, 0.8) // rotated rectangle, up to ~45 degrees
    } else {
        rng.range(-0.3, 0.3) // L-shape, slightly rotated
    };
    let (sin, cos) = f64::sin_cos(angle);
    let mut parts = [Part {
        cu: 0.0,
        cv: 0.0,
        half_u: rng.range(6.0, 24.0),
        half_v: rng.range(5.0, 20.0),
    }; 2];
    let mut n_parts = 1;
    if shape >= 0.7 {
        // L: a wing sharing the main part's left edge, reaching below it.
        let a = parts[0];
        let wing_half_u = rng.range(3.0, a.half_u.max(3.5));
        let wing_half_v = rng.range(a.half_v * 0.8, a.half_v * 1.6);
        parts[1] = Part {
            cu: a.cu - a.half_u + wing_half_u,
            cv: a.cv - wing_half_v, // from the main part's middle to below it
            half_u: wing_half_u,
            half_v: wing_half_v,
        };
        n_parts = 2;
    }
    // Local bounding box of the parts, then recentre on it.
    let (mut u0, mut u1, mut v0, mut v1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in &parts[..n_parts] {
        u0 = u0.min(p.cu - p.half_u);
        u1 = u1.max(p.cu + p.half_u);
        v0 = v0.min(p.cv - p.half_v);
        v1 = v1.max(p.cv + p.half_v);
    }
    let (mu, mv) = ((u0 + u1) / 2.0, (v0 + v1) / 2.0);
    let (mut hu, mut hv) = ((u1 - u0) / 2.0, (v1 - v0) / 2.0);
    // Extent of the rotated box along x and y; shrink everything to fit the room.
    let ext_x = cos.abs() * hu + sin.abs() * hv;
    let ext_y = sin.abs() * hu + cos.abs() * hv;
    let scale = (room_u / ext_x).min(room_v / ext_y).min(1.0);
    for p in &mut parts[..n_parts] {
        p.cu = (p.cu - mu) * scale;
        p.cv = (p.cv - mv) * scale;
        p.half_u *= scale;
        p.half_v *= scale;
    }
    hu *= scale;
    hv *= scale;
    let ext_x = cos.abs() * hu + sin.abs() * hv;
    let ext_y = sin.abs() * hu + cos.abs() * hv;
    let cx = rng.range(
        bbox[0] + MARGIN_M + ext_x,
        bbox[2] - MARGIN_M - ext_x + 1e-9,
    );
    let cy = rng.range(
        bbox[1] + MARGIN_M + ext_y,
        bbox[3] - MARGIN_M - ext_y + 1e-9,
    );
    // Mostly low-rise, a few towers: 3 m + 57 m * u^2.5.
    let height_m = 3.0 + 57.0 * rng.next_f64().powf(2.5);
    let gable_rise_m = if height_m < 15.0 && rng.chance(0.5) {
        rng.range(1.5, 4.5)
    } else {
        0.0
    };
    Building {
        cx,
        cy,
        cos,
        sin,
        parts,
        n_parts,
        base_m: ground(cx, cy),
        height_m,
        gable_rise_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn objects_stay_inside_their_cell() {
        let params = ObjectParams::default();
        for (i, j) in [(0, 0), (7813, 75000), (-3, 12)] {
            let cell = generate_cell(99, i, j, &params, |_, _| 100.0);
            let (x0, y0) = (i as f64 * CELL_M, j as f64 * CELL_M);
            // Scan a ring just outside the cell border: nothing may stand there.
            for k in 0..400 {
                let s = k as f64 / 400.0 * CELL_M;
                for (x, y) in [
                    (x0 + s, y0 + 0.5),
                    (x0 + s, y0 + CELL_M - 0.5),
                    (x0 + 0.5, y0 + s),
                    (x0 + CELL_M - 0.5, y0 + s),
                ] {
                    assert!(cell.buildings.iter().all(|b| b.roof_at(x, y).is_none()));
                    assert!(cell.trees.iter().all(|t| t.crown_at(x, y).is_none()));
                }
            }
        }
    }

    #[test]
    fn roofs_are_within_height_range() {
        let params = ObjectParams {
            building_cells: 1.0,
            tree_cells: 0.0,
            changed_cells: 0.0,
        };
        let mut seen = 0;
        for i in 0..200 {
            let cell = generate_cell(5, i, 0, &params, |_, _| 0.0);
            for b in &cell.buildings {
                let h = b.roof_at(b.cx, b.cy);
                if let Some(h) = h {
                    assert!((3.0..=64.5).contains(&h), "roof {h}");
                    seen += 1;
                }
            }
        }
        assert!(seen > 150, "building centres mostly inside their footprint");
    }
}
