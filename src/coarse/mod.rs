//! Global initial search before ICP: where is the moving DSM, horizontally and
//! vertically, within ±`max_displacement_m`, without a starting guess?
//!
//! ICP only converges from inside its basin (a few times its outlier threshold).
//! Real collections arrive with offsets of hundreds of metres horizontally (a
//! 30 m DSM shifted by tens of pixels) and vertically (ellipsoidal against
//! orthometric heights). This module finds them first:
//!
//! 1. **Level.** The coarsest overview that still holds enough of the overlap
//!    (`min_side_px`) and on which the search radius is still a few pixels
//!    ([`search::search_level`]).
//! 2. **Scan.** Every shift of the reference's pixel lattice within
//!    ±`max_displacement_m` is scored by the spread of the height differences
//!    dh = H_ref(x + dx, y + dy) - h_moving over a lattice of moving samples:
//!    offset = median(dh), cost = RMS of dh - offset clipped at 3 NMAD ([`cost`]). The spread does not see
//!    the vertical offset, so no vertical search is needed, and it ignores up to
//!    half the overlap being water, change or outliers. Exhaustive: a few
//!    thousand shifts of a few thousand samples at that level, each sample's
//!    bilinear cell computed once ([`lattice`]).
//! 3. **Candidates.** The distinct local minima of the cost map, best first
//!    (at most `candidates`), are each refined level by level down to
//!    `finest_level` (±2 pixels at each level, a parabola at the last), on
//!    samples from the candidate's own overlap.
//! 4. **Ranking.** Refined candidates are ranked by cost; `ambiguity` is the
//!    ratio of the two best costs (near 1: a repetitive or flat scene where
//!    the two are hard to tell apart; 0: only one candidate).
//!
//! Rotation is not searched (DSM rotations are hundredths of a degree); ICP
//! takes it from the returned translation. The answer is a translation in the
//! ICP's convention: p_ref = p_moving + `shift_m`.

pub mod cost;
pub mod lattice;
pub mod search;

use nalgebra::Vector3;
use serde::Serialize;

use crate::grid::{Grid, Pyramid};
use cost::sample_box;
use search::{minima, refine, scan, search_level, window, Trial};

/// Settings of the coarse search.
#[derive(Clone, Debug)]
pub struct CoarseConfig {
    /// Horizontal search radius (metres, per axis).
    pub max_displacement_m: f64,
    /// Local minima of the scan refined and reported.
    pub candidates: usize,
    /// Moving samples per level (a regular lattice over the overlap); the
    /// global scan takes fewer (not below 1024) when it has many shifts.
    pub samples: usize,
    /// The search level's overlap box must span at least this many pixels.
    pub min_side_px: f64,
    /// Refine the candidates down to this level (0 = full resolution).
    pub finest_level: usize,
    /// Refinement levels sample a central window of at most this many pixels
    /// per side (bounded reads on huge DSMs).
    pub refine_window_px: f64,
}

impl Default for CoarseConfig {
    fn default() -> Self {
        CoarseConfig {
            max_displacement_m: 100.0,
            candidates: 4,
            samples: 4096,
            min_side_px: 32.0,
            finest_level: 0,
            refine_window_px: 768.0,
        }
    }
}

/// One candidate position, refined to `CoarseEstimate::refined_level`.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Candidate {
    /// p_ref = p_moving + shift_m (x, y, z in CRS metres).
    pub shift_m: [f64; 3],
    /// Robust spread of the height differences at this shift, metres
    /// ([`cost::ShiftScore::cost_m`]).
    pub cost_m: f64,
    /// Samples with a reference height under them at this shift.
    pub support: usize,
}

/// The outcome of the coarse search.
#[derive(Clone, Debug, Serialize)]
pub struct CoarseEstimate {
    /// The best candidate's translation, moving -> reference.
    #[serde(serialize_with = "vector_as_array")]
    pub shift_m: Vector3<f64>,
    /// All refined candidates, best (lowest cost) first.
    pub candidates: Vec<Candidate>,
    /// best cost / second-best cost, in [0, 1]; 0 with a single candidate.
    pub ambiguity: f64,
    /// The overview level of the global scan.
    pub level: usize,
    /// The level the candidates were refined to.
    pub refined_level: usize,
    /// Trial shifts scored in all.
    pub trials: usize,
}

fn vector_as_array<S: serde::Serializer>(v: &Vector3<f64>, s: S) -> Result<S::Ok, S::Error> {
    use serde::Serialize as _;
    [v.x, v.y, v.z].serialize(s)
}

