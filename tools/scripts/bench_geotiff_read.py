#!/usr/bin/env python3
"""Benchmark helper for the GeoTIFF reader: make a large Deflate-tiled f32 DSM and
time GDAL (through rasterio) reading it top to bottom in row bands, single- and
multi-threaded. The Rust side is timed by the ignored unit test
`geotiff::reader::tests::bench_streaming_read` (see its doc comment).

Usage:
  python3 tools/scripts/bench_geotiff_read.py make /tmp/big.tif [size=20000] [tile=256] [compress=deflate]
    (compress: any GDAL COMPRESS for Float32, e.g. deflate, zstd, lerc, lerc_deflate, lerc_zstd)
  python3 tools/scripts/bench_geotiff_read.py gdal /tmp/big.tif [band_rows=512]
"""

import os
import sys
import time

import numpy as np
import rasterio
from rasterio.transform import from_origin
from rasterio.windows import Window


def make(path, size=20000, tile=256, compress="deflate"):
    profile = dict(driver="GTiff", width=size, height=size, count=1, dtype="float32",
                   crs="EPSG:32617", transform=from_origin(600000.0, 4900000.0, 0.5, 0.5),
                   nodata=float("nan"), tiled=True, blockxsize=tile, blockysize=tile,
                   compress=compress, BIGTIFF="IF_SAFER", NUM_THREADS="ALL_CPUS")
    rng = np.random.default_rng(1)
    x = np.arange(size, dtype="float64")
    with rasterio.open(path, "w", **profile) as ds:
        for row0 in range(0, size, 1024):
            rows = min(1024, size - row0)
            y = np.arange(row0, row0 + rows, dtype="float64")[:, None]
            z = 150.0 + 30.0 * np.sin(x / 700.0) * np.cos(y / 900.0) + 0.002 * x
            z = z + np.round(rng.normal(0.0, 0.2, size=(rows, size)), 2)
            z[:, (x > size * 0.8)] = np.nan  # a no-data strip, like a DSM edge
            ds.write(z.astype("float32"), 1, window=Window(0, row0, size, rows))
    print(f"wrote {path}: {os.path.getsize(path) / 1e6:.0f} MB")


def gdal(path, band_rows=512):
    for threads in ("1", "ALL_CPUS"):
        with rasterio.Env(GDAL_NUM_THREADS=threads, GDAL_CACHEMAX=64):
            t0 = time.perf_counter()
            total = 0.0
            with rasterio.open(path) as ds:
                for row0 in range(0, ds.height, band_rows):
                    rows = min(band_rows, ds.height - row0)
                    a = ds.read(1, window=Window(0, row0, ds.width, rows))
                    total += float(a[0, 0]) if a.size else 0.0
            dt = time.perf_counter() - t0
        mpix = ds.width * ds.height / 1e6
        print(f"gdal {rasterio.__gdal_version__} GDAL_NUM_THREADS={threads}: {dt:.2f} s, "
              f"{mpix / dt:.0f} Mpx/s")


if __name__ == "__main__":
    cmd, path = sys.argv[1], sys.argv[2]
    args = [int(a) if a.isdigit() else a for a in sys.argv[3:]]
    {"make": make, "gdal": gdal}[cmd](path, *args)
