//! The integration tests: every command run as the built binary on the
//! repository's fixtures and on collections generated at test time. One test
//! binary, one module per topic, helpers in `util`.

mod util;

mod align;
mod demo;
mod fuse_eval;
mod ingest;
mod pair_real;
mod pair_recovery;
mod readme;
mod resume;
mod ttp_collection;
