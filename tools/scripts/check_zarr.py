#!/usr/bin/env python3
"""Check a dsmstream store with independent readers: zarr-python for the store,
rasterio (GDAL) for the source GeoTIFFs.

For every DSM listed in the root catalog:
  * level 0 must equal the source GeoTIFF pixel for pixel (source no-data and
    non-finite values -> NaN, values cast to float32 as the ingest reader does);
  * every overview level k must equal the 2x2 mean of the valid pixels of the
    stored level k-1 (NaN where none), computed here in float64 in the same
    order, so the comparison is exact;
  * the catalog attributes (shape, geotransform, valid count, levels) must
    match what rasterio and the arrays say;
  * each level array's georeferencing attributes (the spatial:/proj: Zarr
    conventions GDAL >= 3.13 reads) must match: spatial:transform is the
    level's geotransform in [a, b, c, d, e, f] order, spatial:shape its shape,
    proj:code the source's EPSG code (when it has one).
Reads a block of rows at a time, so large stores are fine.

Prints a table and exits 1 on any mismatch, 2 on bad usage.

    pip install zarr numpy rasterio
    python3 tools/scripts/check_zarr.py collection.zarr
"""

import argparse
import math
import sys

import numpy as np
import rasterio
import zarr


def source_rows(ds, r0, r1):
    """Rows r0..r1 of band 1 as float32, no-data and non-finite -> NaN."""
    win = rasterio.windows.Window(0, r0, ds.width, r1 - r0)
    raw = ds.read(1, window=win)
    out = raw.astype(np.float32)
    if ds.nodata is not None:
        if math.isnan(ds.nodata):
            out[np.isnan(raw)] = np.nan
        else:
            out[raw == ds.nodata] = np.nan
    out[~np.isfinite(out)] = np.nan
    return out


def mean_2x2(rows):
    """2x2 mean of the valid pixels (float64 sum in a, a+1, b, b+1 order)."""
    h, w = rows.shape
    if h % 2:
        rows = np.vstack([rows, np.full((1, w), np.nan, np.float32)])
    if w % 2:
        rows = np.hstack([rows, np.full((rows.shape[0], 1), np.nan, np.float32)])
    v = rows.astype(np.float64)
    parts = [v[0::2, 0::2], v[0::2, 1::2], v[1::2, 0::2], v[1::2, 1::2]]
    total = np.zeros_like(parts[0])
    count = np.zeros(parts[0].shape, np.int64)
    for p in parts:
        ok = ~np.isnan(p)
        total = total + np.where(ok, p, 0.0)
        count += ok
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (total / count).astype(np.float32)
    mean[count == 0] = np.nan
    return mean


def compare(got, want):
    """(mismatching pixels, max |diff| over pixels valid in both)."""
    nan_g, nan_w = np.isnan(got), np.isnan(want)
    both = ~nan_g & ~nan_w
    bad = (nan_g != nan_w) | (both & (got != want))
    diff = float(np.max(np.abs(got[both].astype(np.float64) - want[both]))) if both.any() else 0.0
    return int(bad.sum()), diff


def georef_problems(k, arr, gt0, src):
    """Differences between level k's spatial:/proj: attributes and the source."""
    attrs = dict(arr.attrs)
    f = float(2 ** k)
    want = [gt0[1] * f, gt0[2] * f, gt0[0], gt0[4] * f, gt0[5] * f, gt0[3]]
    got = attrs.get("spatial:transform")
    out = []
    if got is None or any(abs(a - b) > 1e-9 * max(1.0, abs(a)) for a, b in zip(want, got)):
        out.append(f"level {k}: spatial:transform {got} vs {want}")
    if list(attrs.get("spatial:shape", [])) != list(arr.shape):
        out.append(f"level {k}: spatial:shape {attrs.get('spatial:shape')} vs {list(arr.shape)}")
    epsg = src.crs.to_epsg() if src.crs else None
    if epsg is not None and attrs.get("proj:code") != f"EPSG:{epsg}":
        out.append(f"level {k}: proj:code {attrs.get('proj:code')} vs EPSG:{epsg}")
    return out


