//! The steps of the coarse search: which overview level to search on, the
//! exhaustive scan of trial shifts there, the distinct minima of that cost
//! map, and the refinement of one minimum down the pyramid.

use super::cost::{score_shift, Sample, ShiftScore};
use super::lattice::LatticeSamples;
use crate::grid::{Grid, MemGrid};

/// A trial shift with its score (shift in CRS metres, moving -> reference).
#[derive(Clone, Copy, Debug)]
pub struct Trial {
    pub shift_xy_m: [f64; 2],
    pub score: ShiftScore,
}

/// Smallest search radius, in pixels of the search level, worth searching on:
/// coarser levels blur the terrain into a single blob.
const MIN_RADIUS_PX: f64 = 4.0;
/// Largest search radius in pixels of the search level (time bound:
/// (2 r + 1)^2 trial shifts).
const MAX_RADIUS_PX: f64 = 40.0;

/// The level of the global scan: the coarsest whose overlap box still spans
/// `min_side_px` pixels and on which the search radius spans at least
/// `MIN_RADIUS_PX` pixels; never so fine that it spans more than `MAX_RADIUS_PX`.
/// `pixel_m[l]` and `box_side_px[l]` describe level l (shortest side).
pub fn search_level(
    pixel_m: &[f64],
    box_side_px: &[f64],
    max_displacement_m: f64,
    min_side_px: f64,
) -> usize {
    let mut level = 0;
    for l in 1..pixel_m.len() {
        let holds_overlap = box_side_px[l] >= min_side_px;
        let resolves_radius = max_displacement_m / pixel_m[l] >= MIN_RADIUS_PX;
        if holds_overlap && resolves_radius {
            level = l;
        }
    }
    while level + 1 < pixel_m.len() && max_displacement_m / pixel_m[level] > MAX_RADIUS_PX {
        level += 1;
    }
    level
}

/// Copies the part of `grid` covering `box_m` (CRS metres) into memory, so
/// that the thousands of trial shifts of the scan read a plain array.
pub fn window<G: Grid + ?Sized>(grid: &mut G, box_m: &[f64; 4]) -> MemGrid {
    let gt = grid.geotransform();
    let (ca, ra) = gt.world_to_pixel(box_m[0], box_m[3]);
    let (cb, rb) = gt.world_to_pixel(box_m[2], box_m[1]);
    let c0 = (ca.min(cb).floor() as i64 - 1).max(0);
    let c1 = (ca.max(cb).ceil() as i64 + 1).min(grid.width());
    let r0 = (ra.min(rb).floor() as i64 - 1).max(0);
    let r1 = (ra.max(rb).ceil() as i64 + 1).min(grid.height());
    let (w, h) = ((c1 - c0).max(0), (r1 - r0).max(0));
    let (x0, y0) = gt.pixel_to_world(c0 as f64, r0 as f64);
    let mut sub = gt;
    sub.0[0] = x0;
    sub.0[3] = y0;
    MemGrid::from_fn(w, h, sub, |c, r| grid.get(c0 + c, r0 + r))
}

/// The full scan of the in-memory `window`: every shift (i dx, j dy) by whole
/// pixels of the window, |i|, |j| <= radius_px, row-major over j then i.
pub fn scan(
    window: &MemGrid,
    samples: &[Sample],
    radius_px: i64,
    min_support: usize,
) -> Vec<Trial> {
    let gt = window.geotransform();
    let step_m = [gt.gsd_x(), gt.gsd_y()];
    let lattice = LatticeSamples::new(window, samples);
    let mut scratch = Vec::with_capacity(samples.len());
    let mut trials = Vec::with_capacity(((2 * radius_px + 1) * (2 * radius_px + 1)) as usize);
    for j in -radius_px..=radius_px {
        for i in -radius_px..=radius_px {
            trials.push(Trial {
                shift_xy_m: [i as f64 * step_m[0], j as f64 * step_m[1]],
                score: lattice.score(window, [i, j], min_support, &mut scratch),
            });
        }
    }
    trials
}

/// The distinct local minima of a (2 r + 1)^2 scan, best first: a trial no
/// higher than its 8 neighbours, at least `separation_px` away (Chebyshev)
/// from every better minimum kept. At most `keep` of them.
pub fn minima(trials: &[Trial], radius_px: i64, separation_px: i64, keep: usize) -> Vec<Trial> {
    let side = 2 * radius_px + 1;
    let cost = |i: i64, j: i64| -> f64 {
        if i < 0 || j < 0 || i >= side || j >= side {
            f64::INFINITY
        } else {
            trials[(j * side + i) as usize].score.cost_m
        }
    };
    let mut found: Vec<(i64, i64)> = Vec::new();
    for j in 0..side {
        for i in 0..side {
            let c = cost(i, j);
            if !c.is_finite() {
                continue;
            }
            let lowest = (-1..=1)
                .flat_map(|dj| (-1..=1).map(move |di| (di, dj)))
                .filter(|&(di, dj)| (di, dj) != (0, 0))
                .all(|(di, dj)| c <= cost(i + di, j + dj));
            if lowest {
                found.push((i, j));
            }
        }
    }
    found.sort_by(|a, b| cost(a.0, a.1).total_cmp(&cost(b.0, b.1)));
    let mut kept: Vec<(i64, i64)> = Vec::new();
    for (i, j) in found {
        let far = kept
            .iter()
            .all(|&(a, b)| (a - i).abs().max((b - j).abs()) >= separation_px);
        if far {
            kept.push((i, j));
        }
        if kept.len() == keep {
            break;
        }
    }
    kept.iter()
        .map(|&(i, j)| trials[(j * side + i) as usize])
        .collect()
}

