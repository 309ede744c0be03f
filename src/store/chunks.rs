//! [`ChunkRecord`]: which chunks of a DSM were written. The writer skips
//! chunks without a valid pixel (Zarr's fill value covers them), so without a
//! record a deleted chunk file would read as no-data. The record keeps, per
//! level, the row-major chunk indices that are empty as runs `[first, count]`
//! (a void is a few runs per chunk row, so the record stays small even for a
//! rotated satellite strip); every other chunk must have a file.

use serde::{Deserialize, Serialize};

use super::catalog::LevelMeta;

/// Empty chunks of every level of one DSM.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ChunkRecord {
    /// Per level, sorted non-overlapping runs `[first, count]` of the
    /// row-major indices (`chunk_y * chunks_x + chunk_x`) of empty chunks.
    pub empty_runs: Vec<Vec<[u64; 2]>>,
}

/// Chunks across and down of a level.
pub fn chunk_grid(level: &LevelMeta) -> (u64, u64) {
    let c = level.chunk.max(1);
    (level.width.div_ceil(c), level.height.div_ceil(c))
}

impl ChunkRecord {
    /// True when chunk (chunk_y, chunk_x) of `level` holds no valid pixel
    /// (and so has no file).
    pub fn is_empty(&self, level: usize, chunks_x: u64, chunk_y: u64, chunk_x: u64) -> bool {
        let Some(runs) = self.empty_runs.get(level) else {
            return false;
        };
        let index = chunk_y * chunks_x + chunk_x;
        let after = runs.partition_point(|r| r[0] <= index);
        after > 0 && index < runs[after - 1][0] + runs[after - 1][1]
    }

    /// Empty chunks of `level`.
    pub fn empty_count(&self, level: usize) -> u64 {
        self.empty_runs
            .get(level)
            .map_or(0, |runs| runs.iter().map(|r| r[1]).sum())
    }

    /// Check the record against the levels: one list per level, runs sorted,
    /// non-empty, non-overlapping and inside the level's chunk grid.
    pub fn check(&self, levels: &[LevelMeta]) -> Result<(), String> {
        if self.empty_runs.len() != levels.len() {
            return Err(format!(
                "chunk record has {} levels, the DSM {}",
                self.empty_runs.len(),
                levels.len()
            ));
        }
        for (k, (runs, level)) in self.empty_runs.iter().zip(levels).enumerate() {
            let (cx, cy) = chunk_grid(level);
            let total = cx * cy;
            let mut next_free = 0u64;
            for r in runs {
                let end = r[0].checked_add(r[1]);
                if r[1] == 0 || r[0] < next_free || end.is_none_or(|e| e > total) {
                    return Err(format!(
                        "chunk record of level {k}: run {r:?} is empty, unsorted, overlapping or past the {total} chunks"
                    ));
                }
                next_free = r[0] + r[1];
            }
        }
        Ok(())
    }
}

/// Collects the empty chunk indices of one level (in any order) into runs.
#[derive(Clone, Debug, Default)]
pub struct EmptyChunks(Vec<u64>);

impl EmptyChunks {
    pub fn add(&mut self, index: u64) {
        self.0.push(index);
    }

    pub fn into_runs(mut self) -> Vec<[u64; 2]> {
        self.0.sort_unstable();
        self.0.dedup();
        let mut runs: Vec<[u64; 2]> = Vec::new();
        for i in self.0 {
            match runs.last_mut() {
                Some(r) if r[0] + r[1] == i => r[1] += 1,
                _ => runs.push([i, 1]),
            }
        }
        runs
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn level(w: u64, h: u64, chunk: u64) -> LevelMeta {
        LevelMeta {
            width: w,
            height: h,
            chunk,
        }
    }

    #[test]
    fn runs_round_trip_and_lookup() {
        let mut e = EmptyChunks::default();
        for i in [7, 2, 3, 4, 9, 3] {
            e.add(i);
        }
        let runs = e.into_runs();
        assert_eq!(runs, vec![[2, 3], [7, 1], [9, 1]]);
        let record = ChunkRecord {
            empty_runs: vec![runs],
        };
        let levels = [level(100, 60, 20)]; // 5 x 3 chunks
        record.check(&levels).unwrap();
        let empty: Vec<u64> = (0..15)
            .filter(|&i| record.is_empty(0, 5, i / 5, i % 5))
            .collect();
        assert_eq!(empty, vec![2, 3, 4, 7, 9]);
        assert_eq!(record.empty_count(0), 5);
        assert!(!record.is_empty(1, 5, 0, 0), "no such level: not empty");
    }

    #[test]
    fn bad_records_are_refused() {
        let levels = [level(100, 60, 20)];
        for runs in [
            vec![[0, 0]],
            vec![[3, 2], [4, 1]],
            vec![[14, 2]],
            vec![[u64::MAX, 2]],
        ] {
            let r = ChunkRecord {
                empty_runs: vec![runs.clone()],
            };
            assert!(r.check(&levels).is_err(), "{runs:?}");
        }
        let r = ChunkRecord {
            empty_runs: vec![vec![], vec![]],
        };
        assert!(r.check(&levels).is_err());
    }
}
