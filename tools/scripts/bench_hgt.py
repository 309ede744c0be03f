#!/usr/bin/env python3
"""SRTM HGT tiles: dsmstream's reader against GDAL's SRTMHGT driver, side by side.

Builds full-size tiles of real heights: demcompare's SRTM crop (srtm_ref.tif,
1000 x 1000 px of 3") as the 3" tile N39E040 (1201 x 1201) and, resampled by GDAL
(bilinear) to 1", as the 1" tile N39E040 (3601 x 3601), each zipped as LP DAAC
delivers them (`N39E040.SRTMGL3.hgt.zip`, `N39E040.SRTMGL1.hgt.zip`). For each:
  - GDAL's reading of the zip, written as a GeoTIFF (`rasterio.shutil.copy`,
    int16, Deflate): what a user would have had to do before;
  - `dsmstream ingest` of the zip, of the tile unzipped and of GDAL's GeoTIFF
    into three stores: wall s and peak RSS MB (median of 3 runs each);
  - whether the two stores hold the same heights bit for bit (level 0, zarr)
    and the same grid (and the unzipped tile's store the zip's): dsmstream
    places and reads the tile as GDAL does.

Usage: bench_hgt.py DSMSTREAM WORKDIR   (needs rasterio, zarr: the peers' venv)
"""
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
import zipfile

import numpy as np
import rasterio
import rasterio.shutil
from rasterio.enums import Resampling

HERE = os.path.dirname(os.path.abspath(__file__))
SRTM = os.path.join(HERE, "../../fixtures/real/demcompare_srtm/srtm_ref.tif")


def timed(cmd):
    """(wall s, peak RSS MB) of a command, through /usr/bin/time."""
    t0 = time.perf_counter()
    out = subprocess.run(["/usr/bin/time", "-f", "%M"] + cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed: {out.stderr}")
    return wall, int(out.stderr.strip().splitlines()[-1]) / 1024


def tile(factor, work):
    """The zipped 1201 or 3601 tile of the SRTM crop at 3"/factor."""
    n = 1200 * factor + 1
    with rasterio.open(SRTM) as src:
        data = src.read(1, out_shape=(src.height * factor, src.width * factor),
                        resampling=Resampling.bilinear)
    heights = np.full((n, n), -32768, dtype=">i2")
    heights[: data.shape[0], : data.shape[1]] = data
    product = {1: "SRTMGL3", 3: "SRTMGL1"}[factor]
    path = os.path.join(work, f"N39E040.{product}.hgt.zip")
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("N39E040.hgt", heights.tobytes())
    plain = os.path.join(work, "N39E040.hgt")
    heights.tofile(plain)
    return path, plain


def ingest(exe, src, store):
    runs = []
    for _ in range(3):
        shutil.rmtree(store, ignore_errors=True)
        runs.append(timed([exe, "ingest", src, "--store", store, "-q"]))
    return statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)


def level0(store):
    import zarr

    (name,) = [d for d in os.listdir(store) if not d.startswith(".") and d != "zarr.json"]
    with open(os.path.join(store, name, "zarr.json")) as f:
        attrs = json.load(f)["attributes"]["dsmstream"]
    return zarr.open_array(os.path.join(store, name, "0"), mode="r")[:], attrs


def main():
    exe, work = sys.argv[1], sys.argv[2]
    os.makedirs(work, exist_ok=True)
    print("| tile | samples | zip MB | dsmstream ingest of the zip s | peak MB "
          "| of the .hgt s | peak MB | GDAL to GeoTIFF s | ingest of GDAL's GeoTIFF s | peak MB "
          "| same grid | same heights (bits) | valid px |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for factor in (1, 3):
        z, plain = tile(factor, work)
        t0 = time.perf_counter()
        gtiff = z.replace(".hgt.zip", ".gdal.tif")
        rasterio.shutil.copy(z, gtiff, driver="GTiff", compress="deflate", tiled=True)
        gdal_s = time.perf_counter() - t0
        ours_s, ours_mb = ingest(exe, z, os.path.join(work, "zip.zarr"))
        hgt_s, hgt_mb = ingest(exe, plain, os.path.join(work, "hgt.zarr"))
        tif_s, tif_mb = ingest(exe, gtiff, os.path.join(work, "tif.zarr"))
        a, attrs_a = level0(os.path.join(work, "zip.zarr"))
        b, attrs_b = level0(os.path.join(work, "tif.zarr"))
        c, attrs_c = level0(os.path.join(work, "hgt.zarr"))
        same_grid = all(
            attrs["geotransform"] == attrs_a["geotransform"] and x.shape == a.shape
            for attrs, x in ((attrs_b, b), (attrs_c, c))
        )
        same = same_grid and all(
            np.array_equal(a.view(np.uint32), x.view(np.uint32)) for x in (b, c)
        )
        n = 1200 * factor + 1
        print(f"| {os.path.basename(z)} | {n} x {n} | {os.path.getsize(z) / 1e6:.1f} "
              f"| {ours_s:.2f} | {ours_mb:.0f} | {hgt_s:.2f} | {hgt_mb:.0f} "
              f"| {gdal_s:.2f} | {tif_s:.2f} | {tif_mb:.0f} "
              f"| {same_grid} | {same} | {int(np.isfinite(a).sum())} |")


if __name__ == "__main__":
    main()
