//! `align` as a library call: plan the pairs, stream them through the pipeline,
//! build the scene graph and solve the poses (motion averaging, or the greedy
//! spanning-tree baseline), in a local frame near the data, then hand back the
//! poses.json model in world coordinates.

use std::path::PathBuf;

use nalgebra::{Matrix4, Vector3};

use crate::averaging::{average, edge_residuals, fix_gauge, AveragingOptions, Gauge};
use crate::cache::ChunkCache;
use crate::graph::{
    chain_poses, information_weights, mst, paper_weights, Edge, EdgeSigma, PoseGraph, Weighting,
};
use crate::journal::{EdgeRecord, Journal, JournalError};
use crate::pipeline::{self, PairTask, PipelineConfig};
use crate::plan::{candidate_pairs, Footprint};
use crate::poses::rigid::{to_local, to_world};
use crate::poses::{EdgeEntry, GaugeLabel, GraphKind, PoseEntry, PosesFile, PosesSummary};
use crate::store::Store;

/// Everything `align` needs, validated by the CLI.
#[derive(Clone, Debug)]
pub struct AlignConfig {
    pub pipeline: PipelineConfig,
    pub graph: GraphKind,
    /// Edge weights of the averaging (`--weights`).
    pub weights: Weighting,
    /// Id of the DSM that stays fixed; None = mean gauge.
    pub anchor: Option<String>,
    pub resume: bool,
    pub output: PathBuf,
}

