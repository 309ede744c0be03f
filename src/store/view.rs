//! A DSM of the store seen as a [`Pyramid`]: every level opens a [`StoreGrid`]
//! that reads through the shared chunk cache.

use crate::cache::ChunkCache;
use crate::grid::{GridError, Pyramid};
use crate::store::{Store, StoreGrid};

/// All levels of one DSM of a store, read through `cache`.
pub struct StorePyramid<'a> {
    pub store: &'a Store,
    pub cache: &'a ChunkCache,
    pub dsm: usize,
}

impl<'a> StorePyramid<'a> {
    pub fn new(store: &'a Store, cache: &'a ChunkCache, dsm: usize) -> Self {
        StorePyramid { store, cache, dsm }
    }
}

impl Pyramid for StorePyramid<'_> {
    type Level<'b>
        = StoreGrid<'b>
    where
        Self: 'b;

    fn num_levels(&self) -> usize {
        self.store.dsms()[self.dsm].levels.len()
    }

    fn open_level(&self, level: usize) -> Result<StoreGrid<'_>, GridError> {
        Ok(StoreGrid::new(self.store, self.cache, self.dsm, level)?)
    }
}
