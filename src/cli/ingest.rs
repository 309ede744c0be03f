//! `dsmstream ingest`: convert GeoTIFF DSMs into the collection store, with a
//! progress bar (rows read, through tracing-indicatif, hidden by `-q`; plain
//! lines of DSMs done when stderr is not a terminal) and one
//! summary line per DSM on stdout.

use std::cell::RefCell;
use std::path::PathBuf;

use dsmstream::store::ingest::{DsmAction, DsmOutcome, IngestProgress};
use dsmstream::store::{ingest, Compression, IngestOptions, StorageSettings};
use tracing_indicatif::span_ext::IndicatifSpanExt;

use super::common::{classify, emit_line, plain_progress, quiet, require_writable_dir, Progress};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// GeoTIFF files, or directories whose *.tif / *.tiff files are all taken.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// The store directory (created if absent), e.g. collection.zarr.
    #[arg(long)]
    pub store: PathBuf,
    /// Square chunk side in pixels.
    #[arg(long, default_value_t = 512)]
    pub chunk: u64,
    /// Chunk compression: zstd (level 1), zstd:<level>, or none.
    #[arg(long, default_value = "zstd", value_parser = parse_compression)]
    pub compression: Compression,
    /// Re-ingest DSMs even when their source is unchanged.
    #[arg(long)]
    pub force: bool,
}

fn parse_compression(text: &str) -> Result<Compression, String> {
    Compression::parse(text)
        .ok_or_else(|| format!("unknown compression {text:?} (zstd, zstd:<level>, none)"))
}

/// A progress bar per DSM, as a tracing span (so log lines do not tear it),
/// and the plain lines (DSMs done) when stderr is not a terminal.
struct BarProgress {
    span: RefCell<Option<tracing::Span>>,
    lines: Progress,
}

impl IngestProgress for BarProgress {
    fn dsm_started(&self, id: &str, rows_total: u64) {
        let span = tracing::warn_span!("ingest", dsm = %id);
        if let Ok(style) = indicatif::ProgressStyle::with_template(
            "{span_child_prefix}{spinner} {span_name}{{{span_fields}}} [{bar:30}] {pos}/{len} rows {elapsed}<{eta}",
        ) {
            span.pb_set_style(&style.progress_chars("=> "));
        }
        span.pb_set_length(rows_total);
        span.pb_start();
        self.lines
            .set_message(format!("reading {id} ({rows_total} rows)"));
        *self.span.borrow_mut() = Some(span);
    }

    fn rows_done(&self, rows: u64) {
        if let Some(span) = self.span.borrow().as_ref() {
            span.pb_inc(rows);
        }
    }

    fn dsm_finished(&self, outcome: &DsmOutcome) {
        self.span.borrow_mut().take();
        self.lines.inc(1);
        if quiet() {
            return;
        }
        let line = summary_line(outcome);
        // a closed stdout surfaces again at the command's last line
        tracing_indicatif::suspend_tracing_indicatif(|| {
            let _ = emit_line(&line);
        });
    }
}

fn summary_line(o: &DsmOutcome) -> String {
    let action = match o.action {
        DsmAction::Ingested => "ingested",
        DsmAction::Replaced => "replaced",
        DsmAction::Skipped => "skipped ",
    };
    let valid_pct = 100.0 * o.valid_count as f64 / (o.width * o.height).max(1) as f64;
    let tail = if o.action == DsmAction::Skipped {
        "unchanged".to_string()
    } else {
        format!("{:.1} s", o.seconds)
    };
    let plural = if o.levels == 1 { "" } else { "s" };
    format!(
        "{action} {}: {} x {} px, {valid_pct:.1}% valid, {} level{plural}, {:.1} MB stored, {tail}",
        o.id,
        o.width,
        o.height,
        o.levels,
        o.stored_bytes as f64 / 1e6
    )
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let options = IngestOptions {
        storage: StorageSettings {
            chunk: args.chunk,
            compression: args.compression,
            ..Default::default()
        },
        force: args.force,
    };
    require_writable_dir(&args.store)?;
    let progress = BarProgress {
        span: RefCell::new(None),
        lines: plain_progress("DSMs"),
    };
    let report = ingest(&args.inputs, &args.store, &options, &progress)
        .map_err(|e| classify(e, |e| e.is_bad_input()))?;
    progress.lines.finish_and_clear();
    let count = |a: DsmAction| report.outcomes.iter().filter(|o| o.action == a).count();
    emit_line(&format!(
        "{}: {} ingested, {} replaced, {} skipped",
        report.store.display(),
        count(DsmAction::Ingested),
        count(DsmAction::Replaced),
        count(DsmAction::Skipped)
    ))?;
    Ok(())
}
