#!/usr/bin/env python3
"""Write fixtures/geotiff/ud_*.tif: three 32 x 32 DSMs whose CRS GDAL writes as
user-defined GeoTIFF keys (no EPSG code), as it does for a CRS given as a PROJ
string (Ames Stereo Pipeline's `--t_srs "+proj=stere ..."`, for one):

- ud_lambert93.tif: Lambert-93's parameters on GRS80 with a zero shift
  (`+ellps=GRS80 +towgs84=0,0,0,...`, the usual PROJ string of EPSG:2154);
- ud_nsidc_north.tif: NSIDC's polar stereographic north (EPSG:3413's parameters);
- ud_conus_albers.tif: Conus Albers on NAD83 (EPSG:5070's parameters).

Heights are a ramp (100 m + 0.1 m per column + 0.05 m per row), 1 m pixels.
Usage: pip install rasterio numpy; python3 tools/scripts/make_user_defined_grids.py
"""
import os

import numpy as np
import rasterio
from rasterio.transform import from_origin

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OUT = os.path.join(ROOT, "fixtures", "geotiff")
CASES = [
    ("ud_lambert93.tif",
     "+proj=lcc +lat_1=49 +lat_2=44 +lat_0=46.5 +lon_0=3 +x_0=700000 +y_0=6600000 "
     "+ellps=GRS80 +towgs84=0,0,0,0,0,0,0 +units=m +no_defs", (652000.0, 6862000.0)),
    ("ud_nsidc_north.tif",
     "+proj=stere +lat_0=90 +lat_ts=70 +lon_0=-45 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs",
     (-200000.0, -2000000.0)),
    ("ud_conus_albers.tif",
     "+proj=aea +lat_0=23 +lon_0=-96 +lat_1=29.5 +lat_2=45.5 +x_0=0 +y_0=0 +datum=NAD83 +units=m +no_defs",
     (1332000.0, 2409700.0)),
]


def main():
    rows, cols = np.mgrid[0:32, 0:32]
    ramp = (100.0 + 0.1 * cols + 0.05 * rows).astype("float32")
    for name, proj, (x0, y0) in CASES:
        path = os.path.join(OUT, name)
        with rasterio.open(path, "w", driver="GTiff", width=32, height=32, count=1,
                           dtype="float32", crs=proj, transform=from_origin(x0, y0, 1.0, 1.0),
                           nodata=-9999.0) as d:
            d.write(ramp, 1)
        print(path, os.path.getsize(path))


if __name__ == "__main__":
    main()
