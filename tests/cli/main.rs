//! The integration tests: every command run as the built binary on the
//! repository's fixtures and on collections generated at test time. One test
//! binary, one module per topic, helpers in `util`.

mod util;

mod align;
mod align_journal;
mod coarse;
mod codem;
mod corner;
mod demo;
mod dsmgen;
mod eco;
mod eco2;
mod faults;
mod fuse_eval;
mod fuzz;
mod grids;
mod icpwire;
mod ingest;
mod ingest4;
mod narrow;
mod outputs;
mod pair_real;
mod pair_recovery;
mod pose_sigma;
mod readme;
mod real_split;
mod resume;
mod scale3;
mod shard;
mod store_reliability;
mod ttp_collection;
mod ttp_lidar;