def check_dsm(group, meta, rows_per_block):
    """Yield one result row per level."""
    src = rasterio.open(meta["source"]["path"])
    levels = meta["levels"]
    problems = []
    if (src.width, src.height) != (meta["width"], meta["height"]):
        problems.append(f"shape {src.width}x{src.height} vs catalog {meta['width']}x{meta['height']}")
    gt = list(src.transform.to_gdal())
    if any(abs(a - b) > 1e-9 * max(1.0, abs(a)) for a, b in zip(gt, meta["geotransform"])):
        problems.append(f"geotransform {gt} vs catalog {meta['geotransform']}")

    for k, lm in enumerate(levels):
        arr = group[str(k)]
        shape_ok = tuple(arr.shape) == (lm["height"], lm["width"])
        mismatches, max_diff, valid = 0, 0.0, 0
        h = lm["height"]
        block = rows_per_block
        # Level k > 0 is checked against stored level k-1, 2*block rows at a time.
        prev_arr = group[str(k - 1)] if k > 0 else None
        for r0 in range(0, h, block):
            r1 = min(h, r0 + block)
            got = arr[r0:r1, :]
            if k == 0:
                want = source_rows(src, r0, r1)
            else:
                above = prev_arr[2 * r0:min(prev_arr.shape[0], 2 * r1), :]
                want = mean_2x2(above)
            m, d = compare(got, want)
            mismatches += m
            max_diff = max(max_diff, d)
            valid += int((~np.isnan(got)).sum())
        if k == 0 and valid != meta["valid_count"]:
            problems.append(f"valid_count {meta['valid_count']} in catalog, {valid} in array")
        problems.extend(georef_problems(k, arr, gt, src))
        ok = shape_ok and mismatches == 0
        yield {
            "level": k,
            "shape": f"{arr.shape[1]}x{arr.shape[0]}",
            "chunks": f"{arr.chunks[1]}x{arr.chunks[0]}",
            "valid": valid,
            "mismatches": mismatches,
            "max_diff": max_diff,
            "ok": ok,
        }
    src.close()
    for p in problems:
        yield {"problem": p}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("store", help="the .zarr store made by dsmstream ingest")
    ap.add_argument("--rows", type=int, default=1024, help="rows per read block")
    args = ap.parse_args()
    try:
        root = zarr.open_group(args.store, mode="r")
        cat = root.attrs["dsmstream"]
    except Exception as e:  # noqa: BLE001 - one line for the user
        print(f"error: {args.store}: not a dsmstream store ({e})", file=sys.stderr)
        return 2

    print(f"store {args.store}: {len(cat['dsms'])} DSMs, zarr-python {zarr.__version__}, rasterio {rasterio.__version__}")
    idw = max([2] + [len(i) for i in cat["dsms"]])
    print(f"{'id':<{idw}} {'level':>5} {'shape':>13} {'chunks':>9} {'valid px':>11} {'mismatch':>9} {'max |d|':>9}  status")
    failures = 0
    for dsm_id in cat["dsms"]:
        group = root[dsm_id]
        meta = group.attrs["dsmstream"]
        for row in check_dsm(group, meta, args.rows):
            if "problem" in row:
                failures += 1
                print(f"{dsm_id:<{idw}} catalog mismatch: {row['problem']}")
                continue
            failures += 0 if row["ok"] else 1
            print(
                f"{dsm_id:<{idw}} {row['level']:>5} {row['shape']:>13} {row['chunks']:>9} {row['valid']:>11} "
                f"{row['mismatches']:>9} {row['max_diff']:>9.2g}  {'ok' if row['ok'] else 'MISMATCH'}"
            )
    print("all arrays match" if failures == 0 else f"{failures} mismatching arrays or attributes")
    return 0 if failures == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
