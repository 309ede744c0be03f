#!/usr/bin/env python3
"""DSMs in longitude and latitude: dsmstream's ingest (which puts them into UTM
as it reads) against GDAL's warp, side by side.

For each source (demcompare's SRTM tile, 3" pixels, and the same tile resampled
by GDAL to 1" and to 1/3", 9x and 81x the pixels, as Copernicus GLO-30 and a
10 m national DSM in degrees would be; and GDAL's UTM 37N warp of the tile at
90 m, and that resampled to 10 m, put into UTM 38N as a DSM across a zone
boundary is; Tommy Thompson Park's 1 m lidar DSM in UTM 17N, and that resampled
to 0.25 m, put into NAD83 / Conus Albers; and the SRTM tile, labelled as ETRS89
degrees, at 3" and 1/3", put into LAEA Europe: national grids), prints:
  - dsmstream ingest of the source: wall s, peak RSS MB, output size;
  - GDAL (rasterio.warp.reproject, bilinear, to the same UTM grid, in memory)
    then dsmstream ingest of GDAL's UTM file: wall s each;
  - exactness: over 2,000 random valid output pixels, the largest difference
    (m) between the stored height and the bilinear interpolation of the source
    at the pixel centre's position as PROJ computes it (rasterio.warp.transform);
  - agreement: `dsmstream eval` of the two stored DSMs (ours and GDAL's on the
    same grid), dh median and NMAD (m) over their common pixels. GDAL's warper
    does not interpolate at the exact position (its bilinear kernel differs).

Usage: bench_warp.py DSMSTREAM WORKDIR [STEM ...]   (needs rasterio and zarr: the
peers' venv; STEMs pick rows, e.g. ttp_utm17_to_albers)
"""
import json
import os
import subprocess
import sys
import time

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.enums import Resampling
from rasterio.transform import Affine
from rasterio.warp import reproject

HERE = os.path.dirname(os.path.abspath(__file__))
SRTM = os.path.join(HERE, "../../fixtures/real/demcompare_srtm/srtm_ref.tif")
SRTM_UTM = os.path.join(HERE, "../../fixtures/real/demcompare_srtm/srtm_ref_utm.tif")
TTP = os.path.join(HERE, "../../fixtures/real/ttp2015/ttp_dsm_source.tif")


def timed(cmd):
    """(wall s, peak RSS MB, stdout) of a command, through /usr/bin/time."""
    t0 = time.perf_counter()
    out = subprocess.run(
        ["/usr/bin/time", "-f", "%M"] + cmd, capture_output=True, text=True
    )
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed: {out.stderr}")
    rss_kb = int(out.stderr.strip().splitlines()[-1])
    return wall, rss_kb / 1024, out.stdout


def upsampled(factor, path, source=SRTM, crs=None):
    """The source at 1/factor of its pixel, bilinear (GDAL), Float32 tiled Deflate
    (labelled `crs` when given)."""
    with rasterio.open(source) as src:
        data = src.read(1, out_shape=(src.height * factor, src.width * factor),
                        resampling=Resampling.bilinear, masked=True)
        profile = src.profile.copy()
        t = src.transform
        profile.update(
            width=src.width * factor, height=src.height * factor, dtype="float32",
            nodata=-32768.0, tiled=True, blockxsize=256, blockysize=256,
            compress="deflate", transform=Affine(t.a / factor, 0, t.c, 0, t.e / factor, t.f),
        )
        if crs is not None:
            profile.update(crs=CRS.from_epsg(crs))
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(data.filled(-32768.0).astype("float32"), 1)


