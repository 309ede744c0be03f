#!/usr/bin/env python3
"""Write fixtures/national/ttp_dsm_albers.tif: a real lidar DSM in a national grid.

The source is Tommy Thompson Park's 1 m lidar DSM (fixtures/real/ttp2015/
ttp_dsm_source.tif, NAD83 / UTM 17N, EPSG:26917, MIT). Its surface is moved by
SHIFT metres (east, north) in UTM 17N, by moving its geotransform, then put by
GDAL's warper (bilinear, 1 m pixels) into NAD83 / Conus Albers (EPSG:5070), the
equal-area grid of US federal mapping (USGS, NLCD). Registering the UTM DSM onto
this one (or this one onto it) must find the move as Conus Albers sees it: the
same vector turned by the two grids' convergence and scaled by their scales at
the park. PROJ (pyproj) gives that vector here, written into the fixture's
README as its known answer.

Usage: pip install rasterio numpy pyproj; python3 tools/scripts/make_national_fixture.py
"""

import os

import numpy as np
import pyproj
import rasterio
from rasterio.warp import Resampling, calculate_default_transform, reproject

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SRC = os.path.join(ROOT, "fixtures", "real", "ttp2015", "ttp_dsm_source.tif")
OUT = os.path.join(ROOT, "fixtures", "national")
NAME = "ttp_dsm_albers.tif"
SHIFT = (3.0, -2.0)
TARGET = "EPSG:5070"

README = """# A DSM in a national grid (generated: do not edit)

`{name}`: Tommy Thompson Park's 1 m lidar DSM
(`fixtures/real/ttp2015/ttp_dsm_source.tif`, NAD83 / UTM 17N, from the CFCore
project's 2015 lidar, MIT licence: see `fixtures/real/ttp2015/`) moved by
({sx:+.1f}, {sy:+.1f}) m (east, north) in UTM 17N, then put by GDAL's warper
(bilinear, 1 m pixels) into NAD83 / Conus Albers (EPSG:5070). Written by
`tools/scripts/make_national_fixture.py` (rasterio {rio}, GDAL {gdal}, PROJ {proj}).

Known answer: at the park's centre (UTM 17N E {ce:.1f}, N {cn:.1f}; Conus
Albers E {ae:.3f}, N {an:.3f}) the move is ({dx:+.4f}, {dy:+.4f}) m in Conus
Albers (PROJ), the UTM move turned by the grids' convergence
({turn:+.3f} degrees) and scaled by {scale:.5f}.
"""


def main():
    os.makedirs(OUT, exist_ok=True)
    with rasterio.open(SRC) as src:
        data = src.read(1)
        t = src.transform
        moved = rasterio.Affine(t.a, t.b, t.c + SHIFT[0], t.d, t.e, t.f + SHIFT[1])
        dst_t, w, h = calculate_default_transform(
            src.crs, TARGET, src.width, src.height, *rasterio.transform.array_bounds(src.height, src.width, moved), resolution=1.0
        )
        # snap to whole metres
        dst_t = rasterio.Affine(1.0, 0.0, np.floor(dst_t.c), 0.0, -1.0, np.ceil(dst_t.f))
        out = np.full((h + 2, w + 2), np.nan, dtype=np.float32)
        reproject(
            data, out, src_transform=moved, src_crs=src.crs, src_nodata=np.nan,
            dst_transform=dst_t, dst_crs=TARGET, dst_nodata=np.nan, resampling=Resampling.bilinear,
        )
        profile = dict(
            driver="GTiff", width=w + 2, height=h + 2, count=1, dtype="float32", crs=TARGET,
            transform=dst_t, nodata=np.nan, compress="deflate", predictor=3, tiled=True,
            blockxsize=256, blockysize=256,
        )
        tmp = os.path.join(OUT, NAME + ".tmp")
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(out, 1)
        os.replace(tmp, os.path.join(OUT, NAME))
        ce, cn = t.c + 0.5 * src.width * t.a, t.f + 0.5 * src.height * t.e
        to = pyproj.Transformer.from_crs(src.crs.to_wkt(), TARGET, always_xy=True)
        ae, an = to.transform(ce, cn)
        be, bn = to.transform(ce + SHIFT[0], cn + SHIFT[1])
        dx, dy = be - ae, bn - an
        turn = np.degrees(np.arctan2(dy, dx) - np.arctan2(SHIFT[1], SHIFT[0]))
        scale = np.hypot(dx, dy) / np.hypot(*SHIFT)
    text = README.format(
        name=NAME, sx=SHIFT[0], sy=SHIFT[1], rio=rasterio.__version__, gdal=rasterio.__gdal_version__,
        proj=pyproj.proj_version_str, ce=ce, cn=cn, ae=ae, an=an, dx=dx, dy=dy, turn=turn, scale=scale,
    )
    with open(os.path.join(OUT, "README.md"), "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main()
