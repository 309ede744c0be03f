#!/usr/bin/env python3
"""CODEM's photogrammetric DSM against its own lidar, dsmstream beside xDEM.

fixtures/real/codem: dem.tif (1 m DSM) and pc.laz (lidar, EPSG:32616). The
lidar is gridded with `dsmgen grid` (highest first return per cell; also the
mean, and a lattice half a cell away) and, once, 132 m lower (a vertical datum
offset). Every method registers dem.tif (moving) onto each gridded lidar
(reference); the table gives the shift p_ref - p_moving at the centre of
dsmstream's fit on the first lidar, so that all rows are read at one point.
xDEM's methods run with their defaults on the DSM reprojected onto the lidar's
grid (tools/scripts/compare_peers.py, `--one`). A last row per reference is a
brute-force check independent of both: the horizontal shift (0.05 m steps
within 1 m) that minimises the NMAD of the height differences over smooth
sloped cells of the lidar (3-60 deg, within 0.2 m of their 5 x 5 mean), and
the median difference over smooth flat cells (slope below 3 deg) as dz.

    cargo build --release --bins
    python3 tools/scripts/codem_compare.py [--bin target/release]
"""
import argparse, json, os, subprocess, sys, tempfile, time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
CODEM = os.path.join(ROOT, "fixtures/real/codem")
LIDARS = {  # name: dsmgen grid flags
    "lidar max 1 m": [],
    "lidar max 1 m, lattice +0.5": ["--origin", "626996.5", "4323936.5"],
    "lidar mean 1 m": ["--stat", "mean"],
    "lidar max 1 m, 132 m lower": ["--dz", "-132"],
}
PEERS = ["xdem-nuthkaab", "xdem-icp", "xdem-nuthkaab+icp"]


def stable_terrain(lidar_path, dem_path):
    """(dx, dy, dz) p_ref - p_moving from the lidar's smooth cells (module docs)."""
    import rasterio
    from scipy.ndimage import map_coordinates, uniform_filter
    with rasterio.open(lidar_path) as f:
        lidar, lt = f.read(1).astype(float), f.transform
    with rasterio.open(dem_path) as f:
        dem, dt = f.read(1).astype(float), f.transform
        if f.nodata is not None:
            dem[dem == f.nodata] = np.nan
    rows, cols = np.mgrid[0:lidar.shape[0], 0:lidar.shape[1]]
    x, y = lt.c + (cols + 0.5) * lt.a, lt.f + (rows + 0.5) * lt.e
    gy, gx = np.gradient(lidar)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    smooth = np.abs(lidar - uniform_filter(np.nan_to_num(lidar), 5)) < 0.2

    def dh(dx, dy):  # reference minus the moving DSM moved by (dx, dy)
        c, r = (x - dx - dt.c) / dt.a - 0.5, (y - dy - dt.f) / dt.e - 0.5
        moved = map_coordinates(dem, [r.ravel(), c.ravel()], order=1, cval=np.nan)
        return lidar - moved.reshape(lidar.shape)

    def nmad(v):
        return 1.4826 * np.median(np.abs(v - np.median(v)))

    sloped = smooth & (slope > 3) & (slope < 60)
    steps = np.round(np.arange(-1.0, 1.001, 0.05), 2)
    cost = {(dx, dy): nmad(h[sloped & np.isfinite(h)]) for dx in steps for dy in steps
            for h in [dh(dx, dy)]}
    dx, dy = min(cost, key=cost.get)
    h = dh(dx, dy)
    return dx, dy, float(np.median(h[smooth & (slope < 3) & np.isfinite(h)]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default=os.path.join(ROOT, "target/release"))
    a = ap.parse_args()
    dsmgen, dsm = os.path.join(a.bin, "dsmgen"), os.path.join(a.bin, "dsmstream")
    print("| reference | method | dx m | dy m | dz m | sigma x / y / z m | s |")
    print("|---|---|---|---|---|---|---|")
    centre = None
    with tempfile.TemporaryDirectory() as tmp:
        paths = {}
        for k, (name, flags) in enumerate(LIDARS.items()):
            paths[name] = f"{tmp}/lidar{k}.tif"
            subprocess.run([dsmgen, "grid", "--points", f"{CODEM}/pc.laz", "--gsd", "1", *flags,
                            "--out", paths[name]], check=True, capture_output=True)
        store = f"{tmp}/c.zarr"
        subprocess.run([dsm, "ingest", f"{CODEM}/dem.tif", *paths.values(), "--store", store, "-q"],
                       check=True)
        for k, name in enumerate(LIDARS):
            t0 = time.time()
            out = subprocess.run([dsm, "pair", store, f"lidar{k}", "dem", "--json"],
                                 capture_output=True, text=True)
            seconds = time.time() - t0
            if out.returncode != 0:
                print(f"| {name} | dsmstream | failed: {out.stderr.strip()} | | | | |")
                continue
            j = json.loads(out.stdout)
            m = np.array(j["matrix_world"])
            if centre is None:
                centre = np.array(j["centre_m"] + [1.0])
            s = m @ centre - centre
            sig = " / ".join(f"{v:.3f}" for v in j["sigma"]["shift_m"])
            print(f"| {name} | dsmstream ({j['status']}) | {s[0]:.3f} | {s[1]:.3f} | {s[2]:.3f} "
                  f"| {sig} | {seconds:.1f} |")
            for peer in PEERS:
                t0 = time.time()
                out = subprocess.run([sys.executable, f"{HERE}/compare_peers.py", "--one", peer,
                                      paths[name], f"{CODEM}/dem.tif"], capture_output=True, text=True)
                seconds = time.time() - t0
                if out.returncode != 0:
                    print(f"| {name} | {peer} | failed: {out.stderr.strip().splitlines()[-1]} | | | | |")
                    continue
                m = np.array(json.loads(out.stdout.strip().splitlines()[-1]))
                s = m @ centre - centre
                print(f"| {name} | {peer} | {s[0]:.3f} | {s[1]:.3f} | {s[2]:.3f} | | {seconds:.1f} |")
            t0 = time.time()
            dx, dy, dz = stable_terrain(paths[name], f"{CODEM}/dem.tif")
            print(f"| {name} | smooth cells, brute force | {dx:.2f} | {dy:.2f} | {dz:.3f} | "
                  f"| {time.time() - t0:.1f} |")


if __name__ == "__main__":
    main()
