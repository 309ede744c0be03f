//! The zarrs arrays a [`Store`](super::Store) has opened, at most
//! [`MAX_OPEN_ARRAYS`] of them: an opened array holds its parsed metadata
//! (about 10 KB), so keeping every one of 10^4 DSMs open cost ~100 MB and grew
//! with the collection. The oldest opened is dropped first (readers keep their
//! own `Arc` as long as they use it; a dropped array is reopened from its
//! `zarr.json` when asked for again).

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use super::LevelArray;

/// Arrays kept open: more than the DSMs a run touches at once (pairs are
/// processed in spatial order), ~40 MB of metadata.
pub const MAX_OPEN_ARRAYS: usize = 4096;

/// (DSM index, level) -> opened array, bounded, first in first out.
pub struct OpenArrays {
    map: HashMap<(usize, usize), Arc<LevelArray>>,
    order: VecDeque<(usize, usize)>,
    capacity: usize,
}

impl OpenArrays {
    pub fn new(capacity: usize) -> OpenArrays {
        OpenArrays {
            map: HashMap::new(),
            order: VecDeque::new(),
            capacity: capacity.max(1),
        }
    }

    pub fn get(&self, key: (usize, usize)) -> Option<Arc<LevelArray>> {
        self.map.get(&key).cloned()
    }

    /// Keeps `array` under `key`, dropping the oldest entries beyond the capacity.
    pub fn insert(&mut self, key: (usize, usize), array: Arc<LevelArray>) {
        if self.map.insert(key, array).is_none() {
            self.order.push_back(key);
        }
        while self.map.len() > self.capacity {
            match self.order.pop_front() {
                Some(old) => {
                    self.map.remove(&old);
                }
                None => break,
            }
        }
    }

    #[cfg(test)]
    fn len(&self) -> usize {
        self.map.len()
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests_support::{options, run, surface, utm, Inputs};
    use super::*;
    use crate::store::Store;

    #[test]
    fn the_oldest_arrays_are_dropped_beyond_the_capacity() {
        let mut inputs = Inputs::new();
        let a = inputs.add("a.tif", 40, 40, utm(26917), surface(40, 40, 1));
        let store_dir = tempfile::tempdir().unwrap();
        let store_path = store_dir.path().join("c.zarr");
        run(&inputs, &[a], &store_path, &options(16)).unwrap();
        let store = Store::open(&store_path).unwrap();
        let levels = store.dsms()[0].levels.len();
        assert!(levels >= 3, "{levels} levels");
        let mut open = OpenArrays::new(2);
        for level in 0..3 {
            open.insert((0, level), store.array(0, level).unwrap());
            open.insert((0, level), store.array(0, level).unwrap()); // again: kept once
        }
        assert_eq!(open.len(), 2);
        assert!(open.get((0, 0)).is_none());
        assert!(open.get((0, 1)).is_some() && open.get((0, 2)).is_some());
        // the store itself reopens what it dropped
        assert_eq!(store.array(0, 0).unwrap().shape(), &[40, 40]);
    }
}
