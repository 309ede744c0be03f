//! Before any pair is registered: the checks of the store, the anchor and the
//! output path, the planned pairs (footprints moved by the initial poses, if
//! any), the output lock and the journal (fresh, or resumed with the pairs it
//! already holds; the settings it records include the mask and initial poses).

use std::collections::HashSet;

use super::{AlignConfig, AlignError};
use crate::geo::Bounds;
use crate::journal::{DsmIds, Journal, JournalError, OutputLock};
use crate::pipeline::{PairOutcome, PairTask};
use crate::plan::{candidate_pairs, Footprint};
use crate::store::{DsmMeta, Store};

/// What `align` will do: the pairs to register and the DSM kept fixed.
#[derive(Clone, Debug)]
pub struct AlignPlan {
    /// Candidate pairs (overlapping footprints) in Morton order.
    pub tasks: Vec<PairTask>,
    /// Overlapping pairs left out for sharing fewer than `--min-overlap-px` pixels.
    pub too_small: usize,
    /// Index of the DSM that stays fixed; None = mean gauge.
    pub anchor: Option<usize>,
}

/// Checks the store, the anchor and the output path, and plans the pairs.
pub fn plan(store: &Store, config: &AlignConfig) -> Result<AlignPlan, AlignError> {
    let dsms = store.dsms();
    let root = store.root().display();
    match dsms.len() {
        0 => {
            return Err(AlignError::Input(format!(
                "{root}: the store holds no DSM; run `dsmstream ingest` first"
            )))
        }
        1 => {
            return Err(AlignError::Input(format!(
                "{root}: the store holds one DSM; align needs at least two"
            )))
        }
        _ => {}
    }
    let anchor = match &config.anchor {
        Some(id) => Some(store.find(id).ok_or_else(|| {
            AlignError::Input(format!("{root}: --anchor: no DSM with id '{id}'"))
        })?),
        None => None,
    };
    check_output(&config.output)?;
    // where the initial poses (if any) move each DSM
    let inputs = &config.pipeline.inputs;
    let footprints: Vec<Footprint> = dsms
        .iter()
        .enumerate()
        .map(|(index, d)| {
            let s = inputs.shift_m(index);
            let b = d.footprint;
            Footprint {
                index,
                bounds: Bounds::from_corners(
                    (b.min_x + s.x, b.min_y + s.y),
                    (b.max_x + s.x, b.max_y + s.y),
                ),
            }
        })
        .collect();
    let candidates = candidate_pairs(&footprints);
    let min_px = config.pipeline.min_overlap_px;
    let tasks: Vec<PairTask> = candidates
        .iter()
        .filter(|&&(i, j)| shared_pixels(&footprints, dsms, i, j) >= min_px as f64)
        .map(|&(reference, moving)| PairTask { reference, moving })
        .collect();
    if candidates.is_empty() {
        return Err(AlignError::Input(format!(
            "{root}: no two DSM footprints overlap"
        )));
    }
    if tasks.is_empty() {
        return Err(AlignError::Input(format!(
            "{root}: no two DSM footprints share --min-overlap-px {min_px} pixels"
        )));
    }
    let too_small = candidates.len() - tasks.len();
    Ok(AlignPlan {
        tasks,
        too_small,
        anchor,
    })
}

/// Pixels of the coarser of DSMs `i` and `j` in their footprints' intersection.
fn shared_pixels(footprints: &[Footprint], dsms: &[DsmMeta], i: usize, j: usize) -> f64 {
    let Some(shared) = footprints[i].bounds.intersection(&footprints[j].bounds) else {
        return 0.0;
    };
    let pixel = dsms[i].gsd_m().max(dsms[j].gsd_m());
    shared.width() * shared.height() / (pixel * pixel)
}

/// `--out` must name a file in an existing folder: refused before any work.
fn check_output(output: &std::path::Path) -> Result<(), AlignError> {
    let shown = output.display();
    if output.is_dir() {
        return Err(AlignError::Input(format!(
            "--out {shown}: is a directory; give the path of the poses file to write"
        )));
    }
    let parent = match output.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => std::path::Path::new("."),
    };
    if !parent.is_dir() {
        return Err(AlignError::Input(format!(
            "--out {shown}: the folder {} does not exist",
            parent.display()
        )));
    }
    Ok(())
}

