//! A worker's view of the collection for eval: every DSM's corrected surface
//! (level 0, through the chunk cache), opened on first use, before (identity)
//! and after (the poses), and the fused surface = the per-pixel median of the
//! corrected heights of the DSMs covering a point (what `fuse --method median`
//! writes).

use crate::cache::ChunkCache;
use crate::fuse::layout::{FootprintIndex, PlacedDsm};
use crate::fuse::{CorrectedSurface, PoseXf};
use crate::store::{Store, StoreError, StoreGrid};

use super::EvalError;

/// The DSMs of a store placed by one set of poses, with their footprint index.
pub struct Placement<'a> {
    pub poses: &'a [PoseXf],
    pub placed: Vec<PlacedDsm>,
    pub index: FootprintIndex,
}

impl<'a> Placement<'a> {
    pub fn new(store: &Store, poses: &'a [PoseXf]) -> Placement<'a> {
        let placed: Vec<PlacedDsm> = store
            .dsms()
            .iter()
            .enumerate()
            .map(|(i, m)| PlacedDsm::new(i, m, &poses[i]))
            .collect();
        Placement {
            poses,
            index: FootprintIndex::new(&placed),
            placed,
        }
    }
}

/// Lazily opened corrected surfaces of one placement (one per worker).
pub struct Surfaces<'a> {
    store: &'a Store,
    cache: &'a ChunkCache,
    placement: &'a Placement<'a>,
    open: Vec<Option<CorrectedSurface<'a, StoreGrid<'a>>>>,
    slots: Vec<usize>,
    values: Vec<f32>,
}

impl<'a> Surfaces<'a> {
    pub fn new(store: &'a Store, cache: &'a ChunkCache, placement: &'a Placement<'a>) -> Self {
        Surfaces {
            store,
            cache,
            placement,
            open: (0..store.dsms().len()).map(|_| None).collect(),
            slots: Vec::new(),
            values: Vec::new(),
        }
    }

    /// Corrected height of DSM `dsm` at world (x, y); NaN where it has none.
    pub fn height(&mut self, dsm: usize, x: f64, y: f64) -> Result<f64, EvalError> {
        Ok(self.surface(dsm)?.height_at(x, y))
    }

    /// The corrected position M (x, y, h) of the DSM point whose uncorrected
    /// position is (x, y) (a pixel centre reads the pixel itself); None on no-data.
    pub fn moved_point(
        &mut self,
        dsm: usize,
        x: f64,
        y: f64,
    ) -> Result<Option<[f64; 3]>, EvalError> {
        let pose = &self.placement.poses[dsm];
        let h = self.surface(dsm)?.bilinear(x, y);
        Ok((!h.is_nan()).then(|| pose.apply([x, y, h])))
    }

    fn surface(
        &mut self,
        dsm: usize,
    ) -> Result<&mut CorrectedSurface<'a, StoreGrid<'a>>, EvalError> {
        if self.open[dsm].is_none() {
            let grid = StoreGrid::new(self.store, self.cache, dsm, 0)?;
            let p = &self.placement.placed[dsm];
            self.open[dsm] = Some(CorrectedSurface::new(
                grid,
                &self.placement.poses[dsm],
                p.z_start_m,
            ));
        }
        Ok(self.open[dsm].as_mut().expect("opened above"))
    }

    /// Median of the corrected heights of every DSM covering (x, y); NaN if none.
    pub fn fused_height(&mut self, x: f64, y: f64) -> Result<f64, EvalError> {
        let mut slots = std::mem::take(&mut self.slots);
        self.placement.index.at_point(x, y, &mut slots);
        self.values.clear();
        for &slot in &slots {
            let dsm = self.placement.placed[slot].index;
            let h = self.height(dsm, x, y)?;
            if !h.is_nan() {
                self.values.push(h as f32);
            }
        }
        self.slots = slots;
        Ok(crate::fuse::FuseMethod::Median.combine(&mut self.values) as f64)
    }

    /// The first chunk read error of any open surface.
    pub fn take_error(&mut self) -> Option<StoreError> {
        for (dsm, s) in self.open.iter_mut().enumerate() {
            if let Some(e) = s.as_mut().and_then(|s| s.grid_mut().take_chunk_error()) {
                return Some(self.store.chunk_error(dsm, e));
            }
        }
        None
    }
}
