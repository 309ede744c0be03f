#!/usr/bin/env bash
# Ingest benchmark (issue 2): `dsmstream ingest` vs `gdal_translate -of Zarr`
# on the same generated 20000 x 20000 float32 Deflate-tiled GeoTIFF, side by
# side in one run: wall time, CPU time and peak RSS from `/usr/bin/time -v`,
# RUNS runs of each (interleaved, a fresh output store every run), medians.
#
# Usage: tools/scripts/bench_ingest.sh [RUNS]          (from the repository root)
# Env:   BENCH_DIR (default /tmp/dsmstream_bench), SIZE (default 20000),
#        BIN (default target/release), INPUT (default $BENCH_DIR/big_$SIZE.tif),
#        BASE_BIN (a folder with another build's dsmstream, e.g. of the previous
#        commit: adds the row `dsmstream_base`, for before/after in one run),
#        NAMES (the rows to run, default all; e.g. "dsmstream dsmstream_base gdal_default")
#
# Needs a release build (`cargo build --release`) and gdal-bin, which this
# script installs with apt-get when gdal_translate is missing (benchmark only;
# the tests never need GDAL). Prints a Markdown table for tools/results/bench_results.md.
set -euo pipefail

RUNS=${1:-3}
BENCH_DIR=${BENCH_DIR:-/tmp/dsmstream_bench}
SIZE=${SIZE:-20000}
BIN=${BIN:-target/release}
INPUT=${INPUT:-$BENCH_DIR/big_$SIZE.tif}
mkdir -p "$BENCH_DIR"

if ! command -v gdal_translate >/dev/null; then
  apt-get update -qq && apt-get install -y -qq gdal-bin >/dev/null
fi
[ -x /usr/bin/time ] || { apt-get install -y -qq time >/dev/null; }
if [ ! -f "$INPUT" ]; then
  echo "generating $INPUT" >&2
  /usr/bin/time -f "dsmgen: %e s wall, %M kB peak RSS" \
    "$BIN/dsmgen" big --size "$SIZE" --gsd 0.5 --seed 1 --out "$INPUT"
fi

# name -> command (the output store is appended as $OUT)
declare -A CMD=(
  [dsmstream]="$BIN/dsmstream ingest $INPUT --store \$OUT -q"
  [dsmstream_zstd3]="$BIN/dsmstream ingest $INPUT --store \$OUT -q --compression zstd:3"
  [dsmstream_base]="${BASE_BIN:-$BIN}/dsmstream ingest $INPUT --store \$OUT -q"
  [gdal_default]="gdal_translate -q -of Zarr $INPUT \$OUT"
  [gdal_matched]="gdal_translate -q -of Zarr -co FORMAT=ZARR_V3 -co COMPRESS=ZSTD -co ZSTD_LEVEL=3 -co BLOCKSIZE=512,512 $INPUT \$OUT"
)
default_names="dsmstream dsmstream_zstd3 gdal_default gdal_matched"
[ -n "${BASE_BIN:-}" ] && default_names="dsmstream dsmstream_base dsmstream_zstd3 gdal_default gdal_matched"
read -r -a NAMES <<<"${NAMES:-$default_names}"

declare -A WALL CPU USR SYS RSS BYTES
for run in $(seq 1 "$RUNS"); do
  for name in "${NAMES[@]}"; do
    OUT="$BENCH_DIR/out_$name.zarr"
    rm -rf "$OUT"
    log="$BENCH_DIR/time_$name.$run.log"
    cmd=${CMD[$name]//\$OUT/$OUT}
    /usr/bin/time -v $cmd 2>"$log" >/dev/null
    wall=$(awk -F': ' '/Elapsed \(wall clock\)/{n=split($2,a,":"); s=0; for(i=1;i<=n;i++) s=s*60+a[i]; print s}' "$log")
    cpu=$(awk -F': ' '/User time/{u=$2} /System time/{s=$2} END{print u+s}' "$log")
    usr=$(awk -F': ' '/User time/{print $2}' "$log")
    sys=$(awk -F': ' '/System time/{print $2}' "$log")
    rss=$(awk -F': ' '/Maximum resident/{printf "%.0f", $2/1024}' "$log")
    bytes=$(du -sm "$OUT" | cut -f1)
    WALL[$name]+="$wall "; CPU[$name]+="$cpu "; USR[$name]+="$usr "; SYS[$name]+="$sys "; RSS[$name]+="$rss "; BYTES[$name]=$bytes
    echo "run $run $name: wall ${wall}s cpu ${cpu}s rss ${rss}MB out ${bytes}MB (load $(cut -d' ' -f1 /proc/loadavg))" >&2
    rm -rf "$OUT"
  done
done

median() { tr ' ' '\n' | grep -v '^$' | sort -g | awk '{a[NR]=$1} END{print (NR%2)? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2}'; }

echo
echo "input: $INPUT ($(du -m "$INPUT" | cut -f1) MB), $RUNS runs each, $(date -u +%Y-%m-%d), $(nproc) cores, $(gdalinfo --version)"
echo
echo "| tool | wall median (s) | wall runs (s) | CPU user+sys median (s) | CPU runs (s) | user / sys medians (s) | peak RSS median (MB) | RSS runs (MB) | output (MB) |"
echo "|---|---|---|---|---|---|---|---|---|"
for name in "${NAMES[@]}"; do
  echo "| $name | $(echo "${WALL[$name]}" | median) | ${WALL[$name]% } | $(echo "${CPU[$name]}" | median) | ${CPU[$name]% } | $(echo "${USR[$name]}" | median) / $(echo "${SYS[$name]}" | median) | $(echo "${RSS[$name]}" | median) | ${RSS[$name]% } | ${BYTES[$name]} |"
done
