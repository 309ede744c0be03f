//! `dsmstream ingest`: convert GeoTIFF DSMs (or VRT mosaics of them) into the
//! collection store, with a progress bar (rows read, through tracing-indicatif,
//! hidden by `-q`; plain lines of DSMs done when stderr is not a terminal) and
//! one summary line per DSM on stdout. `@LIST` inputs are expanded here.

use std::cell::RefCell;
use std::path::PathBuf;

use dsmstream::store::ingest::{DsmAction, DsmOutcome, IngestProgress};
use dsmstream::store::warp::{CrsChoice, ZoneChoice};
use dsmstream::store::{ingest, Compression, IngestOptions, StorageSettings};
use dsmstream::InputError;
use tracing_indicatif::span_ext::IndicatifSpanExt;

use super::common::{
    classify, emit_line, plain_progress, quiet, require_writable_dir, warn_line, Progress,
};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// GeoTIFF files, GDAL VRT mosaics of GeoTIFFs (*.vrt, each one DSM named
    /// after the VRT), directories whose *.tif / *.tiff files are all taken, or
    /// @LIST: a text file naming one input per line (blank lines and # comments
    /// skipped; relative paths from the list file's folder).
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
    /// The UTM zone DSMs in longitude and latitude or in other projected
    /// CRSs are put into, e.g. 37N or 33S (default: the collection's CRS,
    /// else the zone of their centre).
    #[arg(long, value_parser = parse_zone, conflicts_with = "crs")]
    pub utm_zone: Option<ZoneChoice>,
    /// The CRS they are put into instead, by EPSG code: a UTM zone or one of
    /// the national and polar grids dsmstream knows, e.g. EPSG:3413.
    #[arg(long, value_parser = parse_crs)]
    pub crs: Option<CrsChoice>,
}

fn parse_crs(text: &str) -> Result<CrsChoice, String> {
    CrsChoice::parse_epsg(text).ok_or_else(|| {
        format!("not a CRS dsmstream can put DSMs into: {text:?} (an EPSG code of a UTM zone or of the grids the README lists, e.g. EPSG:3413)")
    })
}

fn parse_zone(text: &str) -> Result<ZoneChoice, String> {
    ZoneChoice::parse(text)
        .ok_or_else(|| format!("not a UTM zone: {text:?} (1N to 60N, 1S to 60S, e.g. 37N)"))
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
    fn planned(&self, dsms: usize) {
        self.lines.set_length(dsms as u64);
    }

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
    let names: Vec<String> = (o.georeferenced_by.iter())
        .filter_map(|p| Some(p.file_name()?.to_string_lossy().into_owned()))
        .collect();
    let tail = match names.is_empty() {
        true => tail,
        false => format!("{tail}; georeferenced by {}", names.join(", ")),
    };
    let tail = match &o.warped {
        None => tail,
        Some(w) => format!(
            "{tail}; reprojected from {} to {} at {} m (bilinear{})",
            w.from,
            w.to,
            w.pixel_m,
            (w.datum.as_ref()).map_or(String::new(), |d| format!("; {d}"))
        ),
    };
    format!(
        "{action} {}: {} x {} px, {valid_pct:.1}% valid, {} level{plural}, {:.1} MB stored, {tail}",
        o.id,
        o.width,
        o.height,
        o.levels,
        o.stored_bytes as f64 / 1e6
    )
}

/// GeoTIFF VerticalCSTypeGeoKey and VerticalCitationGeoKey.
const VERTICAL_CS_KEY: u16 = 4096;
const VERTICAL_CITATION_KEY: u16 = 4097;

/// What a DSM's CRS says about its heights: "EPSG:<code>", "declared" (a
/// vertical citation or a compound WKT without a code), or "none".
fn vertical_reference(crs: &dsmstream::geo::Crs) -> String {
    let keys = &crs.geokeys;
    let n = keys
        .get(3)
        .map_or(0, |&n| n as usize)
        .min(keys.len().saturating_sub(4) / 4);
    let entry = |id: u16| {
        (0..n)
            .map(|i| &keys[4 + 4 * i..8 + 4 * i])
            .find(|e| e[0] == id)
    };
    if let Some(e) = entry(VERTICAL_CS_KEY).filter(|e| e[1] == 0 && e[3] != 32767) {
        return format!("EPSG:{}", e[3]);
    }
    let wkt = crs.wkt.as_deref().unwrap_or("");
    let compound = ["VERTCRS", "VERT_CS", "COMPD_CS", "COMPOUNDCRS"]
        .iter()
        .any(|k| wkt.contains(k));
    if entry(VERTICAL_CS_KEY).is_some() || entry(VERTICAL_CITATION_KEY).is_some() || compound {
        return "declared".to_string();
    }
    "none".to_string()
}

