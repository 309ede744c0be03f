//! `dsmgen score`: a poses.json (and its journal) against the truth.json of the
//! collection: per-DSM and pairwise errors up to the gauge, each journaled
//! pair's error per axis, and the calibration of the pairs' sigmas
//! (fraction within 1, 2, 3 sigma per axis).

use std::collections::HashMap;
use std::io::BufRead;
use std::path::PathBuf;

use clap::Args;
use dsmstream::journal::EdgeRecord;
use dsmstream::poses::{PoseEntry, PosesFile};
use dsmstream::synth::calibration::{calibration, shift_calibration, EdgeError};
use dsmstream::synth::Truth;

/// `println!` that ends the program quietly (exit 0) when stdout is closed
/// early (`dsmgen score ... | head`), as `dsmstream` does, instead of panicking.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        if writeln!(std::io::stdout(), $($arg)*).is_err() {
            std::process::exit(0);
        }
    }};
}

#[derive(Args)]
pub struct ScoreArgs {
    /// truth.json of the collection (dsmgen tiles / cut).
    #[arg(long)]
    truth: PathBuf,
    /// poses.json written by `dsmstream align`.
    #[arg(long)]
    poses: PathBuf,
    /// The align journal (default: <poses>.journal when it exists).
    #[arg(long)]
    journal: Option<PathBuf>,
    /// One JSON document on stdout instead of the table.
    #[arg(long)]
    json: bool,
    /// List the N pairs with the largest |error| / sigma.
    #[arg(long, default_value_t = 5)]
    worst: usize,
    /// List the N DSMs with the largest error (shift at the tile centre).
    #[arg(long, default_value_t = 5)]
    worst_dsms: usize,
    /// Also write every journaled pair's error and sigma per axis to this TSV file.
    #[arg(long)]
    pairs: Option<PathBuf>,
}

