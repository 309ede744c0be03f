//! `dsmstream check STORE [--json]`: verify every DSM of a store (metadata,
//! chunks present and decodable, statistics) and say which DSMs to
//! re-ingest. Exit code 0 when the store is sound, 1 when something is
//! damaged, 2 when the path is not a store.

use std::path::PathBuf;

use dsmstream::store::check::{check_store, CheckReport};
use dsmstream::InputError;

use super::common::{emit, ResourceArgs};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The store directory.
    pub store: PathBuf,
    /// Print the report as JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub resources: ResourceArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let pool = args.resources.pool()?;
    let report = pool
        .install(|| check_store(&args.store))
        .map_err(|e| anyhow::Error::new(InputError::new(e.to_string())))?;
    let text = if args.json {
        serde_json::to_string_pretty(&report)? + "\n"
    } else {
        render(&report)
    };
    emit(&text)?;
    let damaged = report.damaged().count();
    if !report.ok() {
        anyhow::bail!(
            "{}: {damaged} of {} DSMs damaged{}",
            report.store.display(),
            report.dsms.len(),
            if report.catalog_problems.is_empty() {
                ""
            } else {
                ", and the catalog itself"
            }
        );
    }
    Ok(())
}

/// The report as text: one line per DSM, problems indented, then what to do.
fn render(report: &CheckReport) -> String {
    let mut s = String::new();
    for p in &report.catalog_problems {
        s += &format!("catalog  {p}\n");
    }
    for d in &report.dsms {
        let verdict = if d.ok { "ok      " } else { "DAMAGED " };
        s += &format!("{verdict} {} ({} chunks read)\n", d.id, d.chunks_read);
        for p in &d.problems {
            s += &format!("    {p}\n");
        }
        if d.problem_count > d.problems.len() {
            s += &format!("    ... {} more\n", d.problem_count - d.problems.len());
        }
        if let Some(n) = &d.note {
            s += &format!("    note: {n}\n");
        }
    }
    let damaged: Vec<_> = report.damaged().collect();
    if damaged.is_empty() && report.catalog_problems.is_empty() {
        s += &format!(
            "{}: all {} DSMs ok\n",
            report.store.display(),
            report.dsms.len()
        );
        return s;
    }
    for d in damaged {
        match &d.source {
            Some(src) => {
                s += &format!(
                    "re-ingest {}: dsmstream ingest --force {src} --store {}\n",
                    d.id,
                    report.store.display()
                )
            }
            None => {
                s += &format!(
                    "re-ingest {} from its source file with --force (its metadata is unreadable)\n",
                    d.id
                )
            }
        }
    }
    s
}
