//! What a point-to-plane fit knows, direction by direction: the 6x6 information
//! of its estimate, which directions it cannot see (degenerate: flat ground leaves
//! x, y and yaw free; a single ridge one horizontal direction), and per-axis
//! standard errors that are honest when neighbouring residuals are correlated.
//!
//! The covariance is the spatial-correlation-robust sandwich H^+ M H^+ (Conley
//! 1999) with M = sum_{k,l} K(p_k - p_l) s_k s_l^T, s_k = w r a of one
//! correspondence and K a product Bartlett kernel of bandwidth L in ground x, y
//! (evaluated between sums over cells of L / 4): residuals closer than L (one
//! building, one tree) may be correlated. With uncorrelated residuals it is about
//! the usual sandwich; with correlated ones it grows by the
//! effective-sample-count factor that the independent sandwich misses. A
//! small-sample factor G / (G - 6), G = footprint area / L^2, accounts for the
//! meat being estimated from few independent neighbourhoods.
//!
//! Degenerate directions are eigen-directions of the scale-normalised normal
//! matrix H whose eigenvalue is below `min_relative_eigenvalue` times the largest,
//! or whose standard error exceeds `max_sigma_m` (rotations count as the arc at the
//! RMS radius of the points). The fit's update is projected onto the other
//! directions ([`super::point_to_plane_with`]): the degenerate ones keep their
//! initial value (solution remapping, Zhang & Singh 2016; X-ICP, Tuna et al. 2023).

use super::{Correspondence, Model};
use nalgebra::{DMatrix, Matrix6, SymmetricEigen, Vector3, Vector6};
use rayon::prelude::*;

/// One of the six pose parameters, in the order of [`FitInformation::info_6x6`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    X,
    Y,
    Z,
    Roll,
    Pitch,
    Yaw,
}

impl Axis {
    pub const ALL: [Axis; 6] = [
        Axis::X,
        Axis::Y,
        Axis::Z,
        Axis::Roll,
        Axis::Pitch,
        Axis::Yaw,
    ];

    /// Index in (x, y, z, roll, pitch, yaw) order.
    pub fn index(self) -> usize {
        self as usize
    }

    pub fn label(self) -> &'static str {
        ["x", "y", "z", "roll", "pitch", "yaw"][self.index()]
    }
}

/// When a direction counts as degenerate (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DegeneracyRule {
    /// Eigenvalues of the scale-normalised H below this fraction of the largest.
    pub min_relative_eigenvalue: f64,
    /// Standard errors above this (metres; rotations as the arc at the RMS radius).
    pub max_sigma_m: f64,
    /// Distance over which residuals may be correlated (the kernel bandwidth),
    /// metres; None: half the RMS radius of the points.
    pub cluster_cell_m: Option<f64>,
    /// Walls' shared placement error (see [`WallSnap`]); None: none.
    pub walls: Option<WallSnap>,
}

impl DegeneracyRule {
    /// Only numerically singular directions (the plain point-to-plane step).
    pub const NUMERICAL: DegeneracyRule = DegeneracyRule {
        min_relative_eigenvalue: 1e-10,
        max_sigma_m: f64::INFINITY,
        cluster_cell_m: None,
        walls: None,
    };
}

impl Default for DegeneracyRule {
    /// Directions the fit pins to worse than 0.5 m, or 1e-6 of the best one.
    fn default() -> Self {
        DegeneracyRule {
            min_relative_eigenvalue: 1e-6,
            max_sigma_m: 0.5,
            cluster_cell_m: None,
            walls: None,
        }
    }
}

