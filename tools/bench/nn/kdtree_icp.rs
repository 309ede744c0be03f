//! The k-d tree baseline of the paper's comparison (Xu & Qin 2024, Fig. 5/6):
//! the same point-to-point ICP as `dsmstream::icp::register` at full resolution
//! (same samples, local frame, tau, Tukey weights, Kabsch fit and stopping
//! rule), but with correspondences from a kiddo k-d tree built over ALL valid
//! reference points instead of the grid search.
//!
//! The reference cloud is stored as f32 (x, y, z) in the local frame centred on
//! the overlap (like PCL's PointXYZ in the paper's baseline; f32 resolves 0.5 mm
//! at 4 km from the origin), and kept in memory beside the tree, as any k-d tree
//! ICP keeps its cloud. The returned matches are reconstructed in f64.

use std::time::Instant;

use dsmstream::fit::{point_to_point, Correspondence};
use dsmstream::grid::{Grid, Pyramid};
use dsmstream::icp::sample::sample_overlap;
use dsmstream::icp::{associate::block_order, IcpConfig, IcpStatus};
use dsmstream::nn::PixelFrame;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Isometry3, Point3, Vector3};
use rayon::prelude::*;

/// Query points per parallel block (as in `icp::associate`).
const BLOCK: usize = 4096;

/// The query set of one pair, built exactly as `register` builds it at level 0.
pub struct Queries {
    /// Sampled moving points, local frame, in reference block order.
    pub points: Vec<Vector3<f64>>,
    /// Local frame origin in world coordinates (overlap centre, mean sample height).
    pub origin: Vector3<f64>,
    /// The reference level-0 lattice in the local frame.
    pub ref_frame: PixelFrame,
    /// Half diagonal of the overlap, the lever arm of the stopping rule.
    pub lever_m: f64,
}

/// Builds the query set of `register` (level 0 only): stratified samples of the
/// moving DSM inside the overlap, seeded by `config.seed`.
pub fn queries<R: Pyramid, M: Pyramid>(
    reference: &R,
    moving: &M,
    config: &IcpConfig,
) -> Result<Queries, String> {
    let ref0 = reference.open_level(0).map_err(|e| e.to_string())?;
    let mut mov0 = moving.open_level(0).map_err(|e| e.to_string())?;
    let extent = |g: &dyn Grid| g.geotransform().extent(g.width() as u64, g.height() as u64);
    let overlap = extent(&ref0)
        .intersection(&extent(&mov0))
        .ok_or("the two DSMs do not overlap")?;
    let (centre_x, centre_y) = overlap.centre();
    let origin_xy = Vector3::new(centre_x, centre_y, 0.0);
    let sample_frame = PixelFrame::new(&mov0.geotransform(), &origin_xy);
    let mut points = sample_overlap(
        &mut mov0,
        &sample_frame,
        &overlap,
        config.samples,
        config.seed,
    )
    .points;
    if points.is_empty() {
        return Err("no valid pixels in the overlap".into());
    }
    let mean_z = points.iter().map(|p| p.z).sum::<f64>() / points.len() as f64;
    let origin = Vector3::new(origin_xy.x, origin_xy.y, mean_z);
    for p in &mut points {
        p.z -= mean_z;
    }
    let ref_frame = PixelFrame::new(&ref0.geotransform(), &origin);
    block_order(&mut points, &ref_frame, 256);
    let lever_m = overlap.half_diagonal();
    Ok(Queries {
        points,
        origin,
        ref_frame,
        lever_m,
    })
}

/// Every valid reference pixel as an f32 point in the local frame, read in
/// bands of `band_rows` rows through `grid` (no more than one band in flight).
pub fn load_cloud<G: Grid + ?Sized>(
    grid: &mut G,
    read_band: &mut dyn FnMut(&mut G, i64, usize) -> Vec<f32>,
    frame: &PixelFrame,
    expected_points: usize,
    band_rows: usize,
) -> Vec<[f32; 3]> {
    let (w, h) = (grid.width(), grid.height());
    let mut cloud = Vec::with_capacity(expected_points);
    let mut row0 = 0;
    while row0 < h {
        let rows = band_rows.min((h - row0) as usize);
        let band = read_band(grid, row0, rows);
        for (i, &v) in band.iter().enumerate() {
            if v.is_nan() {
                continue;
            }
            let (c, r) = ((i % w as usize) as i64, row0 + (i / w as usize) as i64);
            let p = frame.pixel_point(c, r, v);
            cloud.push([p.x as f32, p.y as f32, p.z as f32]);
        }
        row0 += rows as i64;
    }
    cloud
}

