#!/usr/bin/env python3
"""Check a GeoTIFF written by dsmstream's CogWriter with GDAL (through rasterio).

Prints what GDAL sees (size, type, CRS, geotransform, no-data, tiling,
compression, predictor, overviews, ghost header), compares the pixels with a
NumPy array when one is given (NaN == NaN), checks every overview against the
no-data-aware 2x mean of the level above, and runs `rio cogeo validate`.

    pip install rasterio rio-cogeo numpy
    dsmgen big --size 3000 --out /tmp/big.tif --npy /tmp/big.npy
    python3 tools/scripts/check_cog.py /tmp/big.tif --expect /tmp/big.npy

Exit status 0 when every check passes, 1 otherwise. Not run by cargo test.
"""

import argparse
import subprocess
import sys

import numpy as np
import rasterio


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


def compare(name, got, want, atol):
    """Print and return whether two arrays agree (NaN matching NaN)."""
    if got.shape != want.shape:
        print(f"FAIL {name}: shape {got.shape} != expected {want.shape}")
        return False
    nan_got, nan_want = np.isnan(got), np.isnan(want)
    nan_mismatch = int((nan_got != nan_want).sum())
    both = ~nan_got & ~nan_want
    diff = np.abs(got[both].astype(np.float64) - want[both].astype(np.float64))
    max_diff = float(diff.max()) if diff.size else 0.0
    ok = nan_mismatch == 0 and max_diff <= atol
    print(
        f"{'ok  ' if ok else 'FAIL'} {name}: {got.shape[1]}x{got.shape[0]}, "
        f"no-data {int(nan_got.sum())}, no-data mismatches {nan_mismatch}, "
        f"max |diff| {max_diff:.3g} (tolerance {atol})"
    )
    return ok


def read_nan(src, **kw):
    a = src.read(1, **kw).astype(np.float32)
    if src.nodata is not None and not np.isnan(src.nodata):
        a[a == np.float32(src.nodata)] = np.nan
    return a


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path")
    ap.add_argument("--expect", help=".npy array of the full-resolution pixels")
    args = ap.parse_args()
    ok = True

    with rasterio.open(args.path) as src:
        tags = src.tags(ns="IMAGE_STRUCTURE")
        print(f"driver      {src.driver}")
        print(f"size        {src.width} x {src.height}, {src.count} band, {src.dtypes[0]}")
        print(f"crs         {src.crs}")
        print(f"transform   {tuple(src.transform)[:6]}")
        print(f"nodata      {src.nodata}")
        print(f"blocks      {src.block_shapes[0]} (tiled: {src.profile.get('tiled')})")
        print(f"compression {tags.get('COMPRESSION')}, predictor {tags.get('PREDICTOR')}")
        print(f"layout      {tags.get('LAYOUT')}")
        print(f"overviews   {src.overviews(1)}")
        ghost = src.get_tag_item("GDAL_STRUCTURAL_METADATA", "TIFF")
        print(f"ghost hdr   {ghost!r}")
        full = read_nan(src)
        if args.expect:
            want = np.load(args.expect).astype(np.float32)
            ok &= compare("full resolution vs --expect", full, want, 0.0)
        n_overviews = len(src.overviews(1))

    prev = full
    for level in range(n_overviews):
        with rasterio.open(args.path, OVERVIEW_LEVEL=level) as ovr:
            got = read_nan(ovr)
        want = nan_mean_2x(prev)
        ok &= compare(f"overview {level} vs 2x nan-mean", got, want, 1e-3)
        prev = got

    print("rio cogeo validate:")
    run = subprocess.run(
        ["rio", "cogeo", "validate", args.path], capture_output=True, text=True
    )
    print("  " + (run.stdout + run.stderr).strip().replace("\n", "\n  "))
    if run.returncode != 0 or "is a valid cloud optimized GeoTIFF" not in run.stdout:
        ok = False

    print("ALL CHECKS PASSED" if ok else "SOME CHECKS FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
