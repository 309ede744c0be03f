#!/usr/bin/env python3
"""Generate the GeoTIFF reader fixtures in fixtures/geotiff/ and their expected answers.

GDAL (through rasterio's wheel, which bundles it) writes small 67 x 45 rasters for
every sample type x layout x compression the reader supports, plus predictor,
BigTIFF, pixel-is-point, ModelTransformation, no-data, CRS, multi-band and half-float
variants, georeferencing in side files (.aux.xml, world files, .prj), and files the
reader must refuse. A few variants GDAL cannot write
(old-style Deflate code 32946, a north-up ModelTransformation, zero width, tile
offsets past the end of the file) are made by patching one tag of a GDAL file.

expected.json records what GDAL reports when it reads each file back:
geotransform, EPSG, no-data and the pixels (raw little-endian f32 files under
pixels/, NaN where GDAL's no-data mask says no-data; identical rasters share one
file). For the real rasters in fixtures/real/ it records the same metadata plus
the valid-pixel count and sum and a deterministic sample of pixels.

Usage: pip install rasterio numpy; python3 tools/scripts/make_test_tiffs.py
Re-running rewrites fixtures/geotiff/ from scratch (deterministic data).
"""

import glob
import hashlib
import json
import os
import re
import shutil
import struct
import warnings

import numpy as np
import rasterio
import rasterio.shutil
from rasterio.transform import Affine, from_origin

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OUT = os.path.join(ROOT, "fixtures", "geotiff")
PIX = os.path.join(OUT, "pixels")
W, H = 67, 45
UTM = "EPSG:32617"
GT_UTM = from_origin(630000.5, 4830000.25, 0.5, 0.5)

warnings.filterwarnings("ignore", category=rasterio.errors.NotGeoreferencedWarning)

# ---------------------------------------------------------------- data


def surface():
    """A smooth height field (metres) with a no-data disk and scattered holes."""
    rng = np.random.default_rng(42)
    y, x = np.mgrid[0:H, 0:W].astype("float64")
    z = 100.0 + 20.0 * np.sin(x / 9.0) * np.cos(y / 7.0) + 0.05 * x - 0.03 * y
    z += rng.normal(0.0, 0.3, size=z.shape)
    z = np.round(z * 64.0) / 64.0  # quantised like many DSMs: keeps the fixtures small
    holes = (x - 50) ** 2 + (y - 12) ** 2 < 36
    holes |= rng.random(z.shape) < 0.02
    return z, holes


DTYPES = {
    # name: (numpy dtype, no-data value, scale, offset)
    "f32": ("float32", float("nan"), 1.0, 0.0),
    "f64": ("float64", -9999.0, 1.0, 0.0),
    "i16": ("int16", -32768.0, 10.0, -500.0),
    "u16": ("uint16", 0.0, 100.0, 0.0),
    "i32": ("int32", -9999.0, 1000.0, -50000.0),
    "u8": ("uint8", 255.0, 1.0, 0.0),
}


def raster(kind, nodata=None):
    dtype, default_nodata, scale, offset = DTYPES[kind]
    nodata = default_nodata if nodata is None else nodata
    z, holes = surface()
    v = z * scale + offset
    if not dtype.startswith("float"):
        v = np.round(v)
    v = v.astype(dtype)
    v[holes] = nodata
    return v, nodata


# ---------------------------------------------------------------- writing


def write(name, data, nodata, compress=None, tiled=False, block=16, strip_rows=7,
          predictor=None, bigtiff=False, crs=UTM, transform=GT_UTM, point=False,
          count=1, interleave="pixel", mask=None, **extra):
    path = os.path.join(OUT, name)
    profile = dict(driver="GTiff", width=data.shape[-1], height=data.shape[-2],
                   count=count, dtype=data.dtype.name, interleave=interleave)
    if crs is not None:
        profile["crs"] = crs
    if transform is not None:
        profile["transform"] = transform
    if nodata is not None:
        profile["nodata"] = nodata
    if compress:
        profile["compress"] = compress
    if tiled:
        profile.update(tiled=True, blockxsize=block, blockysize=block)
    else:
        profile.update(blockysize=strip_rows)
    if predictor:
        profile["predictor"] = predictor
    if bigtiff:
        profile["BIGTIFF"] = "YES"
    profile.update(extra)
    with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True), rasterio.open(path, "w", **profile) as ds:
        if point:
            ds.update_tags(AREA_OR_POINT="Point")
        if count == 1:
            ds.write(data, 1)
        else:
            ds.write(data)
        if mask is not None:
            ds.write_mask(mask)
    return name