/// What a fit knows (see the module doc). Axes in (x, y, z, roll, pitch, yaw) order,
/// translations in metres at the weighted centroid of the moving points, rotations
/// in radians about axes through it.
#[derive(Clone, Debug, PartialEq)]
pub struct FitInformation {
    /// Inverse covariance (m^-2, rad^-2) on the well-constrained subspace; zero
    /// along degenerate directions and parameters the model does not estimate.
    pub info_6x6: Matrix6<f64>,
    /// Covariance on the well-constrained subspace (the pseudo-inverse of `info_6x6`).
    pub covariance_6x6: Matrix6<f64>,
    /// One-sigma standard errors: metres for x, y, z, degrees for roll, pitch, yaw;
    /// None for degenerate axes and those the model does not estimate.
    pub sigma: [Option<f64>; 6],
    /// Axes that lie (by more than 10 % of their variance) in a degenerate direction.
    pub degenerate: Vec<Axis>,
    /// Where the translations are measured (the weighted centroid), metres.
    pub centroid: Vector3<f64>,
    /// Correspondences over the factor by which correlation inflates the variance
    /// (trace of the clustered over the independent sandwich).
    pub effective_samples: f64,
    /// RMS distance of the points from the centroid, metres (the
    /// lever that turns a rotation into an arc).
    pub radius_m: f64,
    /// The gridding floor ([`crate::icp::floor`]): a covariance the reported
    /// standard errors add to the fit's (zero until the ICP sets it). The graph
    /// weighs the fit's own covariance: the floor is mostly each DSM's own
    /// placement error, shared by all its pairs.
    pub gridding_6x6: Matrix6<f64>,
}

impl FitInformation {
    pub fn sigma_of(&self, axis: Axis) -> Option<f64> {
        self.sigma[axis.index()]
    }

    pub fn is_degenerate(&self, axis: Axis) -> bool {
        self.degenerate.contains(&axis)
    }

    /// The covariance as reported: the fit's plus the gridding floor.
    pub fn reported_covariance(&self) -> Matrix6<f64> {
        self.covariance_6x6 + self.gridding_6x6
    }

    /// Standard errors as reported (with the gridding floor), in the units of
    /// [`FitInformation::sigma`] and None where it is None.
    pub fn reported_sigma(&self) -> [Option<f64>; 6] {
        let c = self.reported_covariance();
        std::array::from_fn(|k| self.sigma[k].map(|_| standard_error(&c, k)))
    }
}

/// The standard error of parameter `k` of a covariance in (x, y, z [m], roll,
/// pitch, yaw [rad]): metres for the shifts, degrees for the rotations.
pub fn standard_error(covariance: &Matrix6<f64>, k: usize) -> f64 {
    let sd = covariance[(k, k)].max(0.0).sqrt();
    if k < 3 {
        sd
    } else {
        sd.to_degrees()
    }
}

/// The normal equations of one point-to-plane step, scale-normalised: rotation
/// columns divided by the RMS radius so all six compare like for like. Parameter
/// order (rx, ry, rz, tx, ty, tz), as [`super::FitUpdate::weakest_direction`].
pub(crate) struct NormalEquations {
    pub h: Matrix6<f64>,
    pub g: Vector6<f64>,
    /// Independent sandwich meat sum (w r)^2 a a^T.
    pub meat: Matrix6<f64>,
    /// Clustered sandwich meat (see the module doc).
    pub clustered: Matrix6<f64>,
    pub centroid: Vector3<f64>,
    pub radius_m: f64,
}

impl NormalEquations {
    pub fn new(corrs: &[Correspondence], rule: &DegeneracyRule) -> Option<Self> {
        let cell_m = rule.cluster_cell_m;
        let total_w: f64 = corrs.iter().map(|c| c.weight).sum();
        if corrs.len() < 6 || total_w <= 0.0 {
            return None;
        }
        let centroid = corrs
            .iter()
            .map(|c| c.moving * c.weight)
            .sum::<Vector3<f64>>()
            / total_w;
        let radius_m = (corrs
            .iter()
            .map(|c| c.weight * (c.moving - centroid).norm_squared())
            .sum::<f64>()
            / total_w)
            .sqrt()
            .max(1e-6);
        let bandwidth = cell_m.unwrap_or(radius_m / 2.0).max(1e-9);
        let cell = bandwidth / CELLS_PER_BANDWIDTH as f64;
        // fixed chunks summed in parallel, their sums added in order: the
        // same result whatever the thread count
        let parts: Vec<Sums> = corrs
            .par_chunks(SUM_CHUNK)
            .map(|chunk| Sums::of(chunk, &centroid, radius_m, cell))
            .collect();
        let mut parts = parts.into_iter();
        let Sums {
            mut h,
            mut g,
            mut meat,
            mut cells,
        } = parts.next().expect("at least six matches");
        for p in parts {
            h += p.h;
            g += p.g;
            meat += p.meat;
            for (key, s) in p.cells {
                *cells.entry(key).or_insert_with(Vector6::zeros) += s;
            }
        }
        // Small-sample correction as CR1 of cluster-robust estimators, with one
        // "cluster" per kernel footprint: the meat is estimated from few
        // independent neighbourhoods, and from residuals, not errors.
        let groups = cells.len() as f64 / (CELLS_PER_BANDWIDTH * CELLS_PER_BANDWIDTH) as f64;
        let correction = groups / (groups - 6.0).max(1.0);
        let mut clustered = bartlett_meat(&cells) * correction.max(1.0);
        if let Some(walls) = &rule.walls {
            clustered += walls.meat(corrs, &centroid, radius_m);
        }
        Some(NormalEquations {
            h,
            g,
            meat,
            clustered,
            centroid,
            radius_m,
        })
    }
}

