//! Pairwise DSM-ICP (Xu & Qin 2024, Sec. 3.1), coarse to fine over the
//! overview levels.
//!
//! `register(reference, moving)` returns the rigid transform `m_world` that maps
//! points of the moving DSM (x, y, height in the CRS) onto the reference:
//! p_ref = m_world p_moving. Each level runs the classic loop on one screen:
//! associate (exact grid NN, outliers beyond tau dropped), weight (Tukey on the
//! residuals), fit (point-to-plane or Kabsch), check convergence. All math is in a
//! local frame centred on the overlap, in f64; the world matrix is formed at the end.

pub mod associate;
pub mod sample;

use nalgebra::{Isometry3, Matrix4, Translation3, Vector3};
use serde::Serialize;

use crate::fit::{point_to_plane, point_to_point, Correspondence, FitSigma, Model};
use crate::grid::{Grid, Pyramid};
use crate::nn::{NnStats, PixelFrame, PlaneMemo};
use associate::{associate, block_order, Association};
use sample::{pixel_window, sample_overlap};

/// How correspondences are turned into a motion.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Metric {
    /// Linearised point-to-plane with grid normals (sub-pixel horizontal accuracy).
    PointToPlane,
    /// Exact grid NN for outlier rejection, then the distance to the tangent
    /// plane of the bilinear reference surface right below the query.
    PointToSurface,
    /// The paper's point-to-point Kabsch fit (resolves only the pixel lattice horizontally).
    PointToPoint,
}

/// Settings of one pairwise registration.
#[derive(Clone, Debug)]
pub struct IcpConfig {
    pub model: Model,
    pub metric: Metric,
    /// Outlier threshold on the NN distance at full resolution (paper: 10 m).
    pub tau_m: f64,
    /// Query points sampled from the moving DSM.
    pub samples: usize,
    /// Iterations per level.
    pub max_iter: usize,
    /// Largest motion accepted; also caps the NN search radius at coarse levels.
    pub max_displacement_m: f64,
    pub seed: u64,
    /// Coarsest overview level used (coarse-to-fine starts there); 0 = full resolution only.
    pub max_level: usize,
    /// Point-to-surface only: skip places whose neighbourhood deviates from a
    /// plane by more than this RMS and more than 3x the median roughness (walls,
    /// tree crowns): their tangent plane is not the surface.
    pub max_roughness_m: f64,
    /// Converged when an update moves less than this (metres, at the overlap's edge).
    pub tolerance_m: f64,
}

impl Default for IcpConfig {
    fn default() -> Self {
        IcpConfig {
            model: Model::Rigid,
            metric: Metric::PointToSurface,
            tau_m: 10.0,
            samples: 200_000,
            max_iter: 40,
            max_displacement_m: 100.0,
            seed: 1,
            max_level: 3,
            tolerance_m: 1e-4,
            max_roughness_m: 1.0,
        }
    }
}

/// How a registration ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IcpStatus {
    Converged,
    /// Ran out of iterations while still moving (result may still be usable).
    MaxIterations,
    /// Some direction is not constrained by the surface (e.g. flat terrain).
    Degenerate,
    TooFewInliers,
    /// The error grew, or the motion exceeded the displacement cap.
    Diverged,
}

/// The outcome of one pairwise registration.
#[derive(Clone, Debug, Serialize)]
pub struct IcpResult {
    /// Maps moving-DSM points to the reference: p_ref = m_world p_moving.
    #[serde(serialize_with = "serialize_rows")]
    pub m_world: Matrix4<f64>,
    /// RMS nearest-neighbour distance of the inliers at the returned transform.
    pub rmse_m: f64,
    /// RMS point-to-plane residual of the inliers at the returned transform.
    pub rmse_plane_m: f64,
    pub inliers: usize,
    pub samples: usize,
    /// Fraction of samples with a valid reference pixel below them (s_ij estimate).
    pub overlap: f64,
    pub iterations: usize,
    pub status: IcpStatus,
    /// Smallest/largest eigenvalue of the normalised fit matrix (near 0 = degenerate).
    pub constraint_ratio: f64,
    /// Standard errors of the transform from the last fit (point-to-plane
    /// metrics; zero for point-to-point), in the local frame at the overlap.
    #[serde(default)]
    pub sigma: FitSigma,
    pub nn: NnStatsSummary,
}

#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct NnStatsSummary {
    pub queries: u64,
    pub pixels_visited: u64,
}

