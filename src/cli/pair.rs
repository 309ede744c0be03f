//! `dsmstream pair <store> <ref-id> <moving-id>`: one pairwise DSM-ICP through
//! the chunk cache, printed as a table or JSON: the shift at the fit's centre
//! and the rotation about it with their standard errors, the status, held
//! (degenerate) axes, the ambiguity of the global search, and the transform
//! as `matrix_world` (the name poses.json uses).
//!
//! `--mask` limits the match to stable terrain; `--initial` starts the two
//! DSMs from their poses in a poses file (the result stays the full relative
//! transform between the DSMs as stored).
//!
//! Exit 0 when converged, or converged with degenerate axes held (said so);
//! 1 otherwise (not converged, ambiguous, diverged, too few inliers) with a
//! one-line reason; 2 for bad input.

use std::path::PathBuf;

use dsmstream::icp::{matrix_rows, register, CentredPose, IcpError, IcpResult, IcpStatus};
use dsmstream::store::StorePyramid;
use dsmstream::view::to_raw_frames;
use dsmstream::InputError;

use super::common::{emit, emit_line, find_dsm, open_store, ResourceArgs};
use super::icp_args::{IcpArgs, InputArgs};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The store directory.
    pub store: PathBuf,
    /// Id of the reference DSM (stays fixed).
    pub reference: String,
    /// Id of the moving DSM (the transform maps it onto the reference).
    pub moving: String,
    #[command(flatten)]
    pub icp: IcpArgs,
    #[command(flatten)]
    pub inputs: InputArgs,
    #[command(flatten)]
    pub resources: ResourceArgs,
    /// Print the result as JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let config = args.icp.to_config()?;
    let store = open_store(&args.store)?;
    let (i, j) = (
        find_dsm(&store, &args.reference)?,
        find_dsm(&store, &args.moving)?,
    );
    if i == j {
        return Err(InputError::new("the reference and the moving DSM are the same").into());
    }
    let (inputs, _) = args.inputs.load(&store)?;
    let cache = args.resources.cache();
    let started = std::time::Instant::now();
    let (reference, moving) = (
        inputs.view(StorePyramid::new(&store, &cache, i), i),
        inputs.view(StorePyramid::new(&store, &cache, j), j),
    );
    let result = args.resources.pool()?.install(|| {
        register(&reference, &moving, &config)
            .map(|r| to_raw_frames(r, &reference.shift_m, &moving.shift_m))
    });
    let result = match result {
        Ok(r) => r,
        Err(e @ (IcpError::NoOverlap | IcpError::EmptyOverlap)) => {
            let within = match (&args.inputs.mask, &e) {
                (Some(m), IcpError::EmptyOverlap) => {
                    format!(" on the stable cells of the mask {}", m.display())
                }
                _ => String::new(),
            };
            return Err(InputError::new(format!(
                "{} and {}: {e}{within}",
                args.reference, args.moving
            ))
            .into());
        }
        // a chunk of the store that cannot be read or decoded (the message names its file)
        Err(e @ IcpError::Read(_)) => {
            return Err(InputError::new(format!(
                "registering {} to {}: {e}",
                args.moving, args.reference
            ))
            .into())
        }
    };
    let seconds = started.elapsed().as_secs_f64();
    cache.log_stats();
    let pose = result.centred();
    if args.json {
        let mut result_json = serde_json::to_value(&result)?;
        if let Some(obj) = result_json.as_object_mut() {
            if let Some(m) = obj.remove("m_world") {
                obj.insert("matrix_world".into(), m);
            }
            // the centred sigmas next to the historical local ones
            if let Some(sigma) = obj.get_mut("sigma").and_then(|v| v.as_object_mut()) {
                sigma.insert("shift_m".into(), serde_json::to_value(pose.sigma.shift_m)?);
                let rot = serde_json::to_value(pose.sigma.rotation_deg)?;
                sigma.insert("rotation_deg".into(), rot);
            }
        }
        let value = serde_json::json!({
            "reference": args.reference, "moving": args.moving, "seconds": seconds,
            "status": result.status, "centre_m": pose.centre_m, "shift_m": pose.shift_m,
            "rotation_deg": pose.rotation_deg, "sigma": pose.sigma,
            "degenerate": result.degenerate, "ambiguity": result.ambiguity,
            "matrix_world": matrix_rows(&result.t_ref_moving),
            "result": result_json, "cache": cache.stats(),
            "mask": args.inputs.mask, "initial": args.inputs.initial,
        });
        emit_line(&serde_json::to_string_pretty(&value)?)?;
    } else {
        emit(&table(
            &args.reference,
            &args.moving,
            &result,
            &pose,
            seconds,
        ))?;
        if let Some(line) = inputs_line(&args.inputs) {
            emit_line(&line)?;
        }
    }
    if !result.status.is_converged_or_held() {
        anyhow::bail!(
            "registration of {} to {} is not usable: {}",
            args.moving,
            args.reference,
            reason(&result)
        );
    }
    Ok(())
}

