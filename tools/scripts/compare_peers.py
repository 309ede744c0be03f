#!/usr/bin/env python3
"""dsmstream pair against the tools users reach for, on generated pairs with a
known answer, side by side in one run.

Each case is one `dsmgen tiles --count 2` pair (city terrain at 0.5 m, 0.3 m
noise, 2 % spikes, voids, changed buildings, shifts up to 3 m and rotations up to
0.03 deg per axis; tile_01 is registered onto tile_00). Every method runs in its
own process under /usr/bin/time (wall time, peak RSS) and its 4x4 transform is
compared with truth.json: the worst displacement at the corners of the overlap
and the rotation error (tools/scripts/truth_errors.py).

Methods:
- dsmstream: `dsmstream pair` with its defaults (the store is ingested first;
  ingest time is reported apart, as it is paid once per DSM, not per pair).
- xdem-icp, xdem-nuthkaab, xdem-nuthkaab+icp: xDEM's coregistration with its
  defaults (point-to-plane ICP; Nuth & Kaab), the moving DEM reprojected onto the
  reference grid first (bilinear), as xDEM's documentation does.
- open3d: Open3D point-to-plane ICP on every valid pixel of both tiles (normals
  from 30 neighbours), Tukey loss, coarse to fine (5, 2, 1, 0.5 m).

Needs a release build and a Python with xdem and open3d; they are peers, not
dependencies (the tests never import them):

    python3 -m venv /tmp/peers && /tmp/peers/bin/pip install xdem open3d
    cargo build --release --bins
    /tmp/peers/bin/python tools/scripts/compare_peers.py [--cases 1:1024 7:2048] [--methods ...]
"""
import argparse, json, os, re, subprocess, sys, tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from truth_errors import pair_errors

METHODS = ["dsmstream", "xdem-icp", "xdem-nuthkaab", "xdem-nuthkaab+icp", "open3d"]


def xdem_matrix(kind, ref_path, mov_path):
    """p_ref = M p_moving in world coordinates, from xDEM's fitted steps."""
    import xdem
    ref = xdem.DEM(ref_path)
    tba = xdem.DEM(mov_path).reproject(ref)
    steps = {"xdem-icp": [xdem.coreg.ICP()],
             "xdem-nuthkaab": [xdem.coreg.NuthKaab()],
             "xdem-nuthkaab+icp": [xdem.coreg.NuthKaab(), xdem.coreg.ICP()]}[kind]
    coreg = steps[0] if len(steps) == 1 else xdem.coreg.CoregPipeline(steps)
    coreg.fit(ref, tba)
    fitted = coreg.pipeline if len(steps) > 1 else [coreg]
    total = np.eye(4)
    for step in fitted:
        affine = step.meta["outputs"]["affine"]
        m = np.asarray(step.to_matrix(), dtype=float)
        centroid = affine.get("centroid")
        if centroid is not None:  # rotation about the centroid: T(c) M T(-c)
            c = np.eye(4)
            c[:3, 3] = centroid
            m = c @ m @ np.linalg.inv(c)
        total = m @ total
    return total


def cloud(path, origin):
    """Valid pixel centres of a GeoTIFF as points, minus `origin`."""
    import rasterio
    with rasterio.open(path) as src:
        z = src.read(1).astype(np.float64)
        nodata = src.nodata
        rows, cols = np.nonzero(np.isfinite(z) & ((z != nodata) if nodata is not None else True))
        xs, ys = rasterio.transform.xy(src.transform, rows, cols)
    pts = np.column_stack([np.asarray(xs), np.asarray(ys), z[rows, cols]])
    return pts - origin