impl IcpResult {
    /// True when the transform can be used (converged, or stopped while still improving slightly).
    pub fn is_usable(&self) -> bool {
        matches!(self.status, IcpStatus::Converged | IcpStatus::MaxIterations)
    }
}

/// Errors that stop a registration before it starts.
#[derive(Debug, thiserror::Error)]
pub enum IcpError {
    #[error("the two DSMs do not overlap")]
    NoOverlap,
    #[error("no valid pixels in the overlap of the two DSMs")]
    EmptyOverlap,
    #[error("reading the DSM failed: {0}")]
    Read(String),
}

/// Constraint ratio below which a fit is called degenerate.
const DEGENERATE_RATIO: f64 = 1e-6;

/// Samples per iteration on the coarse levels and in the first phase of the
/// full-resolution level (see `run_level`).
const LADDER_SAMPLES: usize = 50_000;

/// Registers `moving` onto `reference` (see module docs).
pub fn register<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
) -> Result<IcpResult, IcpError> {
    let read = |e: String| IcpError::Read(e);
    let ref0 = reference.open_level(0).map_err(read)?;
    let mov0 = moving.open_level(0).map_err(read)?;
    let overlap_box = intersect(
        &ref0
            .geotransform()
            .bounds(ref0.width() as u64, ref0.height() as u64),
        &mov0
            .geotransform()
            .bounds(mov0.width() as u64, mov0.height() as u64),
    )
    .ok_or(IcpError::NoOverlap)?;
    let origin_xy = Vector3::new(
        (overlap_box[0] + overlap_box[2]) / 2.0,
        (overlap_box[1] + overlap_box[3]) / 2.0,
        0.0,
    );
    let start = start_level(reference, moving, &overlap_box, config.max_level);
    let mut origin: Option<Vector3<f64>> = None;
    let mut t_ref_moving = Isometry3::identity();
    let mut last: Option<LevelOutcome> = None;
    for level in (0..=start).rev() {
        let outcome = run_level(
            reference,
            moving,
            level,
            &overlap_box,
            &mut origin,
            origin_xy,
            t_ref_moving,
            config,
        )?;
        t_ref_moving = outcome.t_ref_moving;
        let bad = matches!(
            outcome.status,
            IcpStatus::TooFewInliers | IcpStatus::Diverged
        );
        last = Some(outcome);
        if bad {
            break;
        }
    }
    let outcome = last.expect("at least one level");
    let origin = origin.unwrap_or(origin_xy);
    let final_eval = &outcome.final_association;
    let t_local = outcome.t_ref_moving.to_homogeneous();
    let m_world = Translation3::from(origin).to_homogeneous()
        * t_local
        * Translation3::from(-origin).to_homogeneous();
    let rmse_m = rms(&final_eval.distances_m);
    let plane: Vec<f64> = final_eval
        .corrs
        .iter()
        .map(Correspondence::plane_residual_m)
        .collect();
    Ok(IcpResult {
        m_world,
        rmse_m,
        rmse_plane_m: rms(&plane),
        inliers: final_eval.corrs.len(),
        samples: final_eval.queries,
        overlap: final_eval.with_reference_below as f64 / final_eval.queries.max(1) as f64,
        iterations: outcome.iterations,
        status: outcome.status,
        constraint_ratio: outcome.constraint_ratio,
        sigma: outcome.sigma,
        nn: NnStatsSummary {
            queries: outcome.nn.queries,
            pixels_visited: outcome.nn.pixels_visited,
        },
    })
}

struct LevelOutcome {
    t_ref_moving: Isometry3<f64>,
    status: IcpStatus,
    iterations: usize,
    constraint_ratio: f64,
    sigma: FitSigma,
    final_association: Association,
    nn: NnStats,
}