/// Takes the output lock, then opens the journal: a fresh one, or when resuming
/// (the default) the existing one and the pairs it already holds; a journal
/// written with other settings is refused with a hint (`--fresh`).
pub fn open_journal(
    store: &Store,
    plan: &AlignPlan,
    config: &AlignConfig,
) -> Result<(OutputLock, Journal, Vec<PairOutcome>), AlignError> {
    let lock = OutputLock::acquire(&config.output)?;
    let path = Journal::path_for(&config.output);
    let settings = journal_settings(config);
    let ids = dsm_ids(store);
    let (journal, done) = if config.resume {
        let planned: HashSet<PairTask> = plan.tasks.iter().copied().collect();
        Journal::resume(
            &path,
            &settings,
            ids,
            &|p| planned.contains(&p),
            config.pipeline.min_overlap,
        )
        .map_err(|e| match e {
            JournalError::Mismatch { path, .. } => AlignError::Input(format!(
                "{path}: the journal of an earlier run used other ICP settings, \
                 --min-overlap(-px), --mask or --initial; run again with those to reuse its pairs, \
                 or add --fresh to start over"
            )),
            e => e.into(),
        })?
    } else {
        (Journal::create(&path, &settings, ids)?, Vec::new())
    };
    Ok((lock, journal, done))
}

/// The pairwise registration's behaviour: raised when a version registers the
/// same pair differently, so that its journals are not mixed with older ones.
/// 2: global initial search, degeneracy holding, `ambiguous`.
pub const REGISTRATION_VERSION: u32 = 2;

/// The settings a journal's header records: a journal is reused (or, sharded,
/// merged) only by a run with the same ones. A mask and initial poses are
/// recorded by their content's hash, and only when given (so journals of runs
/// without them keep their settings); `--min-overlap-px` only when not 0 (a
/// journal of a version without it resumes with `--min-overlap-px 0`).
pub fn journal_settings(config: &AlignConfig) -> String {
    let min_px = match config.pipeline.min_overlap_px {
        0 => String::new(),
        px => format!(" min_overlap_px={px}"),
    };
    format!(
        "{:?} min_overlap={}{min_px} registration={REGISTRATION_VERSION}{}",
        config.pipeline.icp,
        config.pipeline.min_overlap,
        config.pipeline.inputs.settings()
    )
}

/// The store's DSM ids, for converting journal lines.
pub fn dsm_ids(store: &Store) -> DsmIds {
    DsmIds::new(store.dsms().iter().map(|d| d.id.clone()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::Weighting;
    use crate::icp::IcpConfig;
    use crate::pipeline::PipelineConfig;
    use crate::poses::GraphKind;
    use crate::view::PairInputs;

    fn config(inputs: PairInputs) -> AlignConfig {
        AlignConfig {
            pipeline: PipelineConfig {
                threads: 1,
                icp: IcpConfig::default(),
                min_overlap: 0.1,
                min_overlap_px: 0,
                inputs,
            },
            graph: GraphKind::Full,
            weights: Weighting::Information,
            anchor: None,
            resume: true,
            output: "poses.json".into(),
            sharding: Default::default(),
        }
    }

    #[test]
    fn the_settings_name_min_overlap_px_only_when_not_0() {
        let plain = journal_settings(&config(PairInputs::default()));
        assert!(!plain.contains("min_overlap_px"), "{plain}");
        let mut c = config(PairInputs::default());
        c.pipeline.min_overlap_px = 2500;
        let given = journal_settings(&c);
        assert!(
            given.contains("min_overlap=0.1 min_overlap_px=2500 "),
            "{given}"
        );
    }

    #[test]
    fn the_settings_name_initial_poses_only_when_given() {
        let plain = journal_settings(&config(PairInputs::default()));
        assert!(plain.ends_with(&format!("registration={REGISTRATION_VERSION}")));
        let initial = PairInputs {
            initial: Some(("a.json".into(), 1)),
            ..Default::default()
        };
        let other = PairInputs {
            initial: Some(("a.json".into(), 2)),
            ..Default::default()
        };
        let (a, b) = (
            journal_settings(&config(initial)),
            journal_settings(&config(other)),
        );
        assert!(a.starts_with(&plain) && a != plain && a != b, "{a}");
    }
}