# ------------------------------------------------------- tag patching


TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 8, 6: 1, 7: 1, 8: 2, 9: 4, 10: 8, 11: 4, 12: 8,
              16: 8, 17: 8, 18: 8}
TYPE_FMT = {1: "B", 3: "H", 4: "I", 8: "h", 9: "i", 12: "d", 16: "Q"}


def ifd_entries(buf):
    """(tag, type, count, value_offset_in_file) for each entry of the first IFD."""
    e = "<" if buf[:2] == b"II" else ">"
    big = struct.unpack(e + "H", buf[2:4])[0] == 43
    off = struct.unpack(e + "Q", buf[8:16])[0] if big else struct.unpack(e + "I", buf[4:8])[0]
    n = struct.unpack(e + ("Q" if big else "H"), buf[off:off + (8 if big else 2)])[0]
    p = off + (8 if big else 2)
    out = []
    for _ in range(n):
        if big:
            tag, typ, cnt = struct.unpack(e + "HHQ", buf[p:p + 12])
            vo, inline = p + 12, 8
        else:
            tag, typ, cnt = struct.unpack(e + "HHI", buf[p:p + 8])
            vo, inline = p + 8, 4
        if TYPE_SIZES[typ] * cnt > inline:
            vo = struct.unpack(e + ("Q" if big else "I"), buf[vo:vo + inline])[0]
        out.append((tag, typ, cnt, vo))
        p += 20 if big else 12
    return e, out


def patch_tag(src, dst, tag, values):
    """Copy src to dst, overwriting the value(s) of one tag in place (same type/count)."""
    buf = bytearray(open(os.path.join(OUT, src), "rb").read())
    e, entries = ifd_entries(buf)
    for t, typ, cnt, vo in entries:
        if t == tag:
            assert len(values) <= cnt, (tag, cnt, values)
            fmt = TYPE_FMT[typ]
            for i, v in enumerate(values):
                struct.pack_into(e + fmt, buf, vo + i * TYPE_SIZES[typ], v)
            break
    else:
        raise KeyError(f"tag {tag} not in {src}")
    open(os.path.join(OUT, dst), "wb").write(bytes(buf))
    return dst


# ------------------------------------------------------- expectations


def compression_label(ds):
    c = ds.profile.get("compress")
    return "none" if c is None else str(c).lower()


def json_nodata(v):
    if v is None:
        return None
    return "nan" if np.isnan(v) else float(v)


def horizontal_epsg(crs):
    """EPSG code of the CRS, or of the horizontal part of a compound CRS."""
    if crs is None:
        return None
    code = crs.to_epsg()
    if code is not None:
        return code
    wkt = crs.to_wkt()
    if wkt.startswith("COMPD_CS"):
        m = re.search(r'AUTHORITY\["EPSG","(\d+)"\]\],VERT_CS', wkt)
        if m:
            return int(m.group(1))
    return None


def gdal_pixels(ds):
    """Band 1 as GDAL reads it, f32, NaN where GDAL's mask says no-data, in the
    band's physical unit (raw * scale + offset, GDAL's band metadata; as
    `gdal_translate -unscale` gives them, computed in double)."""
    band = ds.read(1, masked=True)
    scale, offset = ds.scales[0], ds.offsets[0]
    vals = np.ma.filled(band.astype("float64") * scale + offset, np.nan).astype("<f4")
    return vals


def describe(ds, name):
    return {
        "file": name,
        "width": ds.width,
        "height": ds.height,
        "band_count": ds.count,
        "dtype": ds.dtypes[0],
        "compression": compression_label(ds),
        "tiled": bool(ds.profile.get("tiled", False)),
        "block": [ds.block_shapes[0][1], ds.block_shapes[0][0]],
        "geotransform": list(ds.transform.to_gdal()),
        "epsg": horizontal_epsg(ds.crs),
        "is_geographic": bool(ds.crs.is_geographic) if ds.crs else False,
        "nodata": json_nodata(ds.nodata),
    }