/// The reference cloud and its k-d tree.
pub struct KdReference {
    pub cloud: Vec<[f32; 3]>,
    pub tree: ImmutableKdTree<f32, 3>,
}

impl KdReference {
    /// Builds the tree (parallel construction on the current rayon pool).
    pub fn build(cloud: Vec<[f32; 3]>) -> Result<KdReference, String> {
        let tree = ImmutableKdTree::new_from_slice_parallel(&cloud)
            .map_err(|e| format!("k-d tree construction failed: {e:?}"))?;
        Ok(KdReference { cloud, tree })
    }

    /// Exact nearest reference point of a local-frame query, and its distance.
    #[inline]
    pub fn nearest(&self, q: &Vector3<f64>) -> (Vector3<f64>, f64) {
        let hit = self
            .tree
            .query(&[q.x as f32, q.y as f32, q.z as f32])
            .nearest_one::<SquaredEuclidean<f32>>()
            .execute();
        let p = self.cloud[hit.item as usize];
        let p = Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64);
        (p, (p - q).norm())
    }
}

/// Matches of one iteration: inliers within tau, and their distances.
pub struct KdAssociation {
    pub corrs: Vec<Correspondence>,
    pub distances_m: Vec<f64>,
}

/// The k-d tree counterpart of `icp::associate` (point-to-point: no normals needed).
pub fn associate(
    kd: &KdReference,
    points: &[Vector3<f64>],
    t_ref_moving: &Isometry3<f64>,
    tau_m: f64,
) -> KdAssociation {
    let blocks: Vec<Vec<(Correspondence, f64)>> = points
        .par_chunks(BLOCK)
        .map(|block| {
            block
                .iter()
                .filter_map(|p| {
                    let q = t_ref_moving.transform_point(&Point3::from(*p)).coords;
                    let (reference, d) = kd.nearest(&q);
                    (d <= tau_m).then_some((
                        Correspondence {
                            moving: q,
                            reference,
                            normal: Vector3::z(),
                            weight: 1.0,
                            normal_var: 0.0,
                        },
                        d,
                    ))
                })
                .collect()
        })
        .collect();
    let (corrs, distances_m) = blocks.into_iter().flatten().unzip();
    KdAssociation { corrs, distances_m }
}

/// Outcome of the k-d tree ICP, comparable with `IcpResult`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct KdIcpResult {
    pub m_world: [[f64; 4]; 4],
    pub rmse_m: f64,
    pub inliers: usize,
    pub iterations: usize,
    pub status: IcpStatus,
    /// Wall time of the correspondence searches of the ICP, per iteration.
    pub nn_seconds_per_iteration: f64,
}

/// The full-resolution loop of `register` with k-d tree correspondences.
pub fn register_kd(kd: &KdReference, q: &Queries, config: &IcpConfig) -> KdIcpResult {
    let tau_m = config
        .tau_m
        .min(config.max_displacement_m.max(config.tau_m));
    let min_inliers = 30.max(q.points.len() / 100);
    let mut t = Isometry3::identity();
    let (mut status, mut iterations, mut nn_s) = (IcpStatus::MaxIterations, 0, 0.0);
    let mut peak_inliers = 0;
    for _ in 0..config.max_iter {
        iterations += 1;
        let started = Instant::now();
        let assoc = associate(kd, &q.points, &t, tau_m);
        nn_s += started.elapsed().as_secs_f64();
        if assoc.corrs.len() < min_inliers {
            status = IcpStatus::TooFewInliers;
            break;
        }
        peak_inliers = peak_inliers.max(assoc.corrs.len());
        let corrs = tukey(assoc.corrs);
        let update = point_to_point(&corrs, config.model).unwrap_or_else(Isometry3::identity);
        t = update * t;
        if t.translation.vector.norm() > config.max_displacement_m {
            status = IcpStatus::Diverged;
            break;
        }
        let step_m = update.translation.vector.norm() + update.rotation.angle() * q.lever_m;
        if step_m < config.tolerance_m {
            status = IcpStatus::Converged;
            break;
        }
    }
    let last = associate(kd, &q.points, &t, tau_m);
    if status != IcpStatus::TooFewInliers && last.corrs.len() < min_inliers {
        status = IcpStatus::TooFewInliers;
    } else if status != IcpStatus::TooFewInliers && last.corrs.len() * 2 < peak_inliers {
        status = IcpStatus::Diverged;
    }
    let t_ref_moving = dsmstream::geo::rigid::isometry_to_world(&t, &q.origin);
    let rmse_m = (last.distances_m.iter().map(|d| d * d).sum::<f64>()
        / last.distances_m.len().max(1) as f64)
        .sqrt();
    KdIcpResult {
        m_world: dsmstream::geo::rigid::to_rows(&t_ref_moving),
        rmse_m,
        inliers: last.corrs.len(),
        iterations,
        status,
        nn_seconds_per_iteration: nn_s / iterations.max(1) as f64,
    }
}

