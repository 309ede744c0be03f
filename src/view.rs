//! A DSM as a pair registration sees it: moved by its initial shift
//! (`--initial`) and with the cells a stable-terrain mask excludes (`--mask`)
//! read as no-data. [`ViewedPyramid`] wraps any [`Pyramid`], so the global
//! search, the sampling, the ICP correspondences and the final information all
//! see the same masked, moved surface with no change to their code.
//!
//! The shift is a pure translation S (the initial pose's motion of the DSM's
//! centre), exact on the pixel lattice: the geotransform moves by (sx, sy) and
//! every height by sz. A result between two views, Δ (p_ref_view = Δ
//! p_moving_view), is turned back into the DSMs' own coordinates by
//! [`to_raw_frames`]: T = S_ref^-1 Δ S_moving, the information's centroid moved
//! by -s_ref (its covariance is about the CRS axes and does not change).
//! The mask is looked up at each pixel's moved position.

use std::sync::Arc;

use nalgebra::{Isometry3, Vector3};

use crate::geo::GeoTransform;
use crate::grid::{Grid, GridError, Pyramid};
use crate::icp::IcpResult;
use crate::mask::{MaskLookup, StableMask};

/// What every pair of a run shares: the mask, and each DSM's initial shift.
#[derive(Clone, Debug, Default)]
pub struct PairInputs {
    pub mask: Option<Arc<StableMask>>,
    /// Per DSM index, metres (x, y, z); empty: no initial poses.
    pub shifts_m: Vec<Vector3<f64>>,
    /// The initial poses file and the hash of its bytes, for the journal.
    pub initial: Option<(std::path::PathBuf, u64)>,
}

impl PairInputs {
    /// The initial shift of DSM `index` (zero without initial poses).
    pub fn shift_m(&self, index: usize) -> Vector3<f64> {
        self.shifts_m
            .get(index)
            .copied()
            .unwrap_or_else(Vector3::zeros)
    }

    /// DSM `index` of `inner` as the registration sees it.
    pub fn view<P: Pyramid>(&self, inner: P, index: usize) -> ViewedPyramid<'_, P> {
        ViewedPyramid {
            inner,
            shift_m: self.shift_m(index),
            mask: self.mask.as_deref(),
        }
    }

    /// DSM `index` moved but not masked (for the overlap score).
    pub fn moved<P: Pyramid>(&self, inner: P, index: usize) -> ViewedPyramid<'_, P> {
        ViewedPyramid {
            inner,
            shift_m: self.shift_m(index),
            mask: None,
        }
    }

    /// What a journal records of these inputs; empty without any (so journals
    /// of runs without them keep their settings).
    pub fn settings(&self) -> String {
        let mut s = String::new();
        if let Some(m) = &self.mask {
            s.push_str(&format!(" mask={:016x}", m.content_hash));
        }
        if let Some((_, hash)) = &self.initial {
            s.push_str(&format!(" initial={hash:016x}"));
        }
        s
    }
}

/// A pyramid seen moved by `shift_m` and through `mask`.
pub struct ViewedPyramid<'m, P> {
    pub inner: P,
    pub shift_m: Vector3<f64>,
    pub mask: Option<&'m StableMask>,
}

impl<P: Pyramid> Pyramid for ViewedPyramid<'_, P> {
    type Level<'a>
        = ViewedGrid<'a, P::Level<'a>>
    where
        Self: 'a;

    fn num_levels(&self) -> usize {
        self.inner.num_levels()
    }

    fn open_level(&self, level: usize) -> Result<Self::Level<'_>, GridError> {
        let inner = self.inner.open_level(level)?;
        let g = inner.geotransform().0;
        let s = &self.shift_m;
        let geotransform = GeoTransform([g[0] + s.x, g[1], g[2], g[3] + s.y, g[4], g[5]]);
        let (width, height) = (inner.width(), inner.height());
        Ok(ViewedGrid {
            inner,
            geotransform,
            dz_m: s.z as f32,
            lookup: self.mask.map(|m| m.lookup(&geotransform, width, height)),
        })
    }
}

/// One level of a [`ViewedPyramid`].
pub struct ViewedGrid<'a, G> {
    inner: G,
    geotransform: GeoTransform,
    dz_m: f32,
    lookup: Option<MaskLookup<'a>>,
}

impl<G: Grid> Grid for ViewedGrid<'_, G> {
    fn width(&self) -> i64 {
        self.inner.width()
    }
    fn height(&self) -> i64 {
        self.inner.height()
    }
    fn geotransform(&self) -> GeoTransform {
        self.geotransform
    }
    #[inline]
    fn get(&mut self, col: i64, row: i64) -> f32 {
        let h = self.inner.get(col, row);
        match &self.lookup {
            Some(l) if !h.is_nan() && !l.is_stable(col, row) => f32::NAN,
            _ => h + self.dz_m,
        }
    }
    fn take_error(&mut self) -> Option<GridError> {
        self.inner.take_error()
    }
    fn read_window(&mut self, col0: i64, row0: i64, w: usize, h: usize) -> Vec<f32> {
        let mut out = self.inner.read_window(col0, row0, w, h);
        let Some(l) = &self.lookup else {
            out.iter_mut().for_each(|v| *v += self.dz_m);
            return out;
        };
        for (row, line) in (row0..).zip(out.chunks_exact_mut(w.max(1))) {
            for (col, v) in (col0..).zip(line) {
                if !v.is_nan() && !l.is_stable(col, row) {
                    *v = f32::NAN;
                } else {
                    *v += self.dz_m;
                }
            }
        }
        out
    }
}

