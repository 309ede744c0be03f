//! What every command shares: the resource flags (`--cache-mb`, `--threads`)
//! with their one validation, the one way a library error becomes "the user's
//! fault" (exit code 2), opening a store and finding a DSM in it, the progress
//! report ([`progress_bar`]), and writing to stdout so that a closed pipe ends the command quietly.

use std::io::{IsTerminal, Write};
use std::path::Path;

use dsmstream::cache::ChunkCache;
use dsmstream::store::Store;
use dsmstream::InputError;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use super::progress::plain_interval;
pub use super::progress::Progress;

/// Largest `--threads` accepted: more threads than this only exhaust memory
/// (each has its own stack) and never run faster.
pub const MAX_THREADS: u64 = 1024;
/// Largest `--cache-mb` accepted (1 TiB).
pub const MAX_CACHE_MB: u64 = 1 << 20;

/// Memory and CPU flags shared by every command that reads the store.
#[derive(clap::Args, Debug, Clone)]
pub struct ResourceArgs {
    /// Chunk cache budget in MiB, shared by all workers (1 to 1048576).
    #[arg(long, default_value_t = 256, value_parser = clap::value_parser!(u64).range(1..=MAX_CACHE_MB))]
    pub cache_mb: u64,
    /// Worker threads (default: all cores; 1 to 1024).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=MAX_THREADS))]
    pub threads: Option<u64>,
}

impl Default for ResourceArgs {
    /// The flags as if none were given.
    fn default() -> Self {
        ResourceArgs {
            cache_mb: 256,
            threads: None,
        }
    }
}

impl ResourceArgs {
    /// `--threads`, or every core the process may use.
    pub fn threads(&self) -> usize {
        match self.threads {
            Some(n) => n as usize,
            None => all_cores(),
        }
    }

    /// A chunk cache of `--cache-mb` MiB.
    pub fn cache(&self) -> ChunkCache {
        ChunkCache::new((self.cache_mb as usize) << 20)
    }

    /// A rayon pool of `--threads` threads, for commands whose library call
    /// uses the current pool.
    pub fn pool(&self) -> anyhow::Result<rayon::ThreadPool> {
        Ok(rayon::ThreadPoolBuilder::new()
            .num_threads(self.threads())
            .build()?)
    }
}

/// Every core the process may use.
pub fn all_cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// A library error as `anyhow`, wrapped in [`InputError`] (exit code 2) when
/// `bad_input` says the user's input caused it.
pub fn classify<E>(e: E, bad_input: impl FnOnce(&E) -> bool) -> anyhow::Error
where
    E: std::error::Error + Send + Sync + 'static,
{
    if bad_input(&e) {
        anyhow::Error::new(InputError::new(e.to_string()))
    } else {
        anyhow::Error::new(e)
    }
}

/// Opens a store, mapping problems with it to bad input (exit 2).
pub fn open_store(path: &Path) -> anyhow::Result<Store> {
    Store::open(path).map_err(|e| classify(e, |e| e.is_bad_input()))
}

/// Index of a DSM id, or a bad-input error listing what exists.
pub fn find_dsm(store: &Store, id: &str) -> anyhow::Result<usize> {
    store.find(id).ok_or_else(|| {
        let known: Vec<&str> = store
            .dsms()
            .iter()
            .map(|d| d.id.as_str())
            .take(10)
            .collect();
        InputError::new(format!(
            "{}: no DSM with id '{id}' (known: {}{})",
            store.root().display(),
            known.join(", "),
            if store.dsms().len() > 10 { ", ..." } else { "" }
        ))
        .into()
    })
}

/// Refuses (exit 2) an input file that does not exist or is not a file,
/// before any work starts.
pub fn require_file(path: &Path, flag: &str) -> anyhow::Result<()> {
    match std::fs::metadata(path) {
        Ok(m) if m.is_file() => Ok(()),
        Ok(_) => Err(InputError::new(format!("{}: {flag} is not a file", path.display())).into()),
        Err(e) => Err(InputError::new(format!("{}: {flag}: {e}", path.display())).into()),
    }
}