/// One level of the coarse-to-fine loop.
#[allow(clippy::too_many_arguments)]
fn run_level<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    level: usize,
    overlap_box: &[f64; 4],
    origin: &mut Option<Vector3<f64>>,
    origin_xy: Vector3<f64>,
    mut t_ref_moving: Isometry3<f64>,
    config: &IcpConfig,
) -> Result<LevelOutcome, IcpError> {
    let read = |e: String| IcpError::Read(e);
    let mut mov = moving.open_level(level).map_err(read)?;
    let ref_gt = reference.open_level(level).map_err(read)?.geotransform();
    // Sample with a z origin of 0 (world heights), then fix the local frame's
    // height origin from the first level's samples (any fixed value works).
    let sample_frame = PixelFrame::new(&mov.geotransform(), &origin_xy);
    let mut samples = sample_overlap(
        &mut mov,
        &sample_frame,
        overlap_box,
        // coarse levels only bring the estimate near; their precision is not kept
        if level == 0 {
            config.samples
        } else {
            config.samples.min(LADDER_SAMPLES)
        },
        config.seed ^ level as u64,
    );
    if let Some(e) = mov.take_error() {
        return Err(IcpError::Read(e));
    }
    if samples.points.is_empty() {
        return Err(IcpError::EmptyOverlap);
    }
    let o = *origin.get_or_insert_with(|| {
        let mean_z = samples.points.iter().map(|p| p.z).sum::<f64>() / samples.points.len() as f64;
        Vector3::new(origin_xy.x, origin_xy.y, mean_z)
    });
    for p in &mut samples.points {
        p.z -= o.z;
    }
    let ref_frame = PixelFrame::new(&ref_gt, &o);
    let scale = (1u64 << level) as f64;
    let tau_m = (config.tau_m * scale).min(config.max_displacement_m.max(config.tau_m));
    block_order(&mut samples.points, &ref_frame, 256);
    let lever_m = half_diagonal(overlap_box);

    let mut nn = NnStats::default();
    let min_inliers = 30.max(samples.points.len() / 100);
    let match_at =
        |points: &[Vector3<f64>], memo: &mut [PlaneMemo], t: &Isometry3<f64>, nn: &mut NnStats| {
            let assoc = associate(
                reference,
                level,
                &ref_frame,
                points,
                memo,
                t,
                tau_m,
                config.metric,
            )
            .map_err(read)?;
            add_stats(nn, &assoc.nn);
            Ok::<_, IcpError>(assoc)
        };
    // Sample ladder: with many samples, converge on an even subset first (every
    // k-th point in chunk order), then refine on all of them; the final
    // iterations, and so the result, use every sample.
    let stride = samples.points.len().div_ceil(LADDER_SAMPLES);
    let subset: Vec<Vector3<f64>> = if stride >= 2 {
        samples.points.iter().step_by(stride).copied().collect()
    } else {
        Vec::new()
    };
    let mut full_memo = vec![PlaneMemo::default(); samples.points.len()];
    let mut subset_memo = vec![PlaneMemo::default(); subset.len()];
    let mut phases: Vec<(&[Vector3<f64>], &mut [PlaneMemo])> = Vec::new();
    if !subset.is_empty() {
        phases.push((&subset, &mut subset_memo));
    }
    phases.push((&samples.points, &mut full_memo));
    let mut phase = Phase::default();
    let mut iterations = 0;
    for (points, memo) in phases {
        let min_phase = 30.max(points.len() / 100);
        phase = iterate(t_ref_moving, min_phase, lever_m, scale, config, &mut |t| {
            match_at(points, memo, t, &mut nn)
        })?;
        t_ref_moving = phase.t_ref_moving;
        iterations += phase.iterations;
        if !matches!(
            phase.status,
            IcpStatus::Converged | IcpStatus::MaxIterations
        ) {
            break;
        }
    }
    let Phase {
        mut status,
        constraint_ratio,
        sigma,
        peak_inliers,
        ..
    } = phase;
    let final_association = match_at(&samples.points, &mut full_memo, &t_ref_moving, &mut nn)?;
    if status != IcpStatus::TooFewInliers && final_association.corrs.len() < min_inliers {
        status = IcpStatus::TooFewInliers;
    }
    // Diverged: the matches collapsed while the motion ran away (the peak is
    // over the last phase, which used the same points).
    if status != IcpStatus::TooFewInliers && final_association.corrs.len() * 2 < peak_inliers {
        status = IcpStatus::Diverged;
    }
    Ok(LevelOutcome {
        t_ref_moving,
        status,
        iterations,
        constraint_ratio,
        sigma,
        final_association,
        nn,
    })
}

/// Where one run of the classic loop over a fixed point set ended.
struct Phase {
    t_ref_moving: Isometry3<f64>,
    status: IcpStatus,
    iterations: usize,
    constraint_ratio: f64,
    sigma: FitSigma,
    peak_inliers: usize,
}

impl Default for Phase {
    fn default() -> Self {
        Phase {
            t_ref_moving: Isometry3::identity(),
            status: IcpStatus::MaxIterations,
            iterations: 0,
            constraint_ratio: 1.0,
            sigma: FitSigma::default(),
            peak_inliers: 0,
        }
    }
}