/// Warns when the store's DSMs do not all state the same vertical reference
/// (say ellipsoidal heights for one, nothing for another): their heights may
/// differ by the geoid undulation, tens of metres, which registration absorbs
/// as a vertical shift.
fn warn_mixed_vertical(store: &std::path::Path) {
    let Ok(store) = dsmstream::store::Store::open(store) else {
        return;
    };
    let mut groups: std::collections::BTreeMap<String, Vec<&str>> = Default::default();
    for d in store.dsms() {
        groups
            .entry(vertical_reference(&d.crs))
            .or_default()
            .push(&d.id);
    }
    if groups.len() > 1 {
        let parts: Vec<String> = groups
            .iter()
            .map(|(v, ids)| format!("{v}: {}", ids.join(", ")))
            .collect();
        warn_line(&format!(
            "mixed vertical reference ({}); heights may differ by the geoid undulation",
            parts.join("; ")
        ));
    }
}

/// The inputs with every `@LIST` replaced by the paths it names (relative
/// ones taken from the list file's folder, so a list travels with its data).
fn expand_lists(inputs: &[PathBuf]) -> Result<Vec<PathBuf>, InputError> {
    let mut out = Vec::with_capacity(inputs.len());
    for input in inputs {
        let Some(list) = input.to_str().and_then(|s| s.strip_prefix('@')) else {
            out.push(input.clone());
            continue;
        };
        let text = std::fs::read_to_string(list)
            .map_err(|e| InputError::new(format!("{list}: cannot read the input list ({e})")))?;
        let folder = std::path::Path::new(list)
            .parent()
            .unwrap_or(std::path::Path::new(""));
        let before = out.len();
        out.extend(
            text.lines()
                .map(str::trim)
                .filter(|l| !l.is_empty() && !l.starts_with('#'))
                .map(|l| folder.join(l)),
        );
        if out.len() == before {
            return Err(InputError::new(format!(
                "{list}: the input list names no file"
            )));
        }
    }
    Ok(out)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let options = IngestOptions {
        storage: StorageSettings {
            chunk: args.chunk,
            compression: args.compression,
            ..Default::default()
        },
        force: args.force,
        target: (args.utm_zone.map(CrsChoice::Zone)).or(args.crs),
    };
    require_writable_dir(&args.store)?;
    let inputs = expand_lists(&args.inputs)?;
    let progress = BarProgress {
        span: RefCell::new(None),
        lines: plain_progress("DSMs"),
    };
    let report = ingest(&inputs, &args.store, &options, &progress)
        .map_err(|e| classify(e, |e| e.is_bad_input()))?;
    progress.lines.finish_and_clear();
    warn_mixed_vertical(&args.store);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn list_paths_are_taken_from_the_list_files_folder() {
        let dir = tempfile::tempdir().unwrap();
        let lists = dir.path().join("lists");
        std::fs::create_dir(&lists).unwrap();
        let list = lists.join("in.txt");
        std::fs::write(&list, "# inputs\n../data/a.tif\n\n  /abs/b.tif  \nc.vrt\n").unwrap();
        let at = PathBuf::from(format!("@{}", list.display()));
        let plain = PathBuf::from("d.tif");
        let got = expand_lists(&[plain.clone(), at]).unwrap();
        assert_eq!(
            got,
            vec![
                plain,
                lists.join("../data/a.tif"),
                PathBuf::from("/abs/b.tif"),
                lists.join("c.vrt")
            ]
        );
        std::fs::write(&list, "# nothing\n\n").unwrap();
        let empty = expand_lists(&[PathBuf::from(format!("@{}", list.display()))]).unwrap_err();
        assert!(empty
            .to_string()
            .ends_with("in.txt: the input list names no file"));
    }
}