/// A result between two views in the DSMs' own coordinates (module doc).
pub fn to_raw_frames(
    mut result: IcpResult,
    shift_ref_m: &Vector3<f64>,
    shift_moving_m: &Vector3<f64>,
) -> IcpResult {
    let s_ref_inv = Isometry3::translation(-shift_ref_m.x, -shift_ref_m.y, -shift_ref_m.z);
    let s_moving = Isometry3::translation(shift_moving_m.x, shift_moving_m.y, shift_moving_m.z);
    result.t_ref_moving = s_ref_inv * result.t_ref_moving * s_moving;
    if let Some(info) = result.information.as_mut() {
        info.centroid -= shift_ref_m;
    }
    for k in 0..3 {
        result.centre_m[k] -= shift_ref_m[k];
    }
    result
}

/// FNV-1a (64 bit) of `bytes`: identifies an input file's content in a
/// journal's settings.
pub fn content_hash(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{MemGrid, MemPyramid};
    use crate::mask::{BitPyramid, BitRaster};

    fn pyramid() -> MemPyramid {
        let gt = GeoTransform::north_up(1000.0, 2000.0, 1.0, 1.0);
        MemPyramid::build(MemGrid::from_fn(8, 8, gt, |c, r| (10 * r + c) as f32), 4)
    }

    #[test]
    fn a_view_moves_the_lattice_and_the_heights_and_masks_cells() {
        // stable: x < 1004 (the western half of the DSM once moved 2 m east)
        let mut bits = BitRaster::new(GeoTransform::north_up(1000.0, 2000.0, 1.0, 1.0), 4, 8);
        (0..8).for_each(|r| (0..4).for_each(|c| bits.set(c, r)));
        let mask = StableMask {
            path: "m.tif".into(),
            content_hash: 7,
            pyramid: BitPyramid::build(bits),
        };
        let view = ViewedPyramid {
            inner: pyramid(),
            shift_m: Vector3::new(2.0, -1.0, 0.5),
            mask: Some(&mask),
        };
        let mut level = view.open_level(0).unwrap();
        assert_eq!(level.geotransform().0[0], 1002.0);
        assert_eq!(level.geotransform().0[3], 1999.0);
        assert_eq!(level.get(1, 3), 31.5);
        assert!(level.get(2, 3).is_nan(), "moved onto x = 1004..1005");
        let unmasked = PairInputs::default();
        assert_eq!(
            unmasked.view(pyramid(), 0).open_level(0).unwrap().get(7, 7),
            77.0
        );
        // a window reads as pixel by pixel: moved, masked, NaN off the raster
        let window = level.read_window(-1, 2, 10, 3);
        for (i, v) in window.iter().enumerate() {
            let (col, row) = (-1 + (i % 10) as i64, 2 + (i / 10) as i64);
            let one = level.get(col, row);
            assert!(*v == one || (v.is_nan() && one.is_nan()), "({col}, {row})");
        }
        assert!(window.iter().any(|v| v.is_nan()) && window.iter().any(|v| !v.is_nan()));
    }

    #[test]
    fn a_result_between_views_is_returned_in_the_dsms_own_coordinates() {
        // raw: the moving DSM's points are 3 m west of the reference's
        let t_raw = Isometry3::translation(3.0, 0.0, 0.0);
        let (s_ref, s_mov) = (Vector3::new(0.5, 0.0, 0.0), Vector3::new(2.5, 0.0, 1.0));
        // between the views: p_ref + s_ref = Δ (p_mov + s_mov)
        let delta = Isometry3::translation(s_ref.x, s_ref.y, s_ref.z)
            * t_raw
            * Isometry3::translation(-s_mov.x, -s_mov.y, -s_mov.z);
        assert!((delta.translation.vector - Vector3::new(1.0, 0.0, -1.0)).norm() < 1e-12);
        let r = IcpResult::converged_at(delta, [10.0, 0.0, 0.0]);
        let raw = to_raw_frames(r, &s_ref, &s_mov);
        assert!((raw.t_ref_moving.translation.vector - t_raw.translation.vector).norm() < 1e-12);
        assert_eq!(raw.centre_m, [9.5, 0.0, 0.0]);
    }

    #[test]
    fn the_settings_name_only_the_inputs_given() {
        assert_eq!(PairInputs::default().settings(), "");
        let inputs = PairInputs {
            initial: Some(("p.json".into(), 255)),
            ..Default::default()
        };
        assert_eq!(inputs.settings(), " initial=00000000000000ff");
        assert_ne!(content_hash(b"a"), content_hash(b"b"));
    }
}