/// Refuses (exit 2) a store folder this process cannot write: the store (or,
/// when absent, the nearest existing parent) must take a probe file.
pub fn require_writable_dir(path: &Path) -> anyhow::Result<()> {
    let mut dir = path;
    while !dir.exists() {
        match dir.parent() {
            Some(p) if !p.as_os_str().is_empty() => dir = p,
            _ => return Ok(()),
        }
    }
    if !dir.is_dir() {
        return Ok(()); // the library names what is wrong with a non-folder
    }
    let probe = dir.join(format!(
        "{}{}",
        dsmstream::store::WRITE_PROBE_PREFIX,
        std::process::id()
    ));
    match std::fs::File::create(&probe) {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(InputError::new(format!(
            "{}: the store is read-only for this user ({e})",
            dir.display()
        ))
        .into()),
    }
}

/// The one progress report of the long commands ([`Progress`]): on a
/// terminal the bar `{bar} pos/len <unit> rate eta msg`; otherwise plain
/// lines every `DSMSTREAM_PROGRESS_SECS` (default 10 s); nothing with `-q`.
pub fn progress_bar(unit: &str) -> Progress {
    let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr());
    let template = format!("{{bar:30}} {{pos}}/{{len}} {unit} {{per_sec}} eta {{eta}} {{msg}}");
    bar.set_style(ProgressStyle::with_template(&template).expect("valid template"));
    if quiet() {
        bar.set_draw_target(ProgressDrawTarget::hidden());
        return Progress::new(bar, unit, None);
    }
    let plain = (!std::io::stderr().is_terminal())
        .then(plain_interval)
        .flatten();
    Progress::new(bar, unit, plain)
}

/// Only the plain lines of [`progress_bar`] (none on a terminal or with `-q`),
/// for `ingest`, which draws its terminal bars through tracing spans.
pub fn plain_progress(unit: &str) -> Progress {
    let plain = (!quiet() && !std::io::stderr().is_terminal())
        .then(plain_interval)
        .flatten();
    Progress::new(ProgressBar::hidden(), unit, plain)
}

/// `warning: <text>` on stderr, unless `-q` asked for errors only.
pub fn warn_line(text: &str) {
    if !quiet() {
        eprintln!("warning: {text}");
    }
}

/// True when `-q` asked for errors only.
pub fn quiet() -> bool {
    !tracing::enabled!(tracing::Level::WARN)
}

/// Writes `text` to stdout through a locked handle. A reader that went away
/// (`| head`) surfaces as an `io::Error` of kind `BrokenPipe`, which `main`
/// treats as success.
pub fn emit(text: &str) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())?;
    out.flush()
}

/// [`emit`] with a newline.
pub fn emit_line(line: &str) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")?;
    out.flush()
}

/// True when the error chain holds a closed stdout pipe.
pub fn is_broken_pipe(err: &anyhow::Error) -> bool {
    err.chain().any(|e| {
        e.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser, Debug)]
    struct T {
        #[command(flatten)]
        r: ResourceArgs,
    }

    #[test]
    fn zero_or_absurd_resources_are_refused_at_parse_time() {
        for bad in [
            &["t", "--cache-mb", "0"][..],
            &["t", "--threads", "0"],
            &["t", "--threads", "100000"],
            &["t", "--cache-mb", "2000000"],
        ] {
            let err = T::try_parse_from(bad).unwrap_err();
            assert_eq!(err.exit_code(), 2, "{bad:?}");
        }
        let ok = T::try_parse_from(["t", "--threads", "3", "--cache-mb", "1"]).unwrap();
        assert_eq!((ok.r.threads(), ok.r.cache_mb), (3, 1));
        let none = T::try_parse_from(["t"]).unwrap().r;
        assert!(none.threads() >= 1);
        assert_eq!(
            format!("{none:?}"),
            format!("{:?}", ResourceArgs::default())
        );
    }

    #[test]
    fn a_missing_file_or_unwritable_folder_is_bad_input() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nope.json");
        let err = require_file(&missing, "--poses").unwrap_err();
        assert!(err.downcast_ref::<InputError>().is_some());
        assert!(err.to_string().contains("nope.json"), "{err}");
        require_file(dir.path(), "--poses").unwrap_err();
        require_writable_dir(&dir.path().join("a/b/new.zarr")).unwrap();
        assert!(std::fs::read_dir(dir.path()).unwrap().next().is_none());
    }

    #[test]
    fn broken_pipe_is_found_in_the_chain() {
        let e = anyhow::Error::new(std::io::Error::from(std::io::ErrorKind::BrokenPipe))
            .context("printing");
        assert!(is_broken_pipe(&e));
        assert!(!is_broken_pipe(&anyhow::anyhow!("other")));
    }
}