pub fn run(a: ScoreArgs) -> Result<(), String> {
    let truth = Truth::load(&a.truth).map_err(|e| format!("{}: {e}", a.truth.display()))?;
    let poses = PosesFile::read(&a.poses).map_err(|e| format!("{}: {e}", a.poses.display()))?;
    let journal = a.journal.clone().unwrap_or_else(|| {
        let mut p = a.poses.clone().into_os_string();
        p.push(".journal");
        PathBuf::from(p)
    });
    let edges = if journal.exists() {
        read_edges(&truth, &journal)?
    } else {
        Vec::new()
    };
    if let Some(path) = &a.pairs {
        write_pairs(path, &edges).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    let per_dsm = truth.per_dsm_error(&poses);
    let pairwise = truth.pairwise_error(&poses);
    let seams = truth.overlap_error(&poses);
    let table = calibration(&edges);
    let joint = shift_calibration(&edges);
    let mut worst: Vec<(f64, &EdgeError)> = edges
        .iter()
        .filter_map(|e| {
            let r = e.ratios().iter().flatten().cloned().fold(0.0, f64::max);
            (r > 0.0).then_some((r, e))
        })
        .collect();
    worst.sort_by(|a, b| b.0.total_cmp(&a.0));
    worst.truncate(a.worst);
    let mut dsm_m: Vec<f64> = per_dsm
        .iter()
        .flat_map(|p| p.tiles.iter().map(|t| t.1))
        .collect();
    dsm_m.sort_by(f64::total_cmp);
    let median_m = dsm_m.get(dsm_m.len() / 2).copied().unwrap_or(f64::NAN);
    let worst_edge_m = edges.iter().map(|e| e.shift_error_m()).fold(0.0, f64::max);
    let by_id: HashMap<&str, &PoseEntry> = poses.poses.iter().map(|p| (p.id.as_str(), p)).collect();
    let dsm_cover = per_dsm.as_ref().map(|p| dsm_coverage(&by_id, &p.tiles));
    let mut worst_dsms: Vec<&(String, f64, f64)> =
        per_dsm.iter().flat_map(|p| p.tiles.iter()).collect();
    worst_dsms.sort_by(|a, b| b.1.total_cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    worst_dsms.truncate(a.worst_dsms);
    if a.json {
        let doc = serde_json::json!({
            "per_dsm": {
                "count": dsm_m.len(),
                "median_m": median_m,
                "worst_m": per_dsm.as_ref().map(|p| p.worst_m),
                "worst_deg": per_dsm.as_ref().map(|p| p.worst_deg),
            },
            "pairwise": {
                "mean_m": pairwise.mean_m,
                "worst_m": pairwise.worst_m,
                "worst_deg": pairwise.worst_deg,
            },
            "overlapping": {
                "mean_m": seams.mean_m,
                "worst_m": seams.worst_m,
                "worst_deg": seams.worst_deg,
            },
            "per_dsm_sigma": dsm_cover,
            "edges": {"count": edges.len(), "worst_shift_m": worst_edge_m},
            "calibration": table,
            "calibration_shift": joint,
            "worst_ratio_edges": worst.iter().map(|(_, e)| e).collect::<Vec<_>>(),
        });
        say!("{doc:#}");
        return Ok(());
    }
    if let Some(p) = &per_dsm {
        say!(
            "per DSM ({} posed): median {median_m:.4} m, worst {:.4} m / {:.4} deg",
            dsm_m.len(),
            p.worst_m,
            p.worst_deg
        );
    }
    if let Some(Some(c)) = &dsm_cover {
        say!(
            "per DSM sigmas ({} with sigma): error within 1/2/3 x |sigma|: {:.3} / {:.3} / {:.3} (shift), {:.3} / {:.3} / {:.3} (rotation)",
            c.with_sigma, c.shift[0], c.shift[1], c.shift[2], c.rotation[0], c.rotation[1], c.rotation[2]
        );
    }
    say!(
        "pairwise (all pairs of DSMs): mean {:.4} m, worst {:.4} m / {:.4} deg",
        pairwise.mean_m,
        pairwise.worst_m,
        pairwise.worst_deg
    );
    say!(
        "overlapping pairs (worst corner of the overlap): mean {:.4} m, worst {:.4} m / {:.4} deg",
        seams.mean_m,
        seams.worst_m,
        seams.worst_deg
    );
    if edges.is_empty() {
        print_worst_dsms(&worst_dsms, &by_id);
        return Ok(());
    }
    say!(
        "journaled pairs: {}, worst shift error {worst_edge_m:.4} m",
        edges.len()
    );
    say!("| axis | with sigma | held | <= 1 sigma | <= 2 sigma | <= 3 sigma | worst |e|/sigma |");
    say!("|---|---|---|---|---|---|---|");
    for c in &table {
        say!(
            "| {} | {} | {} | {:.3} | {:.3} | {:.3} | {:.2} |",
            c.axis,
            c.with_sigma,
            c.held,
            c.within[0],
            c.within[1],
            c.within[2],
            c.worst_ratio
        );
    }
    say!(
        "| shift (x, y, z jointly: Mahalanobis within the chi-square(3) 68.3 / 95.4 / 99.7 % points) | {} | {} | {:.3} | {:.3} | {:.3} | {:.2} |",
        joint.with_covariance,
        edges.len() - joint.with_covariance,
        joint.within[0],
        joint.within[1],
        joint.within[2],
        joint.worst
    );
    for (r, e) in worst {
        say!(
            "  {} -> {} ({:?}): worst ratio {r:.1}; error {:.3?} (m, deg), sigma {:.3?}",
            e.reference,
            e.moving,
            e.status,
            e.error,
            e.sigma
        );
    }
    print_worst_dsms(&worst_dsms, &by_id);
    Ok(())
}

/// One row per journaled pair: ids, status, overlap, RMSE, iterations, then the
/// error and the sigma per axis (metres, degrees; empty where held).
fn write_pairs(path: &PathBuf, edges: &[EdgeError]) -> std::io::Result<()> {
    use std::fmt::Write as _;
    let mut text = String::from("reference\tmoving\tstatus\toverlap\trmse_m\titerations");
    for axis in dsmstream::synth::calibration::AXES {
        let _ = write!(text, "\terr_{axis}");
    }
    for axis in dsmstream::synth::calibration::AXES {
        let _ = write!(text, "\tsigma_{axis}");
    }
    text.push('\n');
    for e in edges {
        let status = e.status.map(|s| format!("{s:?}")).unwrap_or_default();
        let _ = write!(
            text,
            "{}\t{}\t{status}\t{:.4}\t{:.4}\t{}",
            e.reference, e.moving, e.overlap, e.rmse_m, e.iterations
        );
        for v in e.error {
            let _ = write!(text, "\t{v:.6}");
        }
        for s in e.sigma {
            let _ = write!(
                text,
                "\t{}",
                s.map(|s| format!("{s:.6}")).unwrap_or_default()
            );
        }
        text.push('\n');
    }
    std::fs::write(path, text)
}

/// The journaled pairs with a transform, scored against the truth.
fn read_edges(truth: &Truth, path: &PathBuf) -> Result<Vec<EdgeError>, String> {
    let name = path.display();
    let file = std::fs::File::open(path).map_err(|e| format!("{name}: {e}"))?;
    let mut edges = Vec::new();
    for (k, line) in std::io::BufReader::new(file).lines().enumerate().skip(1) {
        let line = line.map_err(|e| format!("{name}: {e}"))?;
        let record: EdgeRecord =
            serde_json::from_str(&line).map_err(|e| format!("{name}, line {}: {e}", k + 1))?;
        edges.extend(truth.edge_error(&record));
    }
    Ok(edges)
}

/// Per DSM: the fraction whose error (after the gauge) is within 1, 2, 3 times
/// the norm of its reported sigma (shift at the tile centre against the norm of
/// the shift sigmas; angle against the norm of the rotation sigmas). None when
/// poses.json has no sigma.
#[derive(serde::Serialize)]
struct DsmCoverage {
    with_sigma: usize,
    shift: [f64; 3],
    rotation: [f64; 3],
}

/// The DSMs with the largest error: id, error (m, deg), the norm of its shift
/// sigma and its status in poses.json.
fn print_worst_dsms(worst: &[&(String, f64, f64)], by_id: &HashMap<&str, &PoseEntry>) {
    if worst.is_empty() {
        return;
    }
    say!("worst DSMs:");
    for (id, m, deg) in worst {
        let pose = by_id.get(id.as_str());
        let sigma = pose
            .and_then(|p| p.sigma.as_ref())
            .map(|s| format!("{:.3} m", norm(&s.shift_m)))
            .unwrap_or_else(|| "-".into());
        let status = pose
            .and_then(|p| p.status.as_ref())
            .map(|s| format!("{s:?}").to_lowercase())
            .unwrap_or_else(|| "-".into());
        say!("  {id}: {m:.4} m / {deg:.4} deg; shift sigma {sigma}; status {status}");
    }
}

fn norm(v: &[f64; 3]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn dsm_coverage(
    by_id: &HashMap<&str, &PoseEntry>,
    tiles: &[(String, f64, f64)],
) -> Option<DsmCoverage> {
    let rows: Vec<(f64, f64)> = tiles
        .iter()
        .filter_map(|(id, m, deg)| {
            let p = by_id.get(id.as_str())?;
            let s = p.sigma.as_ref()?;
            Some((
                m / norm(&s.shift_m).max(1e-12),
                deg / norm(&s.rotation_deg).max(1e-12),
            ))
        })
        .collect();
    if rows.is_empty() {
        return None;
    }
    let frac = |f: &dyn Fn(&(f64, f64)) -> f64, k: f64| {
        rows.iter().filter(|r| f(r) <= k).count() as f64 / rows.len() as f64
    };
    Some(DsmCoverage {
        with_sigma: rows.len(),
        shift: [1.0, 2.0, 3.0].map(|k| frac(&|r| r.0, k)),
        rotation: [1.0, 2.0, 3.0].map(|k| frac(&|r| r.1, k)),
    })
}
