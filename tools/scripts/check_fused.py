#!/usr/bin/env python3
"""Check a GeoTIFF written by `dsmstream fuse` with GDAL (through rasterio)
against dsmstream's own GeoTIFF reader.

GDAL side: driver, size, type, CRS, geotransform (north-up), no-data (NaN),
256 px tiles, Deflate, internal overviews (2x, 4x, ... down to one tile), each
overview equal to the no-data-aware 2x2 mean of the level above.

dsmstream side: the file is ingested with `dsmstream ingest` (which reads it
with dsmstream's GeoTIFF reader and stores the pixels unchanged, float32, NaN
for no-data), and the stored level 0 is read with zarr-python. Geotransform,
size, CRS and every pixel must equal what GDAL reads (NaN == NaN).

    pip install rasterio zarr numpy
    python3 tools/scripts/check_fused.py fused.tif [--dsmstream target/release/dsmstream]

Exit status 0 when every check passes, 1 otherwise. Not run by cargo test.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np
import rasterio
import zarr

ROWS = 1024


def nan_mean_2x(a):
    """The writer's overview rule: mean of the valid pixels of each 2x2 block."""
    h, w = a.shape
    p = np.full((h + h % 2, w + w % 2), np.nan, dtype=np.float64)
    p[:h, :w] = a
    blocks = np.stack([p[0::2, 0::2], p[0::2, 1::2], p[1::2, 0::2], p[1::2, 1::2]])
    valid = np.isfinite(blocks)
    n = valid.sum(axis=0)
    s = np.where(valid, blocks, 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1), np.nan).astype(np.float32)


class Checks:
    def __init__(self):
        self.failed = 0

    def check(self, name, ok, detail=""):
        print(f"{'ok  ' if ok else 'FAIL'} {name}{': ' + detail if detail else ''}")
        if not ok:
            self.failed += 1


def same(a, b):
    """Arrays equal, NaN matching NaN; returns (ok, mismatches)."""
    both_nan = np.isnan(a) & np.isnan(b)
    eq = (a == b) | both_nan
    return bool(eq.all()), int((~eq).sum())


def open_level(path, k):
    """Level k of the file: 0 full resolution, k >= 1 overview k - 1."""
    return rasterio.open(path) if k == 0 else rasterio.open(path, overview_level=k - 1)