/// Why the search found nothing.
#[derive(Debug, thiserror::Error)]
pub enum CoarseError {
    #[error("the two DSMs do not overlap, even {0} m apart")]
    NoOverlap(f64),
    #[error("no valid pixels of the moving DSM within reach of the reference")]
    EmptyOverlap,
    #[error("no shift within ±{0} m leaves enough valid overlap")]
    NoMatch(f64),
    #[error("reading the DSM failed: {0}")]
    Read(#[from] crate::grid::GridError),
}

/// Finds the translation of `moving` onto `reference` (module docs).
pub fn estimate<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &CoarseConfig,
) -> Result<CoarseEstimate, CoarseError> {
    let read = CoarseError::Read;
    let d_m = config.max_displacement_m;
    let levels = reference.num_levels().min(moving.num_levels()).max(1);
    let ref_box = footprint(&reference.open_level(0).map_err(read)?);
    let mov_box = footprint(&moving.open_level(0).map_err(read)?);
    let reach = intersect(&mov_box, &expand(&ref_box, d_m)).ok_or(CoarseError::NoOverlap(d_m))?;
    let mut pixel_m = Vec::with_capacity(levels);
    let mut side_px = Vec::with_capacity(levels);
    for l in 0..levels {
        let g = reference.open_level(l).map_err(read)?.geotransform();
        let h = moving.open_level(l).map_err(read)?.geotransform();
        let p = g.pixel_m().max(h.pixel_m());
        pixel_m.push(p);
        side_px.push((reach[2] - reach[0]).min(reach[3] - reach[1]) / p);
    }
    let level = search_level(&pixel_m, &side_px, d_m, config.min_side_px);
    let finest = config.finest_level.min(level);

    let (peaks, scanned) = global_scan(reference, moving, level, &reach, config)?;
    let mut n_trials = scanned;
    // Refine every candidate down to `finest`.
    let mut refined = Vec::with_capacity(peaks.len());
    for peak in peaks {
        let (t, n) = refine_down(
            reference, moving, peak, level, finest, &ref_box, &mov_box, config,
        )?;
        n_trials += n;
        refined.push(t);
    }
    let candidates = rank(refined, pixel_m[finest]);
    let best = *candidates.first().ok_or(CoarseError::NoMatch(d_m))?;
    let ambiguity = match candidates.get(1) {
        Some(second) if second.cost_m > 0.0 => best.cost_m / second.cost_m,
        Some(_) => 1.0,
        None => 0.0,
    };
    Ok(CoarseEstimate {
        shift_m: Vector3::from(best.shift_m),
        candidates,
        ambiguity,
        level,
        refined_level: finest,
        trials: n_trials,
    })
}

/// Refined trials ranked by cost, without duplicates (two within 1.5 steps of
/// the finest level are one candidate) or trials that lost their support.
fn rank(mut refined: Vec<Trial>, final_step: f64) -> Vec<Candidate> {
    refined.sort_by(|a, b| a.score.cost_m.total_cmp(&b.score.cost_m));
    let mut candidates: Vec<Candidate> = Vec::new();
    for t in refined.iter().filter(|t| t.score.cost_m.is_finite()) {
        let duplicate = candidates.iter().any(|c| {
            (c.shift_m[0] - t.shift_xy_m[0]).abs() < 1.5 * final_step
                && (c.shift_m[1] - t.shift_xy_m[1]).abs() < 1.5 * final_step
        });
        if !duplicate {
            candidates.push(Candidate {
                shift_m: [t.shift_xy_m[0], t.shift_xy_m[1], t.score.dz_m],
                cost_m: t.score.cost_m,
                support: t.score.support,
            });
        }
    }
    candidates
}