/// A Gaussian prior on a fit's rotation about its start: what georeferenced
/// DSMs are known to hold (their relative rotations are hundredths of a degree,
/// far below what a narrow or flat overlap can measure), so that a direction
/// the data barely see stays near the start instead of following the noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RotationPrior {
    /// One-sigma per axis, radians (infinite or zero: no prior).
    pub sigma_rad: f64,
    /// The current rotation relative to the start (rotation vector, radians).
    pub current: Vector3<f64>,
}

impl NormalEquations {
    /// The equations with `prior` added as three pseudo-observations of the
    /// rotation. Per unit weight the data's residual variance is v =
    /// trace(meat) / trace(H); a pseudo-observation of weight v / sigma^2 would
    /// weigh the prior against the data as if their residuals were independent.
    /// Correlated residuals and walls' shared errors (the clustered meat) make
    /// a direction's data worth less than H says, by a factor kappa (its
    /// sandwich over its naive variance), so each rotation axis's prior weight
    /// is kappa v / sigma^2 and its clustered meat that weight times kappa v: the step and
    /// the sandwich are then the generalised-least-squares combination of the
    /// data with the prior (exact along each axis), and no rotation's standard
    /// error exceeds the prior's. A direction the data do not see has kappa 1.
    pub fn with_rotation_prior(mut self, prior: Option<&RotationPrior>) -> Self {
        let Some(p) = prior.filter(|p| p.sigma_rad > 0.0 && p.sigma_rad.is_finite()) else {
            return self;
        };
        let variance = self.meat.trace() / self.h.trace().max(f64::MIN_POSITIVE);
        if !(variance > 0.0 && variance.is_finite()) {
            return self;
        }
        let lambda = variance / (p.sigma_rad * self.radius_m).powi(2);
        let kappa = self.inflation(lambda, variance);
        for (k, factor) in kappa.into_iter().enumerate() {
            let weight = lambda * factor;
            self.h[(k, k)] += weight;
            self.g[k] += weight * p.current[k] * self.radius_m;
            // the independent meat, as its H, takes the prior as independent data
            self.meat[(k, k)] += variance * weight;
            self.clustered[(k, k)] += variance * weight * factor;
        }
        self
    }

    /// Per rotation axis, the factor by which the clustered sandwich exceeds
    /// the naive variance v H^-1 with the prior in: a fixed point (it converges
    /// to the data's own factor, geometrically by lambda kappa / (h + lambda
    /// kappa)), clamped to [1, 10^6].
    fn inflation(&self, lambda: f64, variance: f64) -> [f64; 3] {
        let mut kappa = [1.0; 3];
        for _ in 0..INFLATION_ITERATIONS {
            let (mut h, mut meat) = (self.h, self.clustered);
            for (k, factor) in kappa.iter().enumerate() {
                h[(k, k)] += lambda * factor;
                meat[(k, k)] += variance * lambda * factor * factor;
            }
            let eig = h.symmetric_eigen();
            let max = eig.eigenvalues.max();
            let keep = std::array::from_fn(|k| eig.eigenvalues[k] > 1e-12 * max);
            let inverse = pseudo_inverse(&eig, &keep);
            let sandwich = inverse * meat * inverse;
            for (k, factor) in kappa.iter_mut().enumerate() {
                let naive = variance * inverse[(k, k)];
                if naive > 0.0 && sandwich[(k, k)].is_finite() {
                    *factor = (sandwich[(k, k)] / naive).clamp(1.0, 1e6);
                }
            }
        }
        kappa
    }
}