/// The classic loop on one point set (behind `match_at`): associate, weight, fit, until the update
/// is below the tolerance, the estimate stalls, or something breaks.
fn iterate(
    mut t_ref_moving: Isometry3<f64>,
    min_inliers: usize,
    lever_m: f64,
    scale: f64,
    config: &IcpConfig,
    match_at: &mut dyn FnMut(&Isometry3<f64>) -> Result<Association, IcpError>,
) -> Result<Phase, IcpError> {
    let mut phase = Phase {
        t_ref_moving,
        ..Phase::default()
    };
    let mut recent: Vec<Isometry3<f64>> = vec![t_ref_moving];
    for _ in 0..config.max_iter {
        phase.iterations += 1;
        let assoc = match_at(&t_ref_moving)?;
        if assoc.corrs.len() < min_inliers {
            phase.status = IcpStatus::TooFewInliers;
            break;
        }
        phase.peak_inliers = phase.peak_inliers.max(assoc.corrs.len());
        let corrs = weighted(
            smooth_only(assoc.corrs, &assoc.roughness_m, config.max_roughness_m),
            config.metric,
        );
        let (update, ratio) = match config.metric {
            Metric::PointToPlane | Metric::PointToSurface => {
                match point_to_plane(&corrs, config.model) {
                    Some(f) => {
                        phase.sigma = f.sigma;
                        (f.update, f.constraint_ratio)
                    }
                    None => (Isometry3::identity(), 0.0),
                }
            }
            Metric::PointToPoint => (
                point_to_point(&corrs, config.model).unwrap_or_else(Isometry3::identity),
                1.0,
            ),
        };
        phase.constraint_ratio = ratio;
        if ratio < DEGENERATE_RATIO {
            phase.status = IcpStatus::Degenerate;
            break;
        }
        t_ref_moving = update * t_ref_moving;
        phase.t_ref_moving = t_ref_moving;
        tracing::trace!(t = ?t_ref_moving.translation.vector, n = corrs.len(), "iteration");
        if t_ref_moving.translation.vector.norm() > config.max_displacement_m {
            phase.status = IcpStatus::Diverged;
            break;
        }
        let step_m = update.translation.vector.norm() + update.rotation.angle() * lever_m;
        recent.push(t_ref_moving);
        if step_m < config.tolerance_m * scale
            || stalled(&recent, lever_m, config.tolerance_m * scale)
        {
            phase.status = IcpStatus::Converged;
            break;
        }
    }
    Ok(phase)
}

/// At the noise floor the inlier set flips between iterations and the estimate
/// jitters without a trend: when the net motion over the last four iterations is
/// below 10 tolerances, the level is done (a slow drift keeps going).
fn stalled(estimates: &[Isometry3<f64>], lever_m: f64, tolerance_m: f64) -> bool {
    let n = estimates.len();
    if n < 5 {
        return false;
    }
    let net = estimates[n - 1] * estimates[n - 5].inverse();
    net.translation.vector.norm() + net.rotation.angle() * lever_m < 10.0 * tolerance_m
}

/// Drops correspondences on rough places: above both `floor_m` and 3x the
/// median roughness (so steep but smooth terrain at coarse GSD is kept).
fn smooth_only(
    corrs: Vec<Correspondence>,
    roughness_m: &[f64],
    floor_m: f64,
) -> Vec<Correspondence> {
    if roughness_m.len() != corrs.len() || corrs.is_empty() {
        return corrs;
    }
    let mut sorted = roughness_m.to_vec();
    let mid = sorted.len() / 2;
    let median = *sorted.select_nth_unstable_by(mid, f64::total_cmp).1;
    let limit = floor_m.max(3.0 * median);
    corrs
        .into_iter()
        .zip(roughness_m)
        .filter(|(_, &r)| r <= limit)
        .map(|(c, _)| c)
        .collect()
}

/// Tukey biweight on the residual, scale from the median absolute residual.
fn weighted(mut corrs: Vec<Correspondence>, metric: Metric) -> Vec<Correspondence> {
    let residual = |c: &Correspondence| match metric {
        Metric::PointToPlane | Metric::PointToSurface => c.plane_residual_m().abs(),
        Metric::PointToPoint => (c.moving - c.reference).norm(),
    };
    let mut abs: Vec<f64> = corrs.iter().map(residual).collect();
    let mid = abs.len() / 2;
    let median = *abs.select_nth_unstable_by(mid, f64::total_cmp).1;
    let c = 4.685 * (1.4826 * median).max(0.01);
    for corr in &mut corrs {
        let u = residual(corr) / c;
        corr.weight = if u < 1.0 { (1.0 - u * u).powi(2) } else { 0.0 };
    }
    corrs
}