/// Tukey biweight on the point-to-point residual, as `register` weights
/// (scale from the median absolute residual, floor 1 cm).
fn tukey(mut corrs: Vec<Correspondence>) -> Vec<Correspondence> {
    let mut abs: Vec<f64> = corrs
        .iter()
        .map(|c| (c.moving - c.reference).norm())
        .collect();
    let mid = abs.len() / 2;
    let median = *abs.select_nth_unstable_by(mid, f64::total_cmp).1;
    let c = 4.685 * (1.4826 * median).max(0.01);
    for corr in &mut corrs {
        let u = (corr.moving - corr.reference).norm() / c;
        corr.weight = if u < 1.0 { (1.0 - u * u).powi(2) } else { 0.0 };
    }
    corrs
}

#[cfg(test)]
mod tests {
    use super::*;
    use dsmstream::geo::GeoTransform;
    use dsmstream::grid::MemGrid;
    use dsmstream::nn::{nearest, NnStats};
    use dsmstream::rng::SplitMix64;

    /// A rough DSM with walls and no-data holes.
    fn dsm() -> MemGrid {
        let gt = GeoTransform::north_up(1000.0, 2000.0, 0.5, 0.5);
        let mut rng = SplitMix64::new(3);
        MemGrid::from_fn(120, 90, gt, |c, r| {
            if rng.next_f64() < 0.05 {
                return f32::NAN;
            }
            let wall = if (c / 15 + r / 10) % 3 == 0 {
                12.0
            } else {
                0.0
            };
            (wall + (c as f64 * 0.11).sin() * 2.0 + rng.next_f64() * 0.4) as f32
        })
    }

    #[test]
    fn kd_nearest_equals_the_exact_grid_search() {
        let mut grid = dsm();
        let origin = Vector3::new(1030.0, 1978.0, 3.0);
        let frame = PixelFrame::new(&grid.geotransform(), &origin);
        let mut band = |g: &mut MemGrid, row0: i64, rows: usize| {
            let w = g.width() as usize;
            g.data[row0 as usize * w..(row0 as usize + rows) * w].to_vec()
        };
        let cloud = load_cloud(&mut grid, &mut band, &frame, 0, 7);
        let valid = grid.data.iter().filter(|v| !v.is_nan()).count();
        assert_eq!(cloud.len(), valid);
        let kd = KdReference::build(cloud).unwrap();
        let mut rng = SplitMix64::new(9);
        let mut stats = NnStats::default();
        for _ in 0..2000 {
            let q = Vector3::new(
                rng.range(-32.0, 32.0),
                rng.range(-24.0, 24.0),
                rng.range(-8.0, 16.0),
            );
            let (_, d_kd) = kd.nearest(&q);
            let grid_hit = nearest(&mut grid, &frame, &q, 1e3, &mut stats).unwrap();
            // f32 storage of the cloud: distances agree to well under a millimetre.
            assert!(
                (d_kd - grid_hit.distance_m).abs() < 1e-3,
                "{q:?}: kd {d_kd} grid {}",
                grid_hit.distance_m
            );
        }
    }

    #[test]
    fn tukey_zeroes_far_residuals() {
        let c = |d: f64| Correspondence {
            moving: Vector3::new(d, 0.0, 0.0),
            reference: Vector3::zeros(),
            normal: Vector3::z(),
            weight: 1.0,
            normal_var: 0.0,
        };
        let w = tukey(vec![c(0.1), c(0.1), c(0.12), c(50.0)]);
        assert!(w[0].weight > 0.9 && w[3].weight == 0.0);
    }
}