/// Fixed-point iterations of [`NormalEquations::inflation`]: the error shrinks
/// by lambda kappa / (h + lambda kappa) each, so where the prior matters
/// (h ~ lambda kappa) five leave about 3 %.
const INFLATION_ITERATIONS: usize = 5;

/// The point-to-plane row of a match at `q` (from the centroid) with normal
/// `n`: rotations (scaled by the radius, so all six share metres) then shifts.
pub(crate) fn jacobian_row(q: &Vector3<f64>, n: &Vector3<f64>, radius_m: f64) -> Vector6<f64> {
    let rot = q.cross(n) / radius_m;
    Vector6::new(rot.x, rot.y, rot.z, n.x, n.y, n.z)
}

/// Cells per kernel bandwidth: the kernel is evaluated between cell sums.
const CELLS_PER_BANDWIDTH: i64 = 4;

/// The eigen-directions of H the fit keeps (true) and holds (false).
pub(crate) fn constrained_directions(
    eq: &NormalEquations,
    model: Model,
    rule: &DegeneracyRule,
) -> (SymmetricEigen<f64, nalgebra::U6>, [bool; 6]) {
    let h = restrict(&eq.h, model);
    let eig = h.symmetric_eigen();
    let max = eig.eigenvalues.max();
    let mut keep = [false; 6];
    for (k, kept) in keep.iter_mut().enumerate() {
        *kept = max > 0.0 && eig.eigenvalues[k] > rule.min_relative_eigenvalue * max;
    }
    if rule.max_sigma_m.is_finite() {
        let cov = sandwich(&eig, &keep, &restrict(&eq.clustered, model));
        for (k, kept) in keep.iter_mut().enumerate() {
            let v = eig.eigenvectors.column(k);
            let sd = (v.transpose() * cov * v)[(0, 0)].max(0.0).sqrt();
            if sd > rule.max_sigma_m {
                *kept = false;
            }
        }
    }
    (eig, keep)
}

/// H restricted to what the model estimates (rotations zeroed for translation only).
fn restrict(m: &Matrix6<f64>, model: Model) -> Matrix6<f64> {
    let mut out = *m;
    if model == Model::Translation {
        for a in 0..6 {
            for b in 0..6 {
                if a < 3 || b < 3 {
                    out[(a, b)] = 0.0;
                }
            }
        }
    }
    out
}

/// The pseudo-inverse of H over the kept directions.
pub(crate) fn pseudo_inverse(
    eig: &SymmetricEigen<f64, nalgebra::U6>,
    keep: &[bool; 6],
) -> Matrix6<f64> {
    let mut inv = Matrix6::zeros();
    for k in (0..6).filter(|&k| keep[k]) {
        let v = eig.eigenvectors.column(k);
        inv += v * v.transpose() / eig.eigenvalues[k];
    }
    inv
}

fn sandwich(
    eig: &SymmetricEigen<f64, nalgebra::U6>,
    keep: &[bool; 6],
    meat: &Matrix6<f64>,
) -> Matrix6<f64> {
    let inv = pseudo_inverse(eig, keep);
    inv * meat * inv
}

/// What the fit of `corrs` (at its solution: the residuals are the final ones) knows.
/// None when there are too few correspondences.
pub fn fit_information(
    corrs: &[Correspondence],
    model: Model,
    rule: &DegeneracyRule,
) -> Option<FitInformation> {
    fit_information_with(corrs, model, rule, None)
}

