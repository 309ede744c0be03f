//! `dsmstream info`: the catalog of a store as a table (or JSON): size, GSD,
//! CRS, valid fraction, heights, chunking, levels, and how many other DSMs
//! each footprint overlaps.

use std::fmt::Write as _;
use std::path::PathBuf;

use dsmstream::store::DsmMeta;

use super::common::{emit, emit_line, open_store};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The store directory (made by `dsmstream ingest`).
    pub store: PathBuf,
    /// Print the full catalog as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Pairs (i, j), i < j, whose footprints overlap (O(N^2), fine for a catalog).
fn overlapping_pairs(dsms: &[DsmMeta]) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    for i in 0..dsms.len() {
        for j in i + 1..dsms.len() {
            if dsms[i].footprint.overlaps(&dsms[j].footprint) {
                pairs.push((i, j));
            }
        }
    }
    pairs
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let store = open_store(&args.store)?;
    let dsms = store.dsms();
    let pairs = overlapping_pairs(dsms);
    let crs = store
        .crs()
        .map(|c| c.label())
        .unwrap_or_else(|| "none".into());
    if args.json {
        let doc = serde_json::json!({
            "store": store.root().display().to_string(),
            "crs": crs,
            "dsms": dsms,
            "overlapping_pairs": pairs.iter().map(|&(i, j)| [&dsms[i].id, &dsms[j].id]).collect::<Vec<_>>(),
        });
        emit_line(&serde_json::to_string_pretty(&doc)?)?;
        return Ok(());
    }
    let mut per_dsm = vec![0usize; dsms.len()];
    for &(i, j) in &pairs {
        per_dsm[i] += 1;
        per_dsm[j] += 1;
    }
    let id_w = dsms.iter().map(|d| d.id.len()).max().unwrap_or(2).max(2);
    let mut t = String::new();
    let _ = writeln!(
        t,
        "{:<id_w$}  {:>13}  {:>7}  {:<12}  {:>7}  {:>21}  {:>5}  {:>6}  {:>8}",
        "id",
        "size (px)",
        "GSD (m)",
        "CRS",
        "valid %",
        "height min..max (m)",
        "chunk",
        "levels",
        "overlaps"
    );
    for (d, n) in dsms.iter().zip(&per_dsm) {
        let chunk = d.levels.first().map(|l| l.chunk).unwrap_or(0);
        let _ = writeln!(
            t,
            "{:<id_w$}  {:>13}  {:>7.3}  {:<12}  {:>7.1}  {:>21}  {:>5}  {:>6}  {:>8}",
            d.id,
            format!("{} x {}", d.width, d.height),
            d.gsd_m(),
            d.crs.label(),
            100.0 * d.valid_fraction(),
            format!("{:.2} .. {:.2}", d.height_stats.min, d.height_stats.max),
            chunk,
            d.levels.len(),
            n
        );
    }
    let reprojected: Vec<String> = (dsms.iter())
        .filter_map(|d| {
            let w = d.reprojected.as_ref()?;
            Some(format!("{} (from {} at {} m)", d.id, w.from, w.pixel_m))
        })
        .collect();
    if !reprojected.is_empty() {
        let _ = writeln!(t, "reprojected at ingest: {}", reprojected.join(", "));
    }
    let _ = writeln!(
        t,
        "{} DSMs, CRS {crs}, {} overlapping footprint pairs",
        dsms.len(),
        pairs.len()
    );
    emit(&t)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use dsmstream::geo::Bounds;

    #[test]
    fn touching_footprints_do_not_overlap() {
        let a = Bounds::from([0.0, 0.0, 10.0, 10.0]);
        let overlaps = |a: &Bounds, b: [f64; 4]| a.overlaps(&Bounds::from(b));
        assert!(overlaps(&a, [5.0, 5.0, 15.0, 15.0]));
        assert!(!overlaps(&a, [10.0, 0.0, 20.0, 10.0]));
        assert!(!overlaps(&a, [0.0, 11.0, 10.0, 20.0]));
    }
}
