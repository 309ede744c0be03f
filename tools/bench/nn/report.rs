//! Tables, CSV and the dated Markdown record of `bench_nn run`.

use std::fmt::Write as _;
use std::path::Path;

use serde_json::Value;

use crate::Prep;

/// One reference size: both methods' JSON results side by side.
pub struct Row {
    pub size_px: u64,
    pub prep: Prep,
    pub dsm: Value,
    pub kd: Value,
    pub truth_shift_m: [f64; 3],
}

fn num(v: &Value, key: &str) -> f64 {
    v.get(key).and_then(Value::as_f64).unwrap_or(f64::NAN)
}

fn failed(v: &Value) -> Option<&str> {
    v.get("failed").and_then(Value::as_str)
}

/// Motion of the overlap centre under a result's m_world.
fn shift(v: &Value) -> Option<[f64; 3]> {
    let m = v.get("motion")?.get("shift_m")?.as_array()?;
    let t = |i: usize| m.get(i)?.as_f64();
    Some([t(0)?, t(1)?, t(2)?])
}

impl Row {
    pub fn new(size_px: u64, prep: Prep, dsm: Value, kd: Value, truth_shift_m: [f64; 3]) -> Row {
        Row {
            size_px,
            prep,
            dsm,
            kd,
            truth_shift_m,
        }
    }

    fn points_m(&self) -> f64 {
        let n = num(&self.dsm, "reference_points");
        if n.is_nan() {
            (self.size_px * self.size_px) as f64 / 1e6
        } else {
            n / 1e6
        }
    }

    /// Do both methods see the same correspondences? Counts equal and mean
    /// distances within 0.1 mm (the k-d cloud is f32).
    fn nn_agree(&self) -> String {
        let c = |v: &Value, k: &str| {
            v.get("check")
                .and_then(|c| c.get(k))
                .and_then(Value::as_f64)
        };
        match (
            c(&self.dsm, "inliers"),
            c(&self.kd, "inliers"),
            c(&self.dsm, "sum_distance_m"),
            c(&self.kd, "sum_distance_m"),
        ) {
            (Some(a), Some(b), Some(sa), Some(sb)) => {
                let mean_diff_m = (sa - sb).abs() / a.max(1.0);
                if a == b && mean_diff_m < 1e-4 {
                    "same".to_string()
                } else {
                    format!("DIFF {a}/{b} {mean_diff_m:.1e} m")
                }
            }
            _ => "-".to_string(),
        }
    }

    fn shift_text(v: &Value) -> String {
        match shift(v) {
            Some(t) => format!("{:+.3} {:+.3} {:+.3}", t[0], t[1], t[2]),
            None => "-".into(),
        }
    }

    fn cells(&self) -> Vec<String> {
        let f = |v: f64, p: usize| {
            if v.is_nan() {
                "-".to_string()
            } else {
                format!("{v:.p$}")
            }
        };
        let kd_fail = failed(&self.kd);
        let speedup = num(&self.kd, "end_to_end_s") / num(&self.dsm, "end_to_end_s");
        let nn_ratio = num(&self.dsm, "nn_s_per_iteration") / num(&self.kd, "nn_s_per_iteration");
        vec![
            format!("{}^2", self.size_px),
            f(self.points_m(), 1),
            f(num(&self.dsm, "nn_s_per_iteration") * 1e3, 1),
            f(num(&self.dsm, "end_to_end_s"), 2),
            f(num(&self.dsm, "peak_rss_mb"), 0),
            f(num(&self.kd, "build_s") + num(&self.kd, "load_s"), 1),
            f(num(&self.kd, "nn_s_per_iteration") * 1e3, 1),
            f(num(&self.kd, "end_to_end_s"), 2),
            kd_fail.map_or_else(|| f(num(&self.kd, "peak_rss_mb"), 0), |e| e.to_string()),
            f(speedup, 1),
            f(nn_ratio, 2),
            format!(
                "{} / {}",
                num(&self.dsm, "iterations"),
                num(&self.kd, "iterations")
            ),
            self.nn_agree(),
            Self::shift_text(&self.dsm),
            Self::shift_text(&self.kd),
        ]
    }

    pub fn table_line(&self) -> String {
        format!("| {} |", self.cells().join(" | "))
    }
}

const HEADER: [&str; 15] = [
    "reference",
    "points (M)",
    "dsm NN/iter (ms)",
    "dsm total (s)",
    "dsm RSS (MB)",
    "kd load+build (s)",
    "kd NN/iter (ms)",
    "kd total (s)",
    "kd RSS (MB)",
    "total speed-up",
    "NN time ratio dsm/kd",
    "iterations dsm/kd",
    "NN results",
    "dsm shift at centre (m)",
    "kd shift at centre (m)",
];

