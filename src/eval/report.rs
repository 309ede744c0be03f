//! The human-readable eval table (the JSON form is `serde_json` of [`EvalReport`]).

use std::fmt::Write;

use super::{DiffStats, EvalReport};

const HEADER: &str =
    "set     samples  inliers%  rmse_tau      mean    median      NMAD       p16       p84";

fn row(label: &str, set: &str, s: &DiffStats) -> String {
    if s.inliers == 0 {
        return format!("{label:<28} {set:<6} {:>8}  no inliers", s.samples);
    }
    format!(
        "{label:<28} {set:<6} {:>8} {:>9.2} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3} {:>9.3}",
        s.samples,
        100.0 * s.inlier_fraction,
        s.rmse_tau_m,
        s.mean_m,
        s.median_m,
        s.nmad_m,
        s.p16_m,
        s.p84_m
    )
}

impl EvalReport {
    /// The report as an aligned text table, metres.
    pub fn to_table(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "eval of {} (poses: {}); tau = {} m",
            self.store.display(),
            self.poses,
            self.tau_m
        );
        let _ = writeln!(
            out,
            "rmse_tau = sqrt(sum dh^2 / N) over |dh| < tau, N = {}; mean, median, NMAD and percentiles over the inliers too; metres",
            self.rmse_tau_n
        );
        let _ = writeln!(out, "\npairs: dh = z_j - z_i at pixel centres of DSM i");
        let _ = writeln!(out, "{:<28} {HEADER}", "pair i - j");
        for p in &self.pairs {
            let label = format!("{} - {}", p.i, p.j);
            let _ = writeln!(out, "{}", row(&label, "before", &p.before));
            if let Some(a) = &p.after {
                let _ = writeln!(out, "{}", row("", "after", a));
            }
        }
        if self.pairs.is_empty() {
            let _ = writeln!(out, "(no overlapping pairs)");
        }
        let mean_label = format!("mean over {} pairs", self.pairs.len());
        if let Some(m) = &self.mean_before {
            let _ = writeln!(out, "{}", row(&mean_label, "before", m));
        }
        if let Some(m) = &self.mean_after {
            let _ = writeln!(out, "{}", row("", "after", m));
        }
        if let Some(r) = &self.reference {
            let _ = writeln!(
                out,
                "\nreference {} ({}): dh = fused surface (median of corrected DSMs) - reference",
                r.path.display(),
                r.kind
            );
            let _ = writeln!(out, "{:<28} {HEADER}", "");
            let _ = writeln!(out, "{}", row("fused - reference", "before", &r.before));
            if let Some(a) = &r.after {
                let _ = writeln!(out, "{}", row("", "after", a));
            }
            for n in &r.notes {
                let _ = writeln!(out, "note: {n}");
            }
        }
        let _ = writeln!(out, "\n{:.1} s", self.seconds);
        out
    }
}
