//! What one edge of the graph knows: its rotation and translation
//! information, from the pair's covariance.

use crate::fit::FitInformation;
use crate::graph::EdgeSigma;
use nalgebra::allocator::Allocator;
use nalgebra::{
    DefaultAllocator, DimName, DimSub, Matrix3, Matrix6, OMatrix, Vector3, Vector6, U1,
};

/// What one edge knows, about the axes of i's frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeInformation {
    /// Information of the relative rotation, rad^-2 (zero along unconstrained axes).
    pub rotation: Matrix3<f64>,
    /// Information of the offset of the edge's centre, m^-2.
    pub translation: Matrix3<f64>,
    /// False for edges that did not converge or are ambiguous: they enter at
    /// `unreliable_factor` of their information and never count as constraining.
    pub reliable: bool,
    /// The part of `rotation` the pair's fit took from its rotation prior (zero
    /// without one). The poses' covariance counts the prior once per DSM, not
    /// once per edge ([`super::average_informed`]).
    pub prior_rotation: Matrix3<f64>,
}

/// Along a rotation direction, the prior's part is at most this fraction of
/// the edge's information there ([`EdgeInformation::with_rotation_prior`]).
pub(super) const MOST_PRIOR_SHARE: f64 = 0.95;

impl EdgeInformation {
    /// The marginal rotation and translation information of a fit: the inverses of
    /// the covariance blocks on their constrained subspaces (zero along degenerate
    /// axes).
    pub fn from_fit(info: &FitInformation, reliable: bool) -> Self {
        Self::from_covariance(&info.covariance_6x6, reliable)
    }

    /// The same from a 6x6 covariance of (x, y, z, roll, pitch, yaw), zero
    /// along the directions the fit held: the marginal (Schur complement)
    /// blocks of its pseudo-inverse. For a full-rank covariance they are the
    /// inverses of its blocks; a held direction that mixes a shift and a
    /// rotation (x with yaw along a narrow strip) leaves no information on
    /// either, where the inverse of a block would read its zero variance as
    /// certainty.
    pub fn from_covariance(c: &Matrix6<f64>, reliable: bool) -> Self {
        // Inverted as a correlation matrix: the cutoff is relative, and radians
        // squared against metres squared span 12 decades on DSMs of tens of
        // kilometres (90 m SRTM: 4e-13 rad^2 beside 0.4 m^2), where it would
        // cut the rotations away.
        let d = Matrix6::from_diagonal(&Vector6::from_fn(|k, _| {
            let v = c[(k, k)];
            if v > 0.0 {
                1.0 / v.sqrt()
            } else {
                0.0
            }
        }));
        let info = d * pseudo_inverse6(&(d * c * d)) * d;
        let block = |r: usize, k: usize| info.fixed_view::<3, 3>(r, k).into_owned();
        let (tt, tr, rr) = (block(0, 0), block(0, 3), block(3, 3));
        EdgeInformation {
            translation: positive_part(&(tt - tr * block_inverse(&rr) * tr.transpose())),
            rotation: positive_part(&(rr - tr.transpose() * block_inverse(&tt) * tr)),
            reliable,
            prior_rotation: Matrix3::zeros(),
        }
    }

    /// The same, for a fit given a rotation prior of one-sigma `sigma_rad` per
    /// axis: the fit's rotation information is the data's plus 1 / sigma^2 per
    /// axis (the generalised least squares of [`crate::fit`], which the
    /// marginal keeps), so per eigen-direction the prior's part is 1 /
    /// sigma^2, or less where the checks' gaps left the edge less than that
    /// (at most [`MOST_PRIOR_SHARE`] of it: a held direction stays empty).
    pub fn with_rotation_prior(mut self, sigma_rad: f64) -> Self {
        if sigma_rad > 0.0 && sigma_rad.is_finite() {
            let prior = sigma_rad.powi(-2);
            self.prior_rotation = spectral(&self.rotation, |l, _| {
                prior.min(MOST_PRIOR_SHARE * l.max(0.0))
            });
        }
        self
    }

    /// What the edge's data say: `rotation` without the prior's part.
    pub fn without_prior(&self) -> Self {
        EdgeInformation {
            rotation: positive_part(&(self.rotation - self.prior_rotation)),
            prior_rotation: Matrix3::zeros(),
            ..*self
        }
    }

