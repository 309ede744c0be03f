#!/usr/bin/env bash
# Open every DSM of a dsmstream store with GDAL, as a GIS user would, and check
# that GDAL sees the CRS and geotransform the store's catalog records.
#
#   tools/scripts/check_gdal.sh collection.zarr
#
# Needs gdalinfo >= 3.13 (final-spec Zarr v3, sharding, the spatial:/proj:
# conventions and multiscales as overviews). Older GDAL: exits 3 saying so
# (GDAL 3.10 rejects the store with "Unsupported codec: bytes").
# Exit 0 when every level 0 opens with the catalog's geotransform and EPSG code,
# 1 on a mismatch, 2 on bad usage.
set -euo pipefail
store=${1:?usage: check_gdal.sh <store.zarr>}
[ -f "$store/zarr.json" ] || { echo "$store: not a Zarr v3 store (no zarr.json)" >&2; exit 2; }
command -v gdalinfo >/dev/null || { echo "gdalinfo not found (install GDAL >= 3.13)" >&2; exit 3; }
version=$(gdalinfo --version | sed -E 's/^GDAL ([0-9]+)\.([0-9]+).*/\1 \2/')
read -r major minor <<<"$version"
if [ "$major" -lt 3 ] || { [ "$major" -eq 3 ] && [ "$minor" -lt 13 ]; }; then
    echo "$(gdalinfo --version): GDAL >= 3.13 reads this store; use 'dsmstream fuse --per-dsm DIR' for GeoTIFFs" >&2
    exit 3
fi
status=0
for id in $(python3 -c 'import json,sys; print(" ".join(json.load(open(sys.argv[1]))["attributes"]["dsmstream"]["dsms"]))' "$store/zarr.json"); do
    want=$(python3 - "$store/$id/zarr.json" <<'PY'
import json, sys
m = json.load(open(sys.argv[1]))["attributes"]["dsmstream"]
print(" ".join(repr(float(v)) for v in m["geotransform"]), m["crs"].get("epsg") or "none")
PY
)
    got=$(gdalinfo -json "ZARR:\"$store\":/$id/0" | python3 -c '
import json, sys
d = json.load(sys.stdin)
gt = d.get("geoTransform")
wkt = d.get("coordinateSystem", {}).get("wkt", "")
import re
codes = re.findall(r"ID\[\"EPSG\",(\d+)\]\]\s*$", wkt)
print(" ".join(repr(float(v)) for v in gt) if gt else "no-geotransform", codes[-1] if codes else "none",
      len(d.get("bands", [{}])[0].get("overviews", [])))
')
    read -r -a w <<<"$want"
    read -r -a g <<<"$got"
    if [ "${w[*]:0:7}" == "${g[*]:0:7}" ]; then
        echo "ok        $id: geotransform ${g[*]:0:6}, EPSG ${g[6]}, ${g[7]} overviews"
    else
        echo "MISMATCH  $id: GDAL ${g[*]} vs catalog ${w[*]}"
        status=1
    fi
done
exit $status
