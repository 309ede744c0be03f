//! A real DSM against grids of its own lidar: Tommy Thompson Park's 1 m DSM
//! (fixtures/real/ttp2015, MIT, derived by its publisher from `TTP_15.laz`)
//! and the same points gridded again by `dsmgen grid` at 2 and 3 m (highest
//! or mean first return per cell; 72,573 returns over 0.38 km2, a third to a
//! half of the cells filled, the rest water and gaps). The truth is the
//! identity. A 2 m grid of the highest returns made the fit cycle by +-5 cm
//! along y (its sigma 0.8 cm, the gridding floor 10 cm): `pair` ran out of
//! iterations 2 cm from the truth and exited 1 until such a jitter within the
//! floor counted as settled (`icp::iterate::settle`).

use std::path::PathBuf;

use crate::util::{dsmgen_grid, fixtures, ingest, pair_json, shift_and_sigma};

fn ttp(name: &str) -> PathBuf {
    fixtures().join("real/ttp2015").join(name)
}

#[test]
fn regridded_lidar_registers_to_its_dsm_at_the_identity() {
    let dir = tempfile::tempdir().unwrap();
    let grids = [
        ("max2", "2", "max"),
        ("mean2", "2", "mean"),
        ("max3", "3", "max"),
    ];
    let mut inputs = vec![ttp("ttp_dsm_source.tif")];
    for (name, gsd, stat) in grids {
        let out = dir.path().join(format!("{name}.tif"));
        dsmgen_grid(&ttp("TTP_15.laz"), &["--gsd", gsd, "--stat", stat], &out);
        inputs.push(out);
    }
    let store = dir.path().join("c.zarr");
    ingest(&inputs, &store);
    for (name, _, _) in grids {
        let (code, doc) = pair_json(&store, "ttp_dsm_source", name);
        assert_eq!(code, Some(0), "{name}: {doc}");
        assert_eq!(doc["status"], "converged", "{name}");
        let (shift, sigma) = shift_and_sigma(&doc);
        for k in 0..3 {
            assert!(
                sigma[k] > 0.0 && shift[k].abs() <= 3.0 * sigma[k],
                "{name} axis {k}: {:.3} +- {:.3} m from the identity",
                shift[k],
                sigma[k]
            );
        }
    }
}