def expect_good(name, extra=None, adjust=None):
    """The record of a good fixture: what GDAL reports and its pixels
    (`adjust`, when given, maps GDAL's pixels to the expected ones, for the
    one case where the reader deliberately differs from GDAL)."""
    with rasterio.open(os.path.join(OUT, name)) as ds:
        rec = describe(ds, name)
        vals = gdal_pixels(ds)
    if adjust is not None:
        vals = adjust(vals)
    raw = vals.tobytes()
    digest = hashlib.sha1(raw).hexdigest()[:10]
    bin_name = f"pixels/{rec['dtype']}_{digest}.bin"
    with open(os.path.join(OUT, bin_name), "wb") as f:
        f.write(raw)
    rec["pixels"] = bin_name
    rec.update(extra or {})
    return rec


def expect_real(path):
    rel = os.path.relpath(path, OUT)
    with rasterio.open(path) as ds:
        rec = describe(ds, rel)
        vals = gdal_pixels(ds)
    valid = ~np.isnan(vals)
    rng = np.random.default_rng(7)
    rows = rng.integers(0, vals.shape[0], 100)
    cols = rng.integers(0, vals.shape[1], 100)
    rec["valid_count"] = int(valid.sum())
    rec["valid_sum"] = float(vals[valid].astype("float64").sum())
    rec["samples"] = [[int(r), int(c), None if np.isnan(vals[r, c]) else float(vals[r, c])]
                      for r, c in zip(rows, cols)]
    return rec


README = """# GeoTIFF reader fixtures (generated: do not edit)

Made by `tools/scripts/make_test_tiffs.py` with GDAL {gdal} (rasterio {rio} wheel); re-running
it rewrites this folder byte for byte. `expected.json` holds what GDAL reports for
each file: `good` (readable: metadata and `pixels/*.bin`, width*height little-endian
f32 with NaN where GDAL's no-data mask is set), `bad` (files the reader must refuse,
with the kind of error), `real` (the rasters in ../real/: metadata, valid-pixel count
and sum, and 100 sampled pixels). Data: a synthetic 67 x 45 height field with
no-data holes, stored in every sample type, layout and compression the reader
supports; `bad_*` and a few variants are patched GDAL files (see the script).
`wf_real_xdem.*` is xdem-data's Svalbard crop of ../real/xdem_gdal (its LICENSE
applies) rewritten with its georeferencing in a world file and an ESRI `.prj`;
`wf_deg_srtm.*` a 160 x 160 crop of demcompare's SRTM tile in degrees
(../real/demcompare_srtm, its LICENSE applies), likewise, its `.prj` ESRI's WGS 84
without a code (GDAL's GeoTIFF driver ignores it: the record's CRS is ours).
The Rust tests are in src/geotiff/reader/tests.rs.
"""


def compact_json(doc):
    """Pretty at the top level, one line per file record (small, diffable)."""
    parts = []
    for key, val in doc.items():
        if isinstance(val, list):
            rows = ",\n  ".join(json.dumps(r, allow_nan=False) for r in val)
            parts.append(f' "{key}": [\n  {rows}\n ]')
        else:
            parts.append(f" {json.dumps(key)}: {json.dumps(val)}")
    return "{\n" + ",\n".join(parts) + "\n}\n"


# ---------------------------------------------------------------- main