def check_overview(path, k):
    """Overview k (0-based) equals the 2x2 mean of the level above, band by band."""
    with open_level(path, k) as above, open_level(path, k + 1) as ov:
        if ov.height != -(-above.height // 2) or ov.width != -(-above.width // 2):
            print(f"     overview {k}: {ov.width} x {ov.height} is not half of "
                  f"{above.width} x {above.height}")
            return False
        for o0 in range(0, ov.height, ROWS):
            o1 = min(ov.height, o0 + ROWS)
            a = above.read(1, window=((2 * o0, min(above.height, 2 * o1)), (0, above.width)))
            want = nan_mean_2x(a)
            got = ov.read(1, window=((o0, o1), (0, ov.width)))
            close = np.isclose(got, want, rtol=0, atol=1e-3) | (np.isnan(got) & np.isnan(want))
            if not close.all():
                print(f"     overview {k}: {int((~close).sum())} pixels differ in rows {o0}..{o1}")
                return False
    return True


def gdal_checks(c, path):
    with rasterio.open(path) as ds:
        print(f"GDAL {rasterio.__gdal_version__}: {path}")
        print(f"  size {ds.width} x {ds.height}, {ds.count} band(s), {ds.dtypes[0]}")
        print(f"  CRS {ds.crs.to_string() if ds.crs else None}")
        print(f"  transform {tuple(ds.transform)[:6]}")
        print(f"  nodata {ds.nodata}, blocks {ds.block_shapes}, "
              f"compression {ds.compression}, overviews {ds.overviews(1)}")
        c.check("one float32 band", ds.count == 1 and ds.dtypes[0] == "float32")
        c.check("has a CRS", ds.crs is not None)
        t = ds.transform
        c.check("north-up geotransform", t.b == 0 and t.d == 0 and t.a > 0 and t.e < 0,
                str(tuple(t)[:6]))
        c.check("no-data is NaN", ds.nodata is not None and np.isnan(ds.nodata), str(ds.nodata))
        c.check("256 px tiles", ds.block_shapes[0] == (256, 256), str(ds.block_shapes[0]))
        comp = ds.compression.value if ds.compression else None
        c.check("Deflate", comp is not None and comp.upper() == "DEFLATE", str(comp))
        ovr = ds.overviews(1)
        want, f = [], 2
        while max(ds.width, ds.height) > 256 * (f // 2):
            want.append(f)
            f *= 2
        c.check("overviews 2x .. one tile", ovr == want, f"{ovr} (expected {want})")
        count, n_valid, lo, hi = 0, 0, np.inf, -np.inf
        for r0 in range(0, ds.height, ROWS):
            band = ds.read(1, window=((r0, min(ds.height, r0 + ROWS)), (0, ds.width)))
            ok = np.isfinite(band)
            count += band.size
            n_valid += int(ok.sum())
            if ok.any():
                lo, hi = min(lo, float(band[ok].min())), max(hi, float(band[ok].max()))
        print(f"  valid pixels {n_valid} of {count} ({100.0 * n_valid / count:.1f} %), "
              f"heights {lo} .. {hi}")
        for k, fct in enumerate(ovr):
            ok = check_overview(path, k)
            c.check(f"overview {fct}x = 2x2 mean of the level above", ok)
        return {
            "width": ds.width,
            "height": ds.height,
            "transform": [t.c, t.a, t.b, t.f, t.d, t.e],
            "epsg": ds.crs.to_epsg() if ds.crs else None,
        }


def reader_checks(c, path, gdal, exe):
    tmp = tempfile.mkdtemp(prefix="check_fused_")
    try:
        store = os.path.join(tmp, "s.zarr")
        r = subprocess.run([exe, "ingest", path, "--store", store, "-q"],
                           capture_output=True, text=True)
        c.check("dsmstream reads the file", r.returncode == 0, r.stderr.strip())
        if r.returncode != 0:
            return
        stem = os.path.splitext(os.path.basename(path))[0]
        with open(os.path.join(store, stem, "zarr.json")) as f:
            meta = json.load(f)["attributes"]["dsmstream"]
        print(f"dsmstream reader: {meta['width']} x {meta['height']}, "
              f"geotransform {meta['geotransform']}, CRS EPSG:{meta['crs'].get('epsg')}")
        c.check("same size", (meta["width"], meta["height"]) == (gdal["width"], gdal["height"]))
        c.check("same geotransform", [float(v) for v in meta["geotransform"]] == gdal["transform"],
                f"{meta['geotransform']} vs {gdal['transform']}")
        c.check("same EPSG", meta["crs"].get("epsg") == gdal["epsg"],
                f"{meta['crs'].get('epsg')} vs {gdal['epsg']}")
        arr = zarr.open_array(os.path.join(store, stem, "0"), mode="r")
        bad = 0
        with rasterio.open(path) as ds:
            for r0 in range(0, ds.height, ROWS):
                r1 = min(ds.height, r0 + ROWS)
                g = ds.read(1, window=((r0, r1), (0, ds.width)))
                ours = arr[r0:r1, :]
                _, n = same(g, ours)
                bad += n
        c.check("every pixel equal (GDAL vs dsmstream reader)", bad == 0, f"{bad} differ")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("fused")
    ap.add_argument("--dsmstream", default=os.path.join(
        os.path.dirname(os.path.abspath(__file__)), "..", "target", "release", "dsmstream"))
    a = ap.parse_args()
    c = Checks()
    gdal = gdal_checks(c, a.fused)
    reader_checks(c, a.fused, gdal, a.dsmstream)
    if shutil.which("gdalinfo"):
        r = subprocess.run(["gdalinfo", a.fused], capture_output=True, text=True)
        lines = [l for l in r.stdout.splitlines()
                 if l.startswith(("Size is", "Origin", "Pixel Size", "  Overviews", "  NoData"))
                 or "LAYOUT=" in l or "COMPRESSION=" in l]
        print("gdalinfo:\n  " + "\n  ".join(lines))
    print(f"{'all checks passed' if c.failed == 0 else f'{c.failed} check(s) failed'}")
    sys.exit(1 if c.failed else 0)


if __name__ == "__main__":
    main()