#[derive(Debug, thiserror::Error)]
pub enum AlignError {
    /// Bad input: the message says what to change.
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Journal(#[from] JournalError),
    #[error("motion averaging failed: {0}")]
    Averaging(String),
}

/// The result: the poses file plus the per-pair records (failed ones included).
pub struct AlignOutcome {
    pub poses: PosesFile,
    pub records: Vec<EdgeRecord>,
    pub components: Vec<Vec<String>>,
    /// The weights used: `config.weights`, or the paper's when some edge has no
    /// standard errors (journaled by an older version, or the point-to-point metric).
    pub weights: Weighting,
}

pub fn align(
    store: &Store,
    cache: &ChunkCache,
    config: &AlignConfig,
    progress: &mut dyn FnMut(&EdgeRecord, usize, usize),
) -> Result<AlignOutcome, AlignError> {
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
    let footprints: Vec<Footprint> = dsms
        .iter()
        .enumerate()
        .map(|(index, d)| Footprint {
            index,
            bounds: d.footprint,
        })
        .collect();
    let tasks: Vec<PairTask> = candidate_pairs(&footprints)
        .into_iter()
        .map(|(reference, moving)| PairTask { reference, moving })
        .collect();
    if tasks.is_empty() {
        return Err(AlignError::Input(format!(
            "{root}: no two DSM footprints overlap"
        )));
    }
    let journal_path = Journal::path_for(&config.output);
    let settings = format!(
        "{:?} min_overlap={}",
        config.pipeline.icp, config.pipeline.min_overlap
    );
    let (mut journal, done) = if config.resume {
        Journal::resume(&journal_path, &settings)?
    } else {
        (Journal::create(&journal_path, &settings)?, Vec::new())
    };
    let records = pipeline::run(
        store,
        cache,
        &tasks,
        &config.pipeline,
        &mut journal,
        done,
        progress,
    )?;
    let usable: Vec<&EdgeRecord> = records.iter().filter(|r| r.usable()).collect();
    if usable.is_empty() {
        let min = config.pipeline.min_overlap;
        let above: Vec<&EdgeRecord> = records
            .iter()
            .filter(|r| !r.below_min_overlap(min))
            .collect();
        return Err(AlignError::Input(match above.first() {
            None => format!("{root}: no pair overlaps by at least --min-overlap {min}"),
            Some(first) => format!(
                "{root}: none of the {} overlapping pairs registered (first: {}-{}: {})",
                above.len(),
                first.reference,
                first.moving,
                first.why_no_edge()
            ),
        }));
    }
    let origin = local_origin(store);
    let mut graph = PoseGraph::new(dsms.len());
    graph.edges = usable.iter().map(|r| edge(store, r, &origin)).collect();
    let weights = match config.weights {
        Weighting::Information => match information_weights(&mut graph.edges) {
            Ok(()) => Weighting::Information,
            Err(e) => {
                tracing::warn!(error = %e, "information weights unavailable, paper weights used");
                paper_weights(&mut graph.edges);
                Weighting::Paper
            }
        },
        Weighting::Paper => {
            paper_weights(&mut graph.edges);
            Weighting::Paper
        }
    };
    let gauge = anchor.map_or(Gauge::Mean, Gauge::Anchor);
    let options = AveragingOptions {
        gauge,
        // Residuals in sigmas only with the weights that trust the sigmas.
        outlier_by_sigma: weights == Weighting::Information,
        ..AveragingOptions::default()
    };
    let (poses_local, residuals, dropped, components, summary) = match config.graph {
        GraphKind::Full => {
            let result =
                average(&graph, &options).map_err(|e| AlignError::Averaging(e.to_string()))?;
            let summary = PosesSummary {
                weights: Some(weights),
                ..PosesSummary::from_result(&result)
            };
            (
                result.poses,
                result.edge_residuals,
                result.dropped_edges,
                result.components,
                Some(summary),
            )
        }
        GraphKind::Mst => {
            let tree = mst(&graph);
            let mut poses = chain_poses(&graph, &tree, anchor.unwrap_or(0))
                .map_err(|e| AlignError::Averaging(e.to_string()))?;
            let components = graph.components().members;
            for members in &components {
                fix_gauge(&mut poses, members, anchor.filter(|a| members.contains(a)));
            }
            let residuals = edge_residuals(&graph, &poses);
            (poses, residuals, Vec::new(), components, None)
        }
    };
    let poses = poses_local
        .iter()
        .enumerate()
        .map(|(k, m)| PoseEntry {
            id: dsms[k].id.clone(),
            matrix_world: to_world(m, &origin),
        })
        .collect();
    let edges = graph
        .edges
        .iter()
        .zip(&usable)
        .enumerate()
        .map(|(k, (e, r))| EdgeEntry {
            i: r.reference.clone(),
            j: r.moving.clone(),
            overlap: e.overlap,
            rmse_m: e.rmse_m,
            weight: e.weight,
            translation_weight: Some(e.translation_weight),
            iterations: r.iterations as u32,
            inliers: r.inliers as u64,
            residual_m: residuals[k].translation_m,
            residual_deg: residuals[k].rotation_deg,
            dropped: dropped.contains(&k),
            converged: r.status == Some(crate::icp::IcpStatus::Converged),
        })
        .collect();
    let component_ids: Vec<Vec<String>> = components
        .iter()
        .map(|c| c.iter().map(|&k| dsms[k].id.clone()).collect())
        .collect();
    let poses = PosesFile {
        crs: store.crs().map(|c| c.label()).unwrap_or_default(),
        poses,
        edges,
        graph: config.graph,
        gauge: anchor.map_or(GaugeLabel::Mean, |a| GaugeLabel::Anchor(dsms[a].id.clone())),
        components: (component_ids.len() > 1).then(|| component_ids.clone()),
        summary,
    };
    Ok(AlignOutcome {
        poses,
        records,
        components: component_ids,
        weights,
    })
}

/// The graph edge of a registered pair, in the local frame: M_ij, its standard
/// errors ([`EdgeSigma::from_fit`]), and the centre of the two footprints' intersection at the mean height
/// as the point where its translation was measured.
fn edge(store: &Store, r: &EdgeRecord, origin: &Vector3<f64>) -> Edge {
    let m = r.m_world.expect("usable edges have a matrix");
    let m_world = Matrix4::from_fn(|a, b| m[a][b]);
    let (i, j) = (
        store.find(&r.reference).expect("id from the store"),
        store.find(&r.moving).expect("id from the store"),
    );
    let (a, b) = (&store.dsms()[i], &store.dsms()[j]);
    let (fa, fb) = (a.footprint, b.footprint);
    let centre_world = Vector3::new(
        (fa[0].max(fb[0]) + fa[2].min(fb[2])) / 2.0,
        (fa[1].max(fb[1]) + fa[3].min(fb[3])) / 2.0,
        (a.height_stats.mean + b.height_stats.mean) / 2.0,
    );
    Edge {
        sigma: r.sigma.map(|s| EdgeSigma::from_fit(&s, r.overlap)),
        centre_j: centre_world - origin,
        ..Edge::new(i, j, to_local(&m_world, origin), r.overlap, r.rmse_m)
    }
}

/// Centre of all footprints at the mean height: edges and poses are solved
/// relative to it (UTM coordinates are ~10^6 m).
fn local_origin(store: &Store) -> Vector3<f64> {
    let n = store.dsms().len() as f64;
    let (mut x, mut y, mut z) = (0.0, 0.0, 0.0);
    for d in store.dsms() {
        x += (d.footprint[0] + d.footprint[2]) / 2.0 / n;
        y += (d.footprint[1] + d.footprint[3]) / 2.0 / n;
        z += d.height_stats.mean / n;
    }
    Vector3::new(x.round(), y.round(), z.round())
}
