#!/usr/bin/env bash
# Align and fuse memory benchmark (issues 4 and 5): peak RSS and time of
# `dsmstream align --cache-mb 128`, then `dsmstream fuse` of its poses at the
# same budget, on generated grid collections of growing size, to show that
# memory is the cache budget plus a constant, whatever the number of DSMs.
#
# Usage: tools/scripts/bench_align.sh ROWSxCOLSxSIZE...   (from the repository root)
#   e.g. tools/scripts/bench_align.sh 4x4x4096 8x8x4096 8x8x1024 16x16x1024
# Env:   BENCH_DIR (default /tmp/dsmstream_bench), BIN (default target/release),
#        CACHE_MB (128), THREADS (default: all cores), OVERLAP (0.3),
#        ALIGN_ARGS (extra align flags), FUSE=0 skips fuse, KEEP=1 keeps
#        tiles and stores.
#
# Each collection: `dsmgen tiles --layout grid` (seed 1, 0.5 m GSD), `dsmstream
# ingest`, `dsmstream align`, `dsmstream fuse`, each under `/usr/bin/time -v`. Prints one
# Markdown row per collection for tools/results/bench_results.md; logs go to BENCH_DIR.
set -euo pipefail

BENCH_DIR=${BENCH_DIR:-/tmp/dsmstream_bench}
BIN=${BIN:-target/release}
CACHE_MB=${CACHE_MB:-128}
OVERLAP=${OVERLAP:-0.3}
THREADS=${THREADS:-$(nproc)}
ALIGN_ARGS=${ALIGN_ARGS:-}
mkdir -p "$BENCH_DIR"
[ -x /usr/bin/time ] || { apt-get install -y -qq time >/dev/null; }

# field extractors for a /usr/bin/time -v log
wall() { awk -F': ' '/Elapsed \(wall clock\)/{n=split($2,a,":"); s=0; for(i=1;i<=n;i++) s=s*60+a[i]; print s}' "$1"; }
cpu() { awk -F': ' '/User time/{u=$2} /System time/{s=$2} END{print u+s}' "$1"; }
rss() { awk -F': ' '/Maximum resident/{printf "%.0f", $2/1024}' "$1"; }

echo "| collection | DSMs | px per DSM | dsmgen wall (s) | ingest wall / CPU (s) | ingest peak RSS (MB) | pairs (edges) | align wall / CPU (s) | align peak RSS (MB) | cache peak (MB) | hit rate | fuse wall / CPU (s) | fuse peak RSS (MB) | mosaic px |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
for spec in "$@"; do
  IFS=x read -r rows cols size <<<"$spec"
  name="grid_${rows}x${cols}_${size}"
  tiles="$BENCH_DIR/$name"
  store="$BENCH_DIR/$name.zarr"
  log="$BENCH_DIR/$name"
  if [ ! -f "$tiles/truth.json" ]; then
    rm -rf "$tiles"
    /usr/bin/time -v "$BIN/dsmgen" tiles --layout grid --rows "$rows" --cols "$cols" \
      --size "$size" --gsd 0.5 --overlap "$OVERLAP" --seed 1 --out "$tiles" \
      >/dev/null 2>"$log.dsmgen.time"
    gen=$(wall "$log.dsmgen.time")
  else
    gen="(cached)"
  fi
  rm -rf "$store"
  /usr/bin/time -v "$BIN/dsmstream" ingest "$tiles" --store "$store" -q \
    >/dev/null 2>"$log.ingest.time"
  out="$BENCH_DIR/$name.poses.json"
  rm -f "$out" "$out.journal"
  # -v: the "cache stats reported" event goes to the log
  /usr/bin/time -v "$BIN/dsmstream" align "$store" --out "$out" -v \
    --cache-mb "$CACHE_MB" --threads "$THREADS" $ALIGN_ARGS \
    >"$log.align.out" 2>"$log.align.time"
  pairs=$(($(wc -l <"$out.journal") - 1))
  edges=$(grep -o '"edges"' "$out" >/dev/null && python3 -c "import json,sys; print(len(json.load(open(sys.argv[1]))['edges']))" "$out")
  stats=$(sed 's/\x1b\[[0-9;]*m//g' "$log.align.time" | grep "cache stats reported" | tail -1)
  peak=$(sed -n 's/.*peak_mb="\{0,1\}\([0-9.]*\).*/\1/p' <<<"$stats")
  hit=$(sed -n 's/.*hit_rate="\{0,1\}\([0-9.]*\).*/\1/p' <<<"$stats")
  fuse_cols="| | |"
  if [ "${FUSE:-1}" = 1 ]; then
    fused="$BENCH_DIR/$name.fused.tif"
    rm -f "$fused"
    /usr/bin/time -v "$BIN/dsmstream" fuse "$store" --poses "$out" --out "$fused" \
      --cache-mb "$CACHE_MB" --threads "$THREADS" -q >"$log.fuse.out" 2>"$log.fuse.time"
    mosaic=$(grep -o '[0-9]* x [0-9]* px' "$log.fuse.out" | head -1)
    fuse_cols="| $(wall "$log.fuse.time") / $(cpu "$log.fuse.time") | $(rss "$log.fuse.time") | $mosaic |"
    if [ "${KEEP:-0}" != 1 ]; then rm -f "$fused"; fi
  fi
  echo "| $name | $((rows * cols)) | ${size}² | $gen | $(wall "$log.ingest.time") / $(cpu "$log.ingest.time") | $(rss "$log.ingest.time") | $pairs ($edges) | $(wall "$log.align.time") / $(cpu "$log.align.time") | $(rss "$log.align.time") | $peak | $hit $fuse_cols"
  if [ "${KEEP:-0}" != 1 ]; then rm -rf "$store"; fi
done
echo
echo "$(date -u +%Y-%m-%d), $(nproc) cores, load $(cut -d' ' -f1-3 /proc/loadavg), cache ${CACHE_MB} MiB, threads $THREADS, overlap $OVERLAP, align args: ${ALIGN_ARGS:-(defaults)}"
