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

use crate::util::{assert_ok, bin, dsmgen, fixtures, ingest};

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
        let run = dsmgen()
            .arg("grid")
            .arg("--points")
            .arg(ttp("TTP_15.laz"))
            .args(["--gsd", gsd, "--stat", stat, "--out"])
            .arg(&out)
            .output()
            .unwrap();
        assert_ok(&run);
        inputs.push(out);
    }
    let store = dir.path().join("c.zarr");
    ingest(&inputs, &store);
    for (name, _, _) in grids {
        let out = bin()
            .arg("pair")
            .arg(&store)
            .args(["ttp_dsm_source", name, "--json"])
            .output()
            .unwrap();
        assert_ok(&out);
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        assert_eq!(json["status"], "converged", "{name}");
        for k in 0..3 {
            let (shift, sigma) = (
                json["shift_m"][k].as_f64().unwrap(),
                json["sigma"]["shift_m"][k].as_f64().unwrap(),
            );
            assert!(
                sigma > 0.0 && shift.abs() <= 3.0 * sigma,
                "{name} axis {k}: {shift:.3} +- {sigma:.3} m from the identity"
            );
        }
    }
}