/// The exhaustive scan on `level` over the moving samples of `reach`: the
/// distinct minima of the cost map, best first, and the number of shifts scored.
fn global_scan<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    level: usize,
    reach: &[f64; 4],
    config: &CoarseConfig,
) -> Result<(Vec<Trial>, usize), CoarseError> {
    let read = CoarseError::Read;
    let d_m = config.max_displacement_m;
    let mut ref_level = reference.open_level(level).map_err(read)?;
    let gt = ref_level.geotransform();
    let step = [gt.gsd_x(), gt.gsd_y()];
    let radius_px = (d_m / step[0].min(step[1])).ceil() as i64;
    // Bound the work: about SCAN_LOOKUPS height look-ups in all.
    let shifts = ((2 * radius_px + 1) * (2 * radius_px + 1)) as usize;
    let target = (SCAN_LOOKUPS / shifts).clamp(1024, config.samples.max(1024));
    let mut mov = moving.open_level(level).map_err(read)?;
    let samples = sample_box(&mut mov, reach, target);
    if let Some(e) = mov.take_error() {
        return Err(read(e));
    }
    if samples.len() < 16 {
        return Err(CoarseError::EmptyOverlap);
    }
    let margin = d_m + 2.0 * step[0].max(step[1]);
    let mut ref_win = window(&mut ref_level, &expand(reach, margin));
    if let Some(e) = ref_level.take_error() {
        return Err(read(e));
    }
    let mut scratch = Vec::new();
    let at_zero = cost::score_shift(&mut ref_win, &samples, [0.0, 0.0], 0, &mut scratch);
    // a shift must keep half the overlap the georeferenced position has
    let min_support = 16.max(at_zero.support / 2).min(samples.len() / 2);
    let trials = scan(&ref_win, &samples, radius_px, min_support);
    let peaks = minima(&trials, radius_px, 2, config.candidates.max(1));
    if peaks.is_empty() {
        return Err(CoarseError::NoMatch(d_m));
    }
    tracing::debug!(
        level,
        radius_px,
        samples = samples.len(),
        peaks = peaks.len(),
        "coarse scan done"
    );
    Ok((peaks, trials.len()))
}

/// Height look-ups of the global scan (shifts x samples), about 0.1 s.
const SCAN_LOOKUPS: usize = 4_000_000;

/// Refines one scan minimum from `level - 1` down to `finest`; returns the
/// refined trial and the number of shifts scored.
#[allow(clippy::too_many_arguments)]
fn refine_down<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    peak: Trial,
    level: usize,
    finest: usize,
    ref_box: &[f64; 4],
    mov_box: &[f64; 4],
    config: &CoarseConfig,
) -> Result<(Trial, usize), CoarseError> {
    let read = CoarseError::Read;
    let mut best = peak;
    let mut scored = 0;
    for l in (finest..level).rev() {
        let mut mov = moving.open_level(l).map_err(read)?;
        let mut refg = reference.open_level(l).map_err(read)?;
        let gt = refg.geotransform();
        let step = [gt.gsd_x(), gt.gsd_y()];
        // The candidate's own overlap: moving pixels whose shifted position is
        // on the reference, a central window of it on fine levels.
        let shifted_ref = [
            ref_box[0] - best.shift_xy_m[0],
            ref_box[1] - best.shift_xy_m[1],
            ref_box[2] - best.shift_xy_m[0],
            ref_box[3] - best.shift_xy_m[1],
        ];
        let Some(overlap) = intersect(mov_box, &shifted_ref) else {
            break;
        };
        let side_m = config.refine_window_px * step[0].max(step[1]);
        let samples = sample_box(&mut mov, &central(&overlap, side_m), config.samples);
        if let Some(e) = mov.take_error() {
            return Err(read(e));
        }
        if samples.len() < 16 {
            break;
        }
        let min_support = 16.max(samples.len() / 8);
        let next = refine(
            &mut refg,
            &samples,
            best.shift_xy_m,
            step,
            min_support,
            l == finest,
        );
        if let Some(e) = refg.take_error() {
            return Err(read(e));
        }
        scored += 26;
        if !next.score.cost_m.is_finite() {
            break;
        }
        best = next;
    }
    Ok((best, scored))
}

/// [min_x, min_y, max_x, max_y] of a grid in CRS metres.
fn footprint<G: Grid>(g: &G) -> [f64; 4] {
    g.geotransform().bounds(g.width() as u64, g.height() as u64)
}

fn intersect(a: &[f64; 4], b: &[f64; 4]) -> Option<[f64; 4]> {
    let r = [
        a[0].max(b[0]),
        a[1].max(b[1]),
        a[2].min(b[2]),
        a[3].min(b[3]),
    ];
    (r[0] < r[2] && r[1] < r[3]).then_some(r)
}

fn expand(b: &[f64; 4], d_m: f64) -> [f64; 4] {
    [b[0] - d_m, b[1] - d_m, b[2] + d_m, b[3] + d_m]
}

/// The central part of `b`, at most `side_m` per side.
fn central(b: &[f64; 4], side_m: f64) -> [f64; 4] {
    let (cx, cy) = ((b[0] + b[2]) / 2.0, (b[1] + b[3]) / 2.0);
    let (hw, hh) = (
        ((b[2] - b[0]) / 2.0).min(side_m / 2.0),
        ((b[3] - b[1]) / 2.0).min(side_m / 2.0),
    );
    [cx - hw, cy - hh, cx + hw, cy + hh]
}

#[cfg(test)]
mod tests;