/// One refinement step on a finer level: the best of the 5 x 5 shifts
/// `start + (i, j) step` (|i|, |j| <= 2); at `subpixel`, a parabola through the
/// best and its neighbours along each axis moves it by at most half a step.
pub fn refine<G: Grid + ?Sized>(
    reference: &mut G,
    samples: &[Sample],
    start_xy_m: [f64; 2],
    step_m: [f64; 2],
    min_support: usize,
    subpixel: bool,
) -> Trial {
    let mut scratch = Vec::with_capacity(samples.len());
    let mut score_at = |i: i64, j: i64| {
        let shift = [
            start_xy_m[0] + i as f64 * step_m[0],
            start_xy_m[1] + j as f64 * step_m[1],
        ];
        Trial {
            shift_xy_m: shift,
            score: score_shift(reference, samples, shift, min_support, &mut scratch),
        }
    };
    let mut grid = [[None::<Trial>; 5]; 5];
    let mut best = (0i64, 0i64);
    let mut best_cost = f64::INFINITY;
    for j in -2..=2 {
        for i in -2..=2 {
            let t = score_at(i, j);
            if t.score.cost_m < best_cost {
                best_cost = t.score.cost_m;
                best = (i, j);
            }
            grid[(j + 2) as usize][(i + 2) as usize] = Some(t);
        }
    }
    let at = |i: i64, j: i64| grid[(j + 2) as usize][(i + 2) as usize].expect("filled");
    let mut winner = at(best.0, best.1);
    if !subpixel || !best_cost.is_finite() {
        return winner;
    }
    let vertex = |minus: f64, centre: f64, plus: f64| -> f64 {
        let curvature = minus + plus - 2.0 * centre;
        if curvature.is_finite() && curvature > 0.0 {
            (0.5 * (minus - plus) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let (i, j) = best;
    let cost = |i: i64, j: i64| {
        if i.abs() > 2 || j.abs() > 2 {
            f64::NAN
        } else {
            at(i, j).score.cost_m
        }
    };
    let du = vertex(cost(i - 1, j), best_cost, cost(i + 1, j));
    let dv = vertex(cost(i, j - 1), best_cost, cost(i, j + 1));
    if du != 0.0 || dv != 0.0 {
        let shift = [
            winner.shift_xy_m[0] + du * step_m[0],
            winner.shift_xy_m[1] + dv * step_m[1],
        ];
        let score = score_shift(reference, samples, shift, min_support, &mut scratch);
        if score.cost_m <= winner.score.cost_m * 1.05 {
            winner = Trial {
                shift_xy_m: shift,
                score,
            };
        }
    }
    winner
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn search_level_holds_the_overlap_and_bounds_the_radius() {
        // 0.5 m pyramid of a 1024 px overlap, 50 m radius.
        let pixel: Vec<f64> = (0..6).map(|l| 0.5 * f64::powi(2.0, l)).collect();
        let side: Vec<f64> = (0..6).map(|l| 1024.0 / f64::powi(2.0, l)).collect();
        let l = search_level(&pixel, &side, 50.0, 48.0);
        assert_eq!(l, 4, "8 m pixels: 64 px overlap, radius 6 px");
        // A 1 km radius on 30 m pixels of a 600 px overlap: 240 m pixels would
        // leave 75 px and a radius of 4.2 px.
        let pixel: Vec<f64> = (0..4).map(|l| 30.0 * f64::powi(2.0, l)).collect();
        let side: Vec<f64> = (0..4).map(|l| 600.0 / f64::powi(2.0, l)).collect();
        assert_eq!(search_level(&pixel, &side, 1000.0, 48.0), 3);
        // A tiny overlap stays at full resolution, but a radius of 100 px forces coarser.
        let pixel = [1.0, 2.0, 4.0];
        let side = [40.0, 20.0, 10.0];
        assert_eq!(search_level(&pixel, &side, 100.0, 48.0), 2);
        assert_eq!(search_level(&pixel, &side, 10.0, 48.0), 0);
    }

    #[test]
    fn minima_are_distinct_and_ranked() {
        let r = 3;
        let side = 2 * r + 1;
        let mut trials = Vec::new();
        for j in -r..=r {
            for i in -r..=r {
                // Two basins: a deep one at (2, -1), a shallow one at (-2, 2).
                let a = ((i - 2) * (i - 2) + (j + 1) * (j + 1)) as f64;
                let b = 0.5 + ((i + 2) * (i + 2) + (j - 2) * (j - 2)) as f64;
                trials.push(Trial {
                    shift_xy_m: [i as f64, j as f64],
                    score: ShiftScore {
                        support: 100,
                        dz_m: 0.0,
                        nmad_m: a.min(b),
                        cost_m: a.min(b),
                    },
                });
            }
        }
        assert_eq!(trials.len() as i64, side * side);
        let m = minima(&trials, r, 2, 4);
        assert_eq!(m.len(), 2, "{m:?}");
        assert_eq!(m[0].shift_xy_m, [2.0, -1.0]);
        assert_eq!(m[1].shift_xy_m, [-2.0, 2.0]);
        assert_eq!(minima(&trials, r, 2, 1).len(), 1);
    }
}