pub fn table(rows: &[Row]) -> String {
    let mut s = format!("| {} |\n", HEADER.join(" | "));
    let _ = writeln!(s, "|{}", "---|".repeat(HEADER.len()));
    for r in rows {
        let _ = writeln!(s, "{}", r.table_line());
    }
    s
}

/// One line per size for the plot script.
pub fn write_csv(path: &Path, rows: &[Row]) -> std::io::Result<()> {
    let mut s = String::from(
        "size_px,points_m,dsm_nn_ms,dsm_total_s,dsm_rss_mb,kd_load_s,kd_build_s,kd_nn_ms,kd_total_s,kd_rss_mb,kd_failed\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},\"{}\"",
            r.size_px,
            r.points_m(),
            num(&r.dsm, "nn_s_per_iteration") * 1e3,
            num(&r.dsm, "end_to_end_s"),
            num(&r.dsm, "peak_rss_mb"),
            num(&r.kd, "load_s"),
            num(&r.kd, "build_s"),
            num(&r.kd, "nn_s_per_iteration") * 1e3,
            num(&r.kd, "end_to_end_s"),
            num(&r.kd, "peak_rss_mb"),
            failed(&r.kd).unwrap_or("").replace('"', "'"),
        );
    }
    std::fs::write(path, s)
}

fn shell(cmd: &str) -> String {
    std::process::Command::new("sh")
        .args(["-c", cmd])
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_default()
}

/// The dated record: environment, command, table, raw JSON.
pub fn write_markdown(
    path: &Path,
    rows: &[Row],
    command: &str,
    commands: &[String],
) -> std::io::Result<()> {
    let mut s = String::from("# bench_nn: grid NN (DSM-ICP) vs k-d tree ICP\n\n");
    let _ = writeln!(s, "- date: {}", shell("date -u '+%Y-%m-%d %H:%M UTC'"));
    let _ = writeln!(s, "- commit: {}", shell("git rev-parse --short HEAD"));
    let _ = writeln!(
        s,
        "- machine: {} cores, {} (shared; load average at the end: {})",
        shell("nproc"),
        shell("free -g | awk '/Mem:/{print $2 \" GB RAM\"}'"),
        shell("cut -d' ' -f1-3 /proc/loadavg")
    );
    let _ = writeln!(s, "- command: `{command}`");
    let t = rows.first().map_or([0.0; 3], |r| r.truth_shift_m);
    let _ = writeln!(
        s,
        "- truth: moving DSM written with shift ({:+.2}, {:+.2}, {:+.2}) m; m_world should recover it\n",
        t[0], t[1], t[2]
    );
    s.push_str(&table(rows));
    s.push_str("\n## Commands run (binaries from target/release)\n\n```\n");
    for c in commands {
        let _ = writeln!(s, "{c}");
    }
    s.push_str("```\n\n## Raw results\n\n```json\n");
    for r in rows {
        let _ = writeln!(
            s,
            "{{\"size_px\": {}, \"generate_s\": {:.1}, \"ingest_s\": {:.1}}}",
            r.size_px, r.prep.generate_s, r.prep.ingest_s
        );
        let _ = writeln!(s, "{}", r.dsm);
        let _ = writeln!(s, "{}", r.kd);
    }
    s.push_str("```\n");
    std::fs::write(path, s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn rows_compare_checks_and_ratios() {
        let prep = Prep {
            generate_s: 1.0,
            ingest_s: 2.0,
        };
        let m = json!({"shift_m": [1.3, -0.7, 0.9], "rotation_deg": 0.0});
        let dsm = json!({"reference_points": 2e6, "end_to_end_s": 1.0, "nn_s_per_iteration": 0.01,
            "check": {"inliers": 10, "sum_distance_m": 5.0}, "motion": m});
        let kd = json!({"end_to_end_s": 8.0, "nn_s_per_iteration": 0.02,
            "check": {"inliers": 10, "sum_distance_m": 5.01}, "motion": m});
        let row = Row::new(2000, prep, dsm, kd, [1.3, -0.7, 0.9]);
        let cells = row.cells();
        assert_eq!(cells[1], "2.0");
        assert_eq!(cells[9], "8.0");
        assert_eq!(cells[10], "0.50");
        assert!(cells[12].starts_with("DIFF"), "{}", cells[12]);
        assert_eq!(cells[13], "+1.300 -0.700 +0.900");
    }
}