/// [`fit_information`] with a prior on the rotation ([`RotationPrior`]).
pub fn fit_information_with(
    corrs: &[Correspondence],
    model: Model,
    rule: &DegeneracyRule,
    prior: Option<&RotationPrior>,
) -> Option<FitInformation> {
    let eq = NormalEquations::new(corrs, rule)?.with_rotation_prior(prior);
    let (eig, keep) = constrained_directions(&eq, model, rule);
    // Covariance with the normals' noise taken out of H and the meat (eiv.rs).
    let (h_noise, meat_noise) = eiv::noise_terms(corrs, &eq.centroid, eq.radius_m);
    let inverse = eiv::corrected_inverse(&eig, &keep, &restrict(&(eq.h - h_noise), model));
    let sandwich_of = |meat: &Matrix6<f64>| {
        let meat = eiv::positive_part(&restrict(&(meat - meat_noise), model));
        inverse * meat * inverse
    };
    let scaled = sandwich_of(&eq.clustered);
    let independent = sandwich_of(&eq.meat);
    // (rx, ry, rz, tx, ty, tz) scaled -> (x, y, z, roll, pitch, yaw) physical
    let mut to_physical = Matrix6::zeros();
    for k in 0..3 {
        to_physical[(k, k + 3)] = 1.0;
        to_physical[(k + 3, k)] = 1.0 / eq.radius_m;
    }
    let covariance = to_physical * scaled * to_physical.transpose();
    let mut held = Matrix6::zeros();
    for k in (0..6).filter(|&k| !keep[k]) {
        let v = to_physical_direction(&eig.eigenvectors.column(k).into_owned());
        held += v * v.transpose();
    }
    let estimated = |axis: usize| model == Model::Rigid || axis < 3;
    let degenerate: Vec<Axis> = Axis::ALL
        .into_iter()
        .filter(|a| estimated(a.index()) && held[(a.index(), a.index())] > 0.1)
        .collect();
    let mut sigma = [None; 6];
    for a in Axis::ALL {
        let k = a.index();
        if estimated(k) && !degenerate.contains(&a) {
            sigma[k] = Some(standard_error(&covariance, k));
        }
    }
    let info = {
        let inverse = to_physical.try_inverse().unwrap_or_else(Matrix6::zeros);
        inverse.transpose() * kept_inverse(&eig, &keep, &scaled) * inverse
    };
    let ratio = scaled.trace() / independent.trace().max(f64::MIN_POSITIVE);
    Some(FitInformation {
        info_6x6: info,
        covariance_6x6: covariance,
        sigma,
        degenerate,
        centroid: eq.centroid,
        effective_samples: corrs.len() as f64 / ratio.max(1e-12),
        radius_m: eq.radius_m,
        gridding_6x6: Matrix6::zeros(),
    })
}

/// A scaled (rx, ry, rz, tx, ty, tz) direction in (x, y, z, roll, pitch, yaw) order,
/// unit length, comparing rotations as arcs at the RMS radius.
fn to_physical_direction(v: &Vector6<f64>) -> Vector6<f64> {
    Vector6::new(v[3], v[4], v[5], v[0], v[1], v[2])
}

/// The inverse of `cov` on the span of the kept eigen-directions (zero elsewhere).
fn kept_inverse(
    eig: &SymmetricEigen<f64, nalgebra::U6>,
    keep: &[bool; 6],
    cov: &Matrix6<f64>,
) -> Matrix6<f64> {
    on_kept(eig, keep, cov, |reduced| reduced.try_inverse())
}

/// `m` reduced to the span of the kept eigen-directions (U^T m U), mapped by
/// `invert` and taken back (U f(U^T m U) U^T); zero when nothing is kept or
/// `invert` gives None.
fn on_kept(
    eig: &SymmetricEigen<f64, nalgebra::U6>,
    keep: &[bool; 6],
    m: &Matrix6<f64>,
    invert: impl FnOnce(DMatrix<f64>) -> Option<DMatrix<f64>>,
) -> Matrix6<f64> {
    let kept: Vec<usize> = (0..6).filter(|&k| keep[k]).collect();
    if kept.is_empty() {
        return Matrix6::zeros();
    }
    let u = DMatrix::from_fn(6, kept.len(), |r, c| eig.eigenvectors[(r, kept[c])]);
    let m = DMatrix::from_fn(6, 6, |r, c| m[(r, c)]);
    let Some(inverse) = invert(u.transpose() * &m * &u) else {
        return Matrix6::zeros();
    };
    let full = &u * inverse * u.transpose();
    Matrix6::from_fn(|r, c| full[(r, c)])
}

mod eiv;
mod sums;
mod walls;
use sums::{bartlett_meat, Sums, SUM_CHUNK};
pub use walls::WallSnap;

#[cfg(test)]
mod tests;