def exactness(store, name, src_path, gt, epsg):
    """Largest |stored - exact bilinear at PROJ's position| over random valid pixels
    (the store in EPSG:`epsg`)."""
    import zarr
    from rasterio.warp import transform
    ours = zarr.open_array(os.path.join(store, name, "0"), mode="r")[:]
    with rasterio.open(src_path) as s:
        z = s.read(1, masked=True).astype(float).filled(np.nan)
        st = s.transform
        src_crs = s.crs
    rng = np.random.default_rng(1)
    rr, cc = np.nonzero(np.isfinite(ours))
    pick = rng.choice(len(rr), size=min(2000, len(rr)), replace=False)
    rr, cc = rr[pick], cc[pick]
    e = gt[0] + (cc + 0.5) * gt[1]
    n = gt[3] + (rr + 0.5) * gt[5]
    lon, lat = transform(f"EPSG:{epsg}", src_crs, e.tolist(), n.tolist())
    u = (np.array(lon) - st.c) / st.a - 0.5
    v = (np.array(lat) - st.f) / st.e - 0.5
    i, j = np.floor(u).astype(int), np.floor(v).astype(int)
    fx, fy = u - i, v - j
    inside = (i >= 0) & (j >= 0) & (i + 1 < z.shape[1]) & (j + 1 < z.shape[0])
    i, j, fx, fy = i[inside], j[inside], fx[inside], fy[inside]
    exact = (z[j, i] * (1 - fx) * (1 - fy) + z[j, i + 1] * fx * (1 - fy)
             + z[j + 1, i] * (1 - fx) * fy + z[j + 1, i + 1] * fx * fy)
    d = ours[rr[inside], cc[inside]] - exact
    return float(np.nanmax(np.abs(d)))


def main():
    binary, work = sys.argv[1], sys.argv[2]
    os.makedirs(work, exist_ok=True)
    rows = []
    only = sys.argv[3:]
    cases = [("srtm", SRTM, f, 32637, [], None) for f in (1, 3, 9)]
    cases += [("srtm_utm37_to_38", SRTM_UTM, f, 32638, ["--utm-zone", "38N"], None) for f in (1, 9)]
    cases += [("ttp_utm17_to_albers", TTP, f, 5070, ["--crs", "EPSG:5070"], None) for f in (1, 4)]
    cases += [("srtm_etrs89_to_laea", SRTM, f, 3035, ["--crs", "EPSG:3035"], 4258) for f in (1, 9)]
    for stem, source, factor, epsg, flags, relabel in cases:
        name = f"{stem}_x{factor}"
        if only and stem not in only:
            continue
        src = os.path.join(work, f"{name}.tif")
        if factor == 1 and relabel is None:
            subprocess.run(["cp", source, src], check=True)
        else:
            upsampled(factor, src, source, relabel)
        store = os.path.join(work, f"{name}.zarr")
        subprocess.run(["rm", "-rf", store], check=True)
        wall, rss, said = timed([binary, "ingest", src, "--store", store, "-q"] + flags)
        info = json.loads(subprocess.run([binary, "info", store, "--json"],
                                         capture_output=True, text=True, check=True).stdout)
        dsm = info["dsms"][0]
        gt, w, h = dsm["geotransform"], dsm["width"], dsm["height"]
        # GDAL onto the very same grid
        t0 = time.perf_counter()
        with rasterio.open(src) as s:
            out = np.full((h, w), np.nan, dtype="float32")
            dst_t = Affine(gt[1], 0, gt[0], 0, gt[5], gt[3])
            reproject(rasterio.band(s, 1), out, dst_transform=dst_t, dst_crs=CRS.from_epsg(epsg),
                      dst_nodata=np.nan, resampling=Resampling.bilinear, tolerance=0)
        gdal_s = time.perf_counter() - t0
        gpath = os.path.join(work, f"{name}_gdal.tif")
        with rasterio.open(gpath, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32",
                           crs=CRS.from_epsg(epsg), transform=dst_t, nodata=np.nan, tiled=True,
                           compress="deflate") as d:
            d.write(out, 1)
        gwall, grss, _ = timed([binary, "ingest", gpath, "--store", store, "-q"])
        ev = subprocess.run([binary, "eval", store, "--json", "-q"], capture_output=True,
                            text=True, check=True)
        pair = json.loads(ev.stdout)["pairs"][0]["before"]
        rows.append((name, f"{w} x {h}", gt[1], wall, rss, exactness(store, name, src, gt, epsg),
                     gdal_s, gwall, pair["median_m"], pair["nmad_m"], pair["samples"]))
    print("| source | UTM grid (px) | pixel m | dsmstream ingest of the source s | peak MB | "
          "max off exact bilinear m | GDAL warp s | + ingest of GDAL's file s | "
          "ours - GDAL dh median m | NMAD m | samples |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]:g} | {r[3]:.2f} | {r[4]:.0f} | {r[5]:.4f} | {r[6]:.2f} | "
              f"{r[7]:.2f} | {r[8]:.4f} | {r[9]:.4f} | {r[10]} |")


if __name__ == "__main__":
    main()