def open3d_matrix(ref_path, mov_path):
    import open3d as o3d
    import rasterio
    with rasterio.open(ref_path) as src:
        origin = np.array([src.transform.c, src.transform.f, 0.0])
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud(ref_path, origin)))
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud(mov_path, origin)))
    target.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=30))
    reg = o3d.pipelines.registration
    local = np.eye(4)
    for distance in (5.0, 2.0, 1.0, 0.5):
        loss = reg.TukeyLoss(k=distance)
        result = reg.registration_icp(
            source, target, distance, local,
            reg.TransformationEstimationPointToPlane(loss),
            reg.ICPConvergenceCriteria(max_iteration=50))
        local = result.transformation
    shift = np.eye(4)
    shift[:3, 3] = origin
    return shift @ local @ np.linalg.inv(shift)


def timed(cmd, ok_codes=(0,)):
    """Runs cmd under /usr/bin/time -v: (stdout, wall s, peak RSS MiB)."""
    out = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True)
    if out.returncode not in ok_codes:
        raise RuntimeError(f"{' '.join(cmd)}: {out.stderr.strip().splitlines()[-3:]}")
    wall = re.search(r"Elapsed \(wall clock\) time.*: (\S+)", out.stderr).group(1)
    seconds = sum(float(p) * 60 ** k for k, p in enumerate(reversed(wall.split(":"))))
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr).group(1))
    return out.stdout, seconds, rss / 1024


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="target/release")
    ap.add_argument("--cases", nargs="+", default=["1:1024"],
                    help="seed:size[:more dsmgen tiles flags], e.g. '3:512:--dz-offset 150'")
    ap.add_argument("--methods", nargs="+", default=METHODS, choices=METHODS)
    ap.add_argument("--one", nargs=3, metavar=("METHOD", "REF", "MOVING"),
                    help=argparse.SUPPRESS)  # internal: one peer, prints its matrix
    a = ap.parse_args()
    if a.one:
        method, ref, mov = a.one
        m = open3d_matrix(ref, mov) if method == "open3d" else xdem_matrix(method, ref, mov)
        print(json.dumps(np.asarray(m).tolist()))
        return
    dsmgen, dsm = os.path.join(a.bin, "dsmgen"), os.path.join(a.bin, "dsmstream")
    print("| case | method | worst error at the overlap corners (cm) | rotation error (deg) | wall s | peak RSS MiB |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for case in a.cases:
            seed, size, *more = case.split(":", 2)
            name = f"c{a.cases.index(case)}"
            tiles, store = f"{tmp}/t{name}", f"{tmp}/s{name}.zarr"
            extra = more[0].split() if more else []
            subprocess.run([dsmgen, "tiles", "--count", "2", "--size", size, "--seed", seed,
                            *extra, "--out", tiles], check=True, capture_output=True)
            truth = json.load(open(f"{tiles}/truth.json"))
            ref, mov = f"{tiles}/tile_00.tif", f"{tiles}/tile_01.tif"
            for method in a.methods:
                if method == "dsmstream":
                    _, ingest_s, ingest_mb = timed([dsm, "ingest", tiles, "--store", store, "-q"])
                    # exit 1: a result that is not converged, reported with its status
                    out, secs, mb = timed([dsm, "pair", store, "tile_00", "tile_01", "--json"],
                                          ok_codes=(0, 1))
                    doc = json.loads(out)
                    est = doc["result"]["matrix_world"]
                    note = f" (+ ingest {ingest_s:.1f} s, {ingest_mb:.0f} MiB)"
                    if doc["status"] != "converged":
                        note += f", {doc['status']}"
                else:
                    try:
                        out, secs, mb = timed([sys.executable, __file__, "--one", method, ref, mov])
                    except RuntimeError as e:
                        print(f"| {case} | {method} | failed: {str(e)[-120:]} | | | |", flush=True)
                        continue
                    est, note = json.loads(out), ""
                worst, ang, _ = pair_errors(truth, est, 0, 1)
                print(f"| {case} | {method} | {worst * 100:.1f} | {ang:.4f} "
                      f"| {secs:.1f}{note} | {mb:.0f} |", flush=True)


if __name__ == "__main__":
    main()