    /// Diagonal information from per-axis standard errors (rad, m): for edges
    /// whose fit reported no covariance.
    pub fn from_sigma(sigma: &EdgeSigma, reliable: bool) -> Self {
        let diag = |v: Vector3<f64>| Matrix3::from_diagonal(&v.map(|s| 1.0 / (s * s)));
        EdgeInformation {
            rotation: diag(sigma.rotation_rad()),
            translation: diag(sigma.translation_m()),
            reliable,
            prior_rotation: Matrix3::zeros(),
        }
    }

    pub fn is_valid(&self) -> bool {
        let symmetric =
            |m: &Matrix3<f64>| (m - m.transpose()).amax() <= 1e-9 * m.amax().max(1e-300);
        let ok = |m: &Matrix3<f64>| {
            m.iter().all(|v| v.is_finite())
                && symmetric(m)
                && m.symmetric_eigen().eigenvalues.min() >= -1e-9 * m.amax()
        };
        ok(&self.rotation) && ok(&self.translation) && ok(&self.prior_rotation)
    }
}

/// `f` applied to the eigenvalues of a symmetric D x D matrix:
/// V diag(f(lambda, largest lambda)) V^T.
fn spectral<D>(m: &OMatrix<f64, D, D>, f: impl Fn(f64, f64) -> f64) -> OMatrix<f64, D, D>
where
    D: DimName + DimSub<U1>,
    DefaultAllocator: Allocator<D, D> + Allocator<D> + Allocator<<D as DimSub<U1>>::Output>,
{
    let eig = m.clone().symmetric_eigen();
    let max = eig.eigenvalues.max();
    let weights = OMatrix::<f64, D, D>::from_diagonal(&eig.eigenvalues.map(|l| f(l, max)));
    &eig.eigenvectors * weights * eig.eigenvectors.transpose()
}

/// 1 / lambda above a relative cutoff of 1e-12, else 0: the pseudo-inverse.
fn inverted(lambda: f64, max: f64) -> f64 {
    if max > 0.0 && lambda > 1e-12 * max {
        1.0 / lambda
    } else {
        0.0
    }
}

/// The symmetric part of `m` with its negative eigenvalues set to zero (the
/// Schur complements of an ill-conditioned information can come out a
/// rounding error below zero, which [`EdgeInformation::is_valid`] refuses).
fn positive_part(m: &Matrix3<f64>) -> Matrix3<f64> {
    spectral(&(0.5 * (m + m.transpose())), |l, _| l.max(0.0))
}

/// Pseudo-inverse of a symmetric positive semi-definite 6x6 (relative cutoff 1e-12).
fn pseudo_inverse6(c: &Matrix6<f64>) -> Matrix6<f64> {
    spectral(c, inverted)
}

/// Pseudo-inverse of a symmetric positive semi-definite 3x3 (relative cutoff 1e-12).
pub(super) fn block_inverse(c: &Matrix3<f64>) -> Matrix3<f64> {
    spectral(c, inverted)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two 90 m SRTM DSMs: shifts known to decimetres (0.4 m^2), rotations to
    /// 1e-6 rad (1e-12 rad^2), twelve decades apart: each block keeps its
    /// information (a relative cutoff on the raw covariance cut the rotations).
    #[test]
    fn rotations_of_wide_dsms_keep_their_information() {
        let mut c = Matrix6::zeros();
        c.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::new(
            0.45, -0.2, 0.0, -0.2, 0.21, 0.0, 0.0, 0.0, 0.003,
        ));
        c.fixed_view_mut::<3, 3>(3, 3)
            .copy_from(&(Matrix3::from_diagonal(&Vector3::new(4.4, 2.0, 60.0)) * 1e-13));
        let e = EdgeInformation::from_covariance(&c, true);
        for k in 0..3 {
            let expected = 1.0 / c[(3 + k, 3 + k)];
            assert!((e.rotation[(k, k)] / expected - 1.0).abs() < 1e-6, "{e:?}");
        }
        let t = block_inverse(&c.fixed_view::<3, 3>(0, 0).into_owned());
        assert!((e.translation - t).amax() <= 1e-6 * t.amax(), "{e:?}");
    }
}
