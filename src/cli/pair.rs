//! `dsmstream pair <store> <ref-id> <moving-id>`: one pairwise DSM-ICP through
//! the chunk cache, printed as a table or JSON (the transform as
//! `matrix_world`, the name poses.json uses).

use std::path::PathBuf;

use dsmstream::icp::{matrix_rows, register, IcpError, IcpResult};
use dsmstream::store::StorePyramid;
use dsmstream::InputError;

use super::common::{emit, emit_line, find_dsm, open_store, ResourceArgs};
use super::icp_args::IcpArgs;

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
    let cache = args.resources.cache();
    let started = std::time::Instant::now();
    let result = args.resources.pool()?.install(|| {
        register(
            &StorePyramid::new(&store, &cache, i),
            &StorePyramid::new(&store, &cache, j),
            &config,
        )
    });
    let result = match result {
        Ok(r) => r,
        Err(e @ (IcpError::NoOverlap | IcpError::EmptyOverlap)) => {
            return Err(
                InputError::new(format!("{} and {}: {e}", args.reference, args.moving)).into(),
            )
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
    if args.json {
        let mut result_json = serde_json::to_value(&result)?;
        if let Some(obj) = result_json.as_object_mut() {
            if let Some(m) = obj.remove("m_world") {
                obj.insert("matrix_world".into(), m);
            }
        }
        let value = serde_json::json!({
            "reference": args.reference, "moving": args.moving, "seconds": seconds,
            "result": result_json, "cache": cache.stats(),
        });
        emit_line(&serde_json::to_string_pretty(&value)?)?;
    } else {
        emit(&table(&args.reference, &args.moving, &result, seconds))?;
    }
    if !result.is_usable() {
        anyhow::bail!(
            "registration of {} to {} is not usable: {:?}",
            args.moving,
            args.reference,
            result.status
        );
    }
    Ok(())
}

/// The result as the text table `pair` prints.
fn table(reference: &str, moving: &str, r: &IcpResult, seconds: f64) -> String {
    use std::fmt::Write as _;
    let mut t = String::new();
    let m = matrix_rows(&r.t_ref_moving);
    let rot = nalgebra::Matrix3::from_fn(|a, b| m[a][b]);
    let angle_deg = ((rot.trace() - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees();
    let _ = writeln!(t, "pair        {moving} -> {reference}");
    let _ = writeln!(
        t,
        "status      {:?} after {} iterations ({seconds:.2} s)",
        r.status, r.iterations
    );
    let _ = writeln!(
        t,
        "rmse        {:.4} m (NN distance, inliers)   plane rmse {:.4} m",
        r.rmse_m, r.rmse_plane_m
    );
    let _ = writeln!(
        t,
        "inliers     {} of {} samples   overlap {:.3}",
        r.inliers, r.samples, r.overlap
    );
    let _ = writeln!(
        t,
        "rotation    {angle_deg:.6} deg   constraint ratio {:.2e}",
        r.constraint_ratio
    );
    let (sr, st) = (r.sigma.rot_deg, r.sigma.trans_m);
    let _ = writeln!(
        t,
        "1-sigma     tilt {:.5} {:.5} deg  yaw {:.5} deg  shift {:.4} {:.4} {:.4} m",
        sr[0], sr[1], sr[2], st[0], st[1], st[2]
    );
    let _ = writeln!(t, "matrix_world (p_ref = M p_moving):");
    for row in m {
        let _ = writeln!(
            t,
            "  [{:>16.9} {:>16.9} {:>16.9} {:>18.6}]",
            row[0], row[1], row[2], row[3]
        );
    }
    t
}