/// Why a result is not usable, in one line.
fn reason(r: &IcpResult) -> String {
    match r.status {
        IcpStatus::MaxIterations => format!(
            "not converged after {} iterations (raise --max-iter, or the surfaces disagree)",
            r.iterations
        ),
        IcpStatus::Ambiguous if r.backward.is_some_and(|b| !b.confirms) => {
            "ambiguous: the backward check (the reference registered onto the moving DSM from this answer) does not confirm it".into()
        }
        IcpStatus::Ambiguous if r.restart.is_some_and(|c| !c.confirms()) => {
            "ambiguous: a restart a few pixels beside this answer ran off instead of returning to it".into()
        }
        IcpStatus::Ambiguous => match &r.second_height {
            Some(h) => format!(
                "ambiguous: {:.0} % of the overlap agrees on a height {:+.2} m from the answer (a changed building?)",
                100.0 * h.share,
                h.gap_m
            ),
            None => format!(
                "ambiguous: another place fits nearly as well (cost ratio {:.2})",
                r.ambiguity.unwrap_or(f64::NAN)
            ),
        },
        IcpStatus::Diverged => {
            "diverged: the fit grew worse or moved beyond --max-displacement".into()
        }
        IcpStatus::TooFewInliers => {
            "too few inliers: the DSMs do not match within tau (try a larger --max-displacement)"
                .into()
        }
        IcpStatus::Degenerate => "degenerate: no direction is constrained".into(),
        IcpStatus::Converged => "converged".into(),
    }
}

/// The mask and initial poses used, when any: "inputs      mask m.tif; initial p.json".
fn inputs_line(inputs: &InputArgs) -> Option<String> {
    let named = [("mask", &inputs.mask), ("initial", &inputs.initial)];
    let parts: Vec<String> = named
        .iter()
        .filter_map(|(name, path)| path.as_ref().map(|p| format!("{name} {}", p.display())))
        .collect();
    (!parts.is_empty()).then(|| format!("inputs      {}", parts.join("; ")))
}

/// "x, y, yaw".
fn axes(r: &IcpResult) -> String {
    let names: Vec<&str> = r.degenerate.iter().map(|a| a.label()).collect();
    names.join(", ")
}