/// The coarsest level whose overlap is still at least 64 px on its short side.
fn start_level<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    overlap_box: &[f64; 4],
    max_level: usize,
) -> usize {
    let levels = reference.num_levels().min(moving.num_levels());
    let mut best = 0;
    for level in 1..levels.min(max_level + 1) {
        let Ok(grid) = moving.open_level(level) else {
            break;
        };
        match pixel_window(&grid, overlap_box) {
            Some([c0, r0, c1, r1]) if (c1 - c0).min(r1 - r0) >= 64 => best = level,
            _ => break,
        }
    }
    best
}

/// Row-major 4x4, the poses.json convention.
pub fn matrix_rows(m: &Matrix4<f64>) -> [[f64; 4]; 4] {
    let mut rows = [[0.0; 4]; 4];
    for (r, row) in rows.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    rows
}

fn serialize_rows<S: serde::Serializer>(m: &Matrix4<f64>, s: S) -> Result<S::Ok, S::Error> {
    matrix_rows(m).serialize(s)
}

fn intersect(a: &[f64; 4], b: &[f64; 4]) -> Option<[f64; 4]> {
    let r = [
        a[0].max(b[0]),
        a[1].max(b[1]),
        a[2].min(b[2]),
        a[3].min(b[3]),
    ];
    (r[2] > r[0] && r[3] > r[1]).then_some(r)
}

fn half_diagonal(b: &[f64; 4]) -> f64 {
    0.5 * ((b[2] - b[0]).powi(2) + (b[3] - b[1]).powi(2)).sqrt()
}

fn rms(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
}

