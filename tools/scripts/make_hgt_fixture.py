#!/usr/bin/env python3
"""Write the SRTM HGT fixture fixtures/hgt/N39E040.SRTMGL3.hgt.zip and check it with GDAL.

The tile is the real SRTM 3" heights of demcompare's srtm_ref.tif
(fixtures/real/demcompare_srtm, Apache-2.0), its first 500 x 500 pixels written
sample for sample as the HGT tile N39E040 (1201 x 1201 big-endian int16, -32768
elsewhere) and zipped by Python's zipfile (Deflate) as LP DAAC names SRTMGL3
tiles. srtm_ref.tif puts the *edges* of its pixels on whole multiples of 3"
(its north-west corner is 40 N 40 E), while an HGT tile puts its *samples*
there, so the tile's surface lies half a pixel (1.5") west and 1.5" north of
srtm_ref.tif's: registering the tile onto srtm_ref.tif must find a shift of
1.5" east and 1.5" south. That is the fixture's known answer.

The script then opens the zip with GDAL's SRTMHGT driver (rasterio's wheel) and
checks that GDAL places it where dsmstream's reader does (transform, CRS,
no-data) and reads the same heights.

Usage: pip install rasterio numpy; python3 tools/scripts/make_hgt_fixture.py
Re-running rewrites the fixture byte for byte (fixed zip timestamps).
"""

import os
import zipfile

import numpy as np
import rasterio

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SRC = os.path.join(ROOT, "fixtures", "real", "demcompare_srtm", "srtm_ref.tif")
OUT = os.path.join(ROOT, "fixtures", "hgt")
NAME = "N39E040.SRTMGL3.hgt.zip"
N, CROP = 1201, 500

README = """# SRTM HGT fixture (generated: do not edit)

`N39E040.SRTMGL3.hgt.zip` holds `N39E040.hgt`: SRTM 3" heights (1201 x 1201
big-endian int16, -32768 for voids) as LP DAAC delivers SRTMGL3 tiles. Written by
`tools/scripts/make_hgt_fixture.py` (rasterio {rio}, GDAL {gdal}) from the first
{crop} x {crop} pixels of `fixtures/real/demcompare_srtm/srtm_ref.tif`, real SRTM
data published by CNES's demcompare under the Apache License 2.0
(`fixtures/real/demcompare_srtm/LICENSE`); the rest of the tile is void.

srtm_ref.tif puts the edges of its pixels on whole multiples of 3"; the tile
puts its samples there, so the tile lies 1.5" west and 1.5" north of
srtm_ref.tif. Registering the tile onto srtm_ref.tif must find 1.5" east and
1.5" south (+36.3 m and -45.8 m in UTM 37N at the tile's data centre). GDAL's SRTMHGT driver reads
the zip with transform {transform} and EPSG:{epsg}.
"""


def main():
    with rasterio.open(SRC) as src:
        ref = src.read(1)
        t = src.transform
        assert abs(t.c - 40.0) < 1e-9 and abs(t.f - 40.0) < 1e-9, t
        assert abs(t.a - 1 / 1200) < 1e-12 and abs(t.e + 1 / 1200) < 1e-12, t
    tile = np.full((N, N), -32768, dtype=">i2")
    tile[:CROP, :CROP] = ref[:CROP, :CROP]
    os.makedirs(OUT, exist_ok=True)
    path = os.path.join(OUT, NAME)
    tmp = path + ".tmp"
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        info = zipfile.ZipInfo("N39E040.hgt", date_time=(2000, 2, 11, 0, 0, 0))
        info.compress_type = zipfile.ZIP_DEFLATED
        z.writestr(info, tile.tobytes())
    os.replace(tmp, path)

    with rasterio.open(path) as d:
        assert d.driver == "SRTMHGT", d.driver
        assert (d.width, d.height) == (N, N)
        got = d.transform
        west, north = 40 - 0.5 / 1200, 40 + 0.5 / 1200
        assert abs(got.c - west) < 1e-12 and abs(got.f - north) < 1e-12, got
        assert d.crs.to_epsg() == 4326 and d.nodata == -32768
        assert np.array_equal(d.read(1), tile.astype(np.int16))
        transform = tuple(round(v, 12) for v in got[:6])
        epsg = d.crs.to_epsg()
    with open(os.path.join(OUT, "README.md"), "w") as f:
        f.write(
            README.format(
                rio=rasterio.__version__,
                gdal=rasterio.__gdal_version__,
                crop=CROP,
                transform=transform,
                epsg=epsg,
            )
        )
    print(f"{path}: {os.path.getsize(path)} bytes; GDAL agrees")


if __name__ == "__main__":
    main()