/// The result as the text table `pair` prints.
fn table(reference: &str, moving: &str, r: &IcpResult, pose: &CentredPose, seconds: f64) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    let pm = |v: f64, s: Option<f64>, digits: usize| match s {
        Some(s) => format!("{v:.digits$} ± {s:.digits$}"),
        None => format!("{v:.digits$} (held)"),
    };
    let _ = writeln!(t, "pair        {moving} -> {reference}");
    let status = match r.status {
        IcpStatus::Degenerate if !r.degenerate.is_empty() => format!(
            "converged, degenerate in {}: held at the start (not measured)",
            axes(r)
        ),
        s => format!("{s:?}"),
    };
    let _ = writeln!(
        t,
        "status      {status} after {} iterations ({seconds:.2} s)",
        r.iterations
    );
    let (s, ss) = (pose.shift_m, pose.sigma.shift_m);
    let _ = writeln!(
        t,
        "shift       dx {}  dy {}  dz {} m (p_ref - p_moving, 1 sigma)",
        pm(s[0], ss[0], 3),
        pm(s[1], ss[1], 3),
        pm(s[2], ss[2], 3)
    );
    let (a, sa) = (pose.rotation_deg, pose.sigma.rotation_deg);
    let _ = writeln!(
        t,
        "rotation    roll {}  pitch {}  yaw {} deg",
        pm(a[0], sa[0], 5),
        pm(a[1], sa[1], 5),
        pm(a[2], sa[2], 5)
    );
    let c = pose.centre_m;
    let _ = writeln!(
        t,
        "  about     ({:.2}, {:.2}, {:.2}) m: the fit's centre",
        c[0], c[1], c[2]
    );
    if let Some(amb) = r.ambiguity {
        let _ = writeln!(
            t,
            "ambiguity   {amb:.2} (this fit's cost over the nearest other place's: the global search's or the starts'; near 1: another place fits as well)"
        );
    }
    if let Some(s) = &r.search {
        let widened = if s.widened() {
            format!(
                ", widened to {:.1} m (the best place lay on the edge)",
                s.reached_m
            )
        } else {
            String::new()
        };
        let _ = writeln!(
            t,
            "search      within {:.1} m{widened}; the answer lies {:.2} m from the start",
            s.cut_m, s.offset_m
        );
    }
    if let Some(b) = &r.backward {
        let _ = writeln!(
            t,
            "backward    dx {:.3}  dy {:.3}  dz {:.3} m, yaw {:.4} deg from the forward fit ({:?}; chi-square {:.1}: {}){}",
            b.shift_m[0], b.shift_m[1], b.shift_m[2], b.rotation_deg[2], b.status,
            b.chi_square.unwrap_or(f64::NAN),
            if b.beyond_noise { "beyond the two fits' noise, added to the sigmas" } else { "within the noise" },
            if b.confirms { "" } else { "; does not confirm the answer" }
        );
    }
    if let Some(c) = &r.restart {
        let _ = writeln!(
            t,
            "restarts    {} of {} ran{}, the farthest ended {:.3} m from the answer ({} beyond the noise{}){}",
            c.ran,
            c.tried,
            if c.lost > 0 { format!(" ({} ran off: the answer is not confirmed)", c.lost) } else { String::new() },
            c.gap_m,
            c.beyond_noise,
            if c.beyond_noise > 0 { ", added to the sigmas" } else { "" },
            if c.moved_m > 0.0 {
                format!("; both settled {:.3} m from the ladder's answer, which moved there", c.moved_m)
            } else {
                String::new()
            }
        );
    }
    if let Some(h) = &r.second_height {
        let place = if h.slide_m > 0.0 {
            format!(
                " where the DSM was georeferenced ({:.1} m from the answer, which slid onto one height; the slide is in the sigmas too)",
                h.slide_m
            )
        } else {
            String::new()
        };
        let _ = writeln!(
            t,
            "heights     {:.0} % of the overlap is {:+.3} m from the answer's height{place}: the pair cannot tell which is ground, the gap is in the sigmas",
            100.0 * h.share,
            h.gap_m
        );
    }
    let _ = writeln!(
        t,
        "residuals   {:.4} m to the reference surface, {:.4} m to its nearest pixel (RMS, inliers)",
        r.rmse_plane_m, r.rmse_m
    );
    let _ = writeln!(
        t,
        "inliers     {} of {} samples   overlap {:.3} (samples with reference below)",
        r.inliers, r.samples, r.overlap
    );
    let _ = writeln!(t, "matrix_world (p_ref = M p_moving):");
    for row in matrix_rows(&r.t_ref_moving) {
        let _ = writeln!(
            t,
            "  [{:>16.9} {:>16.9} {:>16.9} {:>18.6}]",
            row[0], row[1], row[2], row[3]
        );
    }
    t
}