fn add_stats(total: &mut NnStats, s: &NnStats) {
    total.queries += s.queries;
    total.pixels_visited += s.pixels_visited;
    total.not_found += s.not_found;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{MemGrid, MemPyramid};
    use crate::raster::GeoTransform;
    use crate::rng::SplitMix64;
    use nalgebra::{Point3, UnitQuaternion};

    /// Terrain with box buildings of varied heights (walls give horizontal constraints).
    fn surface(x: f64, y: f64) -> f64 {
        let terrain = 5.0 * (x / 47.0).sin() + 3.0 * (y / 31.0).cos() + 0.01 * x;
        let (cx, cy) = ((x / 20.0).floor(), (y / 20.0).floor());
        let hash = ((cx * 73.0 + cy * 151.0).sin() * 43758.5453).fract().abs();
        let (fx, fy) = (x / 20.0 - cx, y / 20.0 - cy);
        let size = 0.3 + 0.4 * hash;
        if hash > 0.35 && fx > 0.2 && fx < 0.2 + size && fy > 0.15 && fy < 0.15 + size * 1.3 {
            terrain + 4.0 + 25.0 * hash
        } else {
            terrain
        }
    }

    /// A DSM of the surface as seen by a sensor whose data need `t_ref_moving`
    /// to be registered: pixel (x', y') holds h' with t_ref_moving (x', y', h') on the surface.
    fn dsm(
        left: f64,
        top: f64,
        size: i64,
        gsd: f64,
        t_ref_moving: &Isometry3<f64>,
        noise_m: f64,
        seed: u64,
    ) -> MemGrid {
        let gt = GeoTransform::north_up(left, top, gsd, gsd);
        let mut rng = SplitMix64::new(seed);
        MemGrid::from_fn(size, size, gt, |c, r| {
            let (x, y) = gt.pixel_to_world(c as f64 + 0.5, r as f64 + 0.5);
            let mut h = surface(x, y);
            for _ in 0..4 {
                let p = t_ref_moving.transform_point(&Point3::new(x, y, h));
                h += surface(p.x, p.y) - p.z;
            }
            let n = (rng.next_f64() + rng.next_f64() + rng.next_f64() - 1.5) * 2.0 * noise_m;
            if rng.next_f64() < 0.02 {
                return f32::NAN;
            }
            (h + n) as f32
        })
    }

    fn pose_error(m_est: &Matrix4<f64>, m_true: &Isometry3<f64>, at: Point3<f64>) -> (f64, f64) {
        let e = m_est.try_inverse().unwrap() * m_true.to_homogeneous();
        let p = e.transform_point(&at);
        let r = e.fixed_view::<3, 3>(0, 0).into_owned();
        let angle = ((r.trace() - 1.0) / 2.0)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        ((p - at).norm(), angle)
    }

    fn check_recovery(
        noise_m: f64,
        truth_local: Isometry3<f64>,
        config: &IcpConfig,
        tol_m: f64,
        tol_deg: f64,
    ) -> IcpResult {
        let centre = Point3::new(500_130.0, 4_800_100.0, 0.0);
        // truth about the overlap centre, expressed in world coordinates
        let to = Translation3::from(centre.coords);
        let truth = nalgebra::convert::<_, Isometry3<f64>>(to)
            * truth_local
            * nalgebra::convert::<_, Isometry3<f64>>(to.inverse());
        let reference = dsm(
            500_000.0,
            4_800_200.0,
            400,
            0.5,
            &Isometry3::identity(),
            noise_m,
            1,
        );
        let moving = dsm(500_060.0, 4_800_200.0, 400, 0.5, &truth, noise_m, 2);
        let (rp, mp) = (
            MemPyramid::build(reference, 64),
            MemPyramid::build(moving, 64),
        );
        let result = register(&rp, &mp, config).unwrap();
        let (d_m, a_deg) = pose_error(
            &result.m_world,
            &truth,
            centre + nalgebra::Vector3::new(0.0, 0.0, 10.0),
        );
        assert!(result.is_usable(), "{:?}", result.status);
        assert!(
            d_m < tol_m && a_deg < tol_deg,
            "error {d_m} m {a_deg} deg; {result:?}"
        );
        result
    }

    #[test]
    fn recovers_known_rigid_motion_forward_and_inverse() {
        let truth = Isometry3::from_parts(
            Translation3::new(1.3, -0.7, 0.9),
            UnitQuaternion::from_euler_angles(0.0002, -0.0003, 0.0006),
        );
        // Noise-free: the machinery must be exact. With noise, rigid accuracy is
        // tested on generated city tiles (tests/cli_pair_recovery.rs): this box
        // surface has too few slopes to fix yaw once walls are filtered out.
        let config = IcpConfig {
            samples: 120_000,
            ..Default::default()
        };
        check_recovery(0.0, truth, &config, 0.01, 0.001);
        check_recovery(0.0, truth.inverse(), &config, 0.01, 0.001);
    }

    #[test]
    fn recovers_known_translation_forward_and_inverse() {
        let truth = Isometry3::from_parts(
            Translation3::new(1.3, -0.7, 0.9),
            UnitQuaternion::identity(),
        );
        let config = IcpConfig {
            samples: 120_000,
            model: Model::Translation,
            ..Default::default()
        };
        check_recovery(0.15, truth, &config, 0.05, 1e-9);
        check_recovery(0.15, truth.inverse(), &config, 0.05, 1e-9);
    }

    #[test]
    fn recovers_large_shift_coarse_to_fine() {
        let truth = Isometry3::from_parts(
            Translation3::new(-4.6, 3.9, -2.1),
            UnitQuaternion::identity(),
        );
        let config = IcpConfig {
            samples: 120_000,
            model: Model::Translation,
            ..Default::default()
        };
        check_recovery(0.15, truth, &config, 0.05, 1e-9);
    }

    #[test]
    fn disjoint_dsms_are_refused() {
        let a = MemPyramid::build(dsm(0.0, 100.0, 50, 1.0, &Isometry3::identity(), 0.0, 1), 64);
        let b = MemPyramid::build(
            dsm(500.0, 100.0, 50, 1.0, &Isometry3::identity(), 0.0, 1),
            64,
        );
        assert!(matches!(
            register(&a, &b, &IcpConfig::default()),
            Err(IcpError::NoOverlap)
        ));
    }

    #[test]
    fn flat_terrain_is_flagged_degenerate() {
        let gt = GeoTransform::north_up(0.0, 100.0, 0.5, 0.5);
        let flat = MemPyramid::build(MemGrid::from_fn(200, 200, gt, |_, _| 12.0), 64);
        let r = register(&flat, &flat, &IcpConfig::default()).unwrap();
        assert_eq!(r.status, IcpStatus::Degenerate);
        assert!(!r.is_usable());
    }
}