def main():
    if os.path.isdir(OUT):
        shutil.rmtree(OUT)
    os.makedirs(PIX)
    good, bad = [], []

    # Every sample type x layout x compression.
    for kind in DTYPES:
        data, nodata = raster(kind)
        for layout in ("strip", "tile"):
            for comp in ("none", "lzw", "deflate", "zstd", "packbits"):
                name = write(f"{kind}_{layout}_{comp}.tif", data, nodata,
                             compress=None if comp == "none" else comp,
                             tiled=layout == "tile")
                good.append(expect_good(name, {"predictor": 1}))

    # Predictors.
    for kind, layout, comp, pred in [
        ("f32", "tile", "deflate", 3), ("f32", "strip", "lzw", 3),
        ("f64", "tile", "zstd", 3), ("f64", "strip", "deflate", 3),
        ("f32", "tile", "deflate", 2), ("f64", "strip", "zstd", 2),
        ("i16", "tile", "lzw", 2), ("u16", "strip", "deflate", 2),
        ("i32", "tile", "zstd", 2), ("u8", "strip", "lzw", 2),
    ]:
        data, nodata = raster(kind)
        name = write(f"{kind}_{layout}_{comp}_p{pred}.tif", data, nodata, compress=comp,
                     tiled=layout == "tile", predictor=pred)
        good.append(expect_good(name, {"predictor": pred}))

    # Old-style Deflate code (32946): same bytes, compression tag patched.
    good.append(expect_good(patch_tag("f32_tile_deflate.tif", "f32_tile_deflate32946.tif",
                                      259, [32946]), {"predictor": 1}))
    # A tile size of 32 and one single strip holding the whole image.
    data, nodata = raster("f32")
    good.append(expect_good(write("f32_tile32_deflate.tif", data, nodata, compress="deflate",
                                  tiled=True, block=32), {"predictor": 1}))
    good.append(expect_good(write("f32_onestrip_deflate.tif", data, nodata, compress="deflate",
                                  strip_rows=H), {"predictor": 1}))

    # Big-endian files (MM byte order), with predictors.
    for kind, layout, comp, pred in [("f32", "strip", "deflate", 3), ("i16", "tile", "lzw", 2),
                                     ("f64", "tile", "zstd", 1), ("u16", "strip", "packbits", 1)]:
        d, n = raster(kind)
        name = write(f"{kind}_{layout}_{comp}_p{pred}_bigendian.tif", d, n, compress=comp,
                     tiled=layout == "tile", predictor=pred if pred > 1 else None,
                     ENDIANNESS="BIG")
        good.append(expect_good(name, {"predictor": pred}))

    # Sparse tiles (GDAL SPARSE_OK): all-no-data tiles are not stored (byte count 0).
    sparse = data.copy()
    sparse[:16, :] = np.nan
    sparse[16:32, 32:48] = np.nan
    good.append(expect_good(write("f32_tile_sparse.tif", sparse, nodata, compress="deflate",
                                  tiled=True, SPARSE_OK=True)))
    sparse16 = raster("i16")[0].copy()
    sparse16[:, :32] = 0
    good.append(expect_good(write("i16_tile_sparse_no_nodata.tif", sparse16, None,
                                  compress="lzw", tiled=True, SPARSE_OK=True)))

    # BigTIFF.
    good.append(expect_good(write("f32_tile_deflate_bigtiff.tif", data, nodata,
                                  compress="deflate", tiled=True, bigtiff=True)))
    d16, n16 = raster("i16")
    good.append(expect_good(write("i16_strip_lzw_bigtiff.tif", d16, n16, compress="lzw",
                                  bigtiff=True)))

    # No-data variants (f32): -9999, -FLT_MAX, none at all (NaN pixels stay NaN).
    for tag, nd in (("9999", -9999.0), ("fltmin", -3.4028234663852886e38)):
        d, n = raster("f32", nd)
        good.append(expect_good(write(f"f32_nodata_{tag}.tif", d, n, compress="deflate",
                                      tiled=True)))
    good.append(expect_good(write("f32_no_nodata.tif", data, None, compress="lzw")))

    # Geographic (EPSG:4326), pixel-is-point (geographic and projected), custom CRS.
    gt_geo = from_origin(-79.5, 43.75, 0.0001, 0.0001)
    good.append(expect_good(write("f32_4326_area.tif", data, nodata, crs="EPSG:4326",
                                  transform=gt_geo)))
    good.append(expect_good(write("f32_4326_point.tif", data, nodata, crs="EPSG:4326",
                                  transform=gt_geo, point=True), {"pixel_is_point": True}))
    good.append(expect_good(write("f32_utm_point.tif", data, nodata, compress="deflate",
                                  tiled=True, point=True), {"pixel_is_point": True}))
    custom = ("+proj=tmerc +lat_0=0 +lon_0=10.5 +k=0.9999 +x_0=250000 +y_0=0 "
              "+ellps=GRS80 +units=m +no_defs")
    good.append(expect_good(write("f32_custom_crs.tif", data, nodata, crs=custom,
                                  transform=from_origin(250000.0, 5200000.0, 2.0, 2.0)),
                            {"custom_crs": True}))

    # LERC (ESRI's codec; GDAL COMPRESS=LERC, LERC_DEFLATE, LERC_ZSTD): lossless
    # and within a MAX_Z_ERROR, tiles and strips, integer and float samples,
    # no-data holes (the blob's mask), two bands pixel-interleaved.
    for kind, layout, comp, extra in [
        ("f32", "tile", "lerc", {}), ("f32", "tile", "lerc_deflate", {}),
        ("f32", "tile", "lerc_zstd", {}), ("f32", "strip", "lerc", {}),
        ("f64", "tile", "lerc_zstd", {}), ("i16", "tile", "lerc_deflate", {}),
        ("u16", "strip", "lerc", {}),
    ]:
        data, nodata = raster(kind)
        good.append(expect_good(write(f"{kind}_{layout}_{comp}.tif", data, nodata, compress=comp,
                                      tiled=layout == "tile", **extra)))
    data, nodata = raster("f32")
    good.append(expect_good(write("f32_tile_lerc_lossy.tif", data, nodata, compress="lerc",
                                  tiled=True, max_z_error=0.01)))
    two = np.stack([data, data * 2.0])
    good.append(expect_good(write("f32_2band_pixel_lerc.tif", two, nodata, count=2,
                                  interleave="pixel", compress="lerc", tiled=True)))

    # GDAL's internal mask band (no no-data value; masked pixels hold 0):
    # strips and tiles, every compression GDAL gives the mask.
    _, holes = surface()
    for kind, layout, comp in [("f32", "tile", "deflate"), ("i16", "strip", "lzw"),
                               ("f32", "strip", "packbits"), ("u16", "tile", "zstd"),
                               ("f32", "tile", None), ("f32", "tile", "lerc_zstd")]:
        zeros, _ = raster(kind)
        zeros[holes] = 0
        name = f"{kind}_{layout}_{comp or 'none'}_mask.tif"
        write(name, zeros, None, compress=comp, tiled=layout == "tile",
              mask=np.where(holes, 0, 255).astype("uint8"))
        good.append(expect_good(name, {"internal_mask": True}))

    # Half floats (Float16): GDAL writes them for Float32 with NBITS=16,
    # truncating each value, and reads them back as Float32 (GDAL 3.10), so
    # the records say float16. No-data NaN, and -9999, which no half float
    # holds: GDAL stores -9992 and, its no-data staying -9999, reads those
    # pixels as heights; the reader takes them as no-data (expected: NaN).
    half = {"dtype": "float16"}
    data, nodata = raster("f32")
    for layout, comp, pred, extra in [("strip", None, None, {}), ("tile", "deflate", 3, {}),
                                      ("strip", "lzw", 3, {"ENDIANNESS": "BIG"}),
                                      ("tile", "zstd", None, {})]:
        name = f"f16_{layout}_{comp or 'none'}_p{pred or 1}{'_bigendian' if extra else ''}.tif"
        good.append(expect_good(write(name, data, nodata, compress=comp, tiled=layout == "tile",
                                      predictor=pred, nbits=16, **extra),
                                dict(half, predictor=pred or 1)))
    d9, n9 = raster("f32", -9999.0)
    good.append(expect_good(write("f16_tile_deflate_nodata_9999.tif", d9, n9, compress="deflate",
                                  tiled=True, predictor=3, nbits=16),
                            dict(half, predictor=3),
                            adjust=lambda v: np.where(v == -9992.0, np.float32(np.nan), v)))

    # GDAL band metadata (GDAL_METADATA tag): heights stored as centimetres
    # about 100 m (physical = raw * 0.01 + 100), and a band whose unit is feet.
    z, holes = surface()
    cm = np.round((z - 100.0) / 0.01).astype("int16")
    cm[holes] = -32768
    name = write("i16_scale_offset.tif", cm, -32768.0, compress="deflate", tiled=True)
    with rasterio.open(os.path.join(OUT, name), "r+") as ds:
        ds.scales, ds.offsets, ds.units = (0.01,), (100.0,), ("m",)
    good.append(expect_good(name, {"scale": 0.01, "offset": 100.0, "height_unit": "m"}))
    name = write("f32_units_ft.tif", data, nodata, compress="deflate")
    with rasterio.open(os.path.join(OUT, name), "r+") as ds:
        ds.units = ("ft",)
    good.append(expect_good(name, {"height_unit": "ft"}))

    # Georeferencing beside the file, as GDAL reads it (GEOREF_SOURCES
    # PAM,INTERNAL,TABFILE,WORLDFILE): PROFILE=BASELINE writes no GeoTIFF tags,
    # puts the CRS in a PAM .aux.xml and, with TFW=YES, the transform in a
    # world file. "side_files": the ones the reader
    # took georeferencing from (transform first).
    d64, n64 = raster("f64")  # no-data -9999: only the .aux.xml says so
    name = write("wf_tfw_aux.tif", d64, n64, compress="deflate", PROFILE="BASELINE", TFW="YES")
    good.append(expect_good(name, {"side_files": ["wf_tfw_aux.tfw", "wf_tfw_aux.tif.aux.xml"]}))
    name = write("wf_aux_only.tif", d64, n64, compress="lzw", tiled=True, PROFILE="BASELINE")
    good.append(expect_good(name, {"side_files": ["wf_aux_only.tif.aux.xml"]}))
    # Band 1's no-data, scale, offset and unit only in the .aux.xml (the file has
    # no GDAL_NODATA or GDAL_METADATA tag): GDAL takes them from there.
    name = write("wf_pam_band.tif", cm, None, compress="deflate")
    with open(os.path.join(OUT, name + ".aux.xml"), "w") as f:
        f.write('<PAMDataset>\n  <PAMRasterBand band="1">\n'
                '    <NoDataValue>-3.27680000000000E+04</NoDataValue>\n'
                '    <Offset>100</Offset>\n    <Scale>0.01</Scale>\n'
                '    <UnitType>m</UnitType>\n  </PAMRasterBand>\n</PAMDataset>\n')
    good.append(expect_good(name, {"scale": 0.01, "offset": 100.0, "height_unit": "m"}))
    # A .wld world file and the CRS in an ESRI .prj only: GDAL's GeoTIFF driver
    # ignores a .prj (no CRS); the reader takes it, as ArcGIS does.
    name = write("wf_wld_prj.tif", data, nodata, compress="deflate", PROFILE="BASELINE", TFW="YES")
    stem = os.path.join(OUT, "wf_wld_prj")
    os.replace(stem + ".tfw", stem + ".wld")
    os.remove(stem + ".tif.aux.xml")
    with open(stem + ".prj", "w") as f:
        f.write(rasterio.crs.CRS.from_string(UTM).to_wkt(version="WKT1_ESRI"))
    good.append(expect_good(name, {"epsg": 32617, "side_files": ["wf_wld_prj.wld",
                                                                 "wf_wld_prj.prj"]}))
    # The .aux.xml's transform before the file's own tags (10 m east).
    name = write("wf_pam_over_tags.tif", data, nodata, compress="deflate")
    with open(os.path.join(OUT, name + ".aux.xml"), "w") as f:
        f.write("<PAMDataset>\n  <GeoTransform>  6.3001050000000000e+05,  5.0000000000000000e-01,"
                "  0.0000000000000000e+00,  4.8300002500000000e+06,  0.0000000000000000e+00,"
                " -5.0000000000000000e-01</GeoTransform>\n</PAMDataset>\n")
    good.append(expect_good(name, {"side_files": ["wf_pam_over_tags.tif.aux.xml"]}))

    # A real DSM delivered as a TIFF with a world file and an ESRI .prj: xDEM's
    # Svalbard crop (fixtures/real/xdem_gdal, see its LICENSE) rewritten by GDAL
    # with no GeoTIFF tags; its .aux.xml keeps only band 1's no-data, the CRS
    # goes to a .prj as ESRI WKT (no EPSG code: ETRS89 / UTM zone 33N by its
    # parameters).
    src = os.path.join(ROOT, "fixtures/real/xdem_gdal/shifted_reprojected_xoff20.0_yoff20.0.tif")
    name = "wf_real_xdem.tif"
    rasterio.shutil.copy(src, os.path.join(OUT, name), driver="GTiff", PROFILE="BASELINE",
                         TFW="YES", COMPRESS="DEFLATE")
    stem = os.path.join(OUT, "wf_real_xdem")
    aux = open(stem + ".tif.aux.xml").read()
    band = aux[aux.index("  <PAMRasterBand"):]
    open(stem + ".tif.aux.xml", "w").write("<PAMDataset>\n" + band)
    with rasterio.open(src) as ds, open(stem + ".prj", "w") as f:
        f.write(ds.crs.to_wkt(version="WKT1_ESRI"))
    good.append(expect_good(name, {"epsg": 25833, "side_files": ["wf_real_xdem.tfw",
                                                                 "wf_real_xdem.prj"]}))

    # A DSM in degrees georeferenced by side files only: a 160 x 160 crop of
    # demcompare's SRTM tile (../real/demcompare_srtm, its LICENSE applies) as
    # BASELINE + .tfw, its CRS in an ESRI .prj (GEOGCS WGS 84, no code), which
    # GDAL's GeoTIFF driver ignores and ingest puts into UTM.
    src = os.path.join(ROOT, "fixtures/real/demcompare_srtm/srtm_ref.tif")
    name = "wf_deg_srtm.tif"
    with rasterio.open(src) as ds:
        window = rasterio.windows.Window(400, 400, 160, 160)
        profile = ds.profile.copy()
        profile.update(width=160, height=160, transform=ds.window_transform(window),
                       PROFILE="BASELINE", TFW="YES", compress="deflate")
        profile.pop("crs", None)
        profile.pop("nodata", None)
        with rasterio.open(os.path.join(OUT, name), "w", **profile) as out:
            out.write(ds.read(1, window=window), 1)
    with open(os.path.join(OUT, "wf_deg_srtm.prj"), "w") as f:
        f.write('GEOGCS["GCS_WGS_1984",DATUM["D_WGS_1984",SPHEROID["WGS_1984",6378137.0,'
                '298.257223563]],PRIMEM["Greenwich",0.0],UNIT["Degree",0.0174532925199433]]')
    good.append(expect_good(name, {"epsg": None, "is_geographic": True,
                                   "side_files": ["wf_deg_srtm.tfw", "wf_deg_srtm.prj"]}))

    # ModelTransformation only: GDAL writes one for a rotated transform; patch it north-up.
    rot = Affine(0.5, 0.1, 630000.0, 0.1, -0.5, 4830000.0)
    write("bad_rotated.tif", data, nodata, transform=rot, compress="deflate")
    bad.append({"file": "bad_rotated.tif", "error": "rotated"})
    mt = [0.5, 0.0, 0.0, 630010.0, 0.0, -0.5, 0.0, 4830020.0, 0, 0, 0, 0, 0, 0, 0, 1]
    good.append(expect_good(patch_tag("bad_rotated.tif", "f32_model_transformation.tif",
                                      34264, mt)))

    # Multi-band: band 1 is read, pixel- and band-interleaved.
    two = np.stack([data, data * 2.0])
    for il in ("pixel", "band"):
        good.append(expect_good(write(f"f32_2band_{il}.tif", two, nodata, count=2,
                                      interleave=il, compress="deflate", tiled=True)))

    # Files the reader must refuse.
    with open(os.path.join(OUT, "bad_not_tiff.tif"), "wb") as f:
        f.write(b"this is not a TIFF file, just text pretending to be one\n")
    bad.append({"file": "bad_not_tiff.tif", "error": "not_tiff"})
    write("bad_south_up.tif", data, nodata, transform=Affine(0.5, 0, 630000, 0, 0.5, 4830000),
          compress="deflate")
    bad.append({"file": "bad_south_up.tif", "error": "rotated"})
    write("bad_no_georef.tif", data, nodata, crs=None, transform=None, compress="deflate")
    bad.append({"file": "bad_no_georef.tif", "error": "no_georef"})
    # LERC whose blobs another compression wraps than GDAL's two (patched: 9)
    patch_tag("f32_tile_lerc_zstd.tif", "bad_lerc_wrapping.tif", 50674, [4, 9])
    bad.append({"file": "bad_lerc_wrapping.tif", "error": "compression"})
    d8, _ = raster("u8")
    write("bad_jpeg.tif", d8, None, compress="jpeg", tiled=True)
    bad.append({"file": "bad_jpeg.tif", "error": "compression"})
    write("bad_complex.tif", data[:8, :8].astype("complex64"), None)
    bad.append({"file": "bad_complex.tif", "error": "sample_format"})
    write("bad_1bit.tif", (d8 > 100).astype("uint8"), None, nbits=1)
    bad.append({"file": "bad_1bit.tif", "error": "sample_format"})
    patch_tag("f32_strip_none.tif", "bad_zero_width.tif", 256, [0])
    bad.append({"file": "bad_zero_width.tif", "error": "zero_size"})
    patch_tag("f32_tile_deflate.tif", "bad_offset_past_end.tif", 324, [3_000_000_000])
    bad.append({"file": "bad_offset_past_end.tif", "error": "truncated"})
    src = open(os.path.join(OUT, "f32_tile_none.tif"), "rb").read()
    open(os.path.join(OUT, "bad_truncated.tif"), "wb").write(src[: len(src) // 2])
    bad.append({"file": "bad_truncated.tif", "error": "truncated"})

    # Side files the reader must refuse, each named in the error: a rotated
    # world file, a world file of five lines, a .prj CRS with no EPSG code
    # that is no UTM zone, an .aux.xml that is not XML.
    wf = open(os.path.join(OUT, "wf_wld_prj.tif"), "rb").read()
    esri = rasterio.crs.CRS.from_string(UTM).to_wkt(version="WKT1_ESRI")
    for name, tfw, prj, aux, kind in [
        ("bad_wf_rotated", "0.5\n0.1\n0.1\n-0.5\n630000.75\n4830000.0\n", esri, None, "rotated"),
        ("bad_wf_short", "0.5\n0.0\n0.0\n-0.5\n630000.75\n", esri, None, "side_file"),
        ("bad_wf_prj_lambert", "0.5\n0.0\n0.0\n-0.5\n630000.75\n4830000.0\n",
         esri.replace("Transverse_Mercator", "Lambert_Conformal_Conic"), None, "side_file"),
        ("bad_wf_aux_xml", None, None, "<PAMDataset><SRS>PROJCS[", "side_file"),
    ]:
        stem = os.path.join(OUT, name)
        open(stem + ".tif", "wb").write(wf)
        names = {"rotated": ".tfw", "side_file": ".prj" if "lambert" in name else ".tfw"}[kind]
        if tfw is not None:
            open(stem + ".tfw", "w").write(tfw)
        if prj is not None:
            open(stem + ".prj", "w").write(prj)
        if aux is not None:
            open(stem + ".tif.aux.xml", "w").write(aux)
            names = ".tif.aux.xml"
        bad.append({"file": name + ".tif", "error": kind, "names": name + names})

    real = [expect_real(p) for p in sorted(glob.glob(os.path.join(ROOT, "fixtures/real/*/*.tif")))]

    expected = {
        "generator": "tools/scripts/make_test_tiffs.py",
        "gdal_version": rasterio.__gdal_version__,
        "rasterio_version": rasterio.__version__,
        "note": "pixels/*.bin: width*height little-endian f32, row-major, NaN = no-data",
        "good": good,
        "bad": bad,
        "real": real,
    }
    with open(os.path.join(OUT, "expected.json"), "w") as f:
        f.write(compact_json(expected))
    with open(os.path.join(OUT, "README.md"), "w") as f:
        f.write(README.format(gdal=rasterio.__gdal_version__, rio=rasterio.__version__))
    total = sum(os.path.getsize(p) for p in glob.glob(os.path.join(OUT, "**"), recursive=True)
                if os.path.isfile(p))
    print(f"{len(good)} good, {len(bad)} bad, {len(real)} real; {total / 1e6:.2f} MB in {OUT}")


if __name__ == "__main__":
    main()
