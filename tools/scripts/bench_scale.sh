#!/usr/bin/env bash
# Many-DSM benchmark (issue 12): wall time, CPU time and peak RSS of ingest, align, fuse
# and eval on a generated ROWS x COLS grid of SIZE-pixel tiles, each stage under
# `/usr/bin/time -v`, with the 1-minute load average before each stage (the machine is shared).
#
# Usage: tools/scripts/bench_scale.sh ROWS COLS SIZE        (from the repository root)
# Env:   BENCH_DIR (default /tmp/dsmstream_scale), BIN (default target/release),
#        CACHE_MB (256), THREADS (default: all cores), FUSE_GSD (fuse cell, default 4 m:
#        a 10^4 mosaic at full resolution is a multi-GB file), EVAL_SAMPLES (10000),
#        DSMGEN_FLAGS (extra `dsmgen tiles` flags, e.g. "--lakes 0": at 10^4 tiles
#        of 128 px the default lakes leave a tile with no valid pixel, which ingest refuses),
#        ALIGN_FLAGS (default "--min-overlap 0.1 --min-overlap-px 0": the pairs of the
#        README's table; small tiles stand in for DSMs here, and their strips are below
#        the default --min-overlap-px).
# Prints one Markdown row per stage.
set -euo pipefail
rows=$1; cols=$2; size=$3
BENCH_DIR=${BENCH_DIR:-/tmp/dsmstream_scale}
BIN=${BIN:-target/release}
CACHE_MB=${CACHE_MB:-256}
THREADS=${THREADS:-$(nproc)}
FUSE_GSD=${FUSE_GSD:-4}
EVAL_SAMPLES=${EVAL_SAMPLES:-10000}
ALIGN_FLAGS=${ALIGN_FLAGS:---min-overlap 0.1 --min-overlap-px 0}
work=$BENCH_DIR/${rows}x${cols}x${size}
mkdir -p "$work"
wall() { awk -F': ' '/Elapsed \(wall clock\)/{n=split($2,a,":"); s=0; for(i=1;i<=n;i++) s=s*60+a[i]; print s}' "$1"; }
cpu() { awk -F': ' '/User time/{u=$2} /System time/{s=$2} END{print u+s}' "$1"; }
rss() { awk -F': ' '/Maximum resident/{printf "%.0f", $2/1024}' "$1"; }
load() { cut -d' ' -f1 /proc/loadavg; }
stage() { # name, then the command
  local name=$1; shift
  local l; l=$(load)
  /usr/bin/time -v -o "$work/$name.time" "$@" >"$work/$name.out" 2>"$work/$name.err" || {
    echo "bench_scale: $name failed; see $work/$name.err" >&2; tail -3 "$work/$name.err" >&2; exit 1; }
  printf '| %s | %s | %s | %s | %s | %s |\n' "$((rows * cols))" "$name" "$(wall "$work/$name.time")" \
    "$(cpu "$work/$name.time")" "$(rss "$work/$name.time")" "$l"
}
[ -d "$work/tiles" ] || "$BIN/dsmgen" tiles --layout grid --rows "$rows" --cols "$cols" --size "$size" \
  --overlap 0.3 --seed 1 ${DSMGEN_FLAGS:-} --out "$work/tiles" >/dev/null
rm -rf "$work/store.zarr" "$work"/poses.json*
echo "| DSMs | stage | wall s | CPU s | peak RSS MB | load avg (1 min) |"
echo "|---|---|---|---|---|---|"
stage ingest "$BIN/dsmstream" ingest "$work/tiles" --store "$work/store.zarr" -q
stage align "$BIN/dsmstream" align "$work/store.zarr" --out "$work/poses.json" \
  --threads "$THREADS" --cache-mb "$CACHE_MB" $ALIGN_FLAGS -q
stage fuse "$BIN/dsmstream" fuse "$work/store.zarr" --poses "$work/poses.json" --gsd "$FUSE_GSD" \
  --out "$work/fused.tif" --threads "$THREADS" --cache-mb "$CACHE_MB" -q
stage eval "$BIN/dsmstream" eval "$work/store.zarr" --poses "$work/poses.json" \
  --max-samples "$EVAL_SAMPLES" --threads "$THREADS" --cache-mb "$CACHE_MB" -q
