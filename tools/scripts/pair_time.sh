#!/usr/bin/env bash
# Time and memory of `dsmstream pair` for several builds side by side, on the
# same generated pairs (the well-posed cases of tools/scripts/compare_peers.py:
# `dsmgen tiles --count 2`, city terrain at 0.5 m). Runs alternate between the
# builds, so a busy machine slows them alike; prints the median wall time and
# the largest peak RSS of RUNS runs per build and case, and each build's ratio
# to the first one.
#
# Usage: tools/scripts/pair_time.sh DIR...   (each DIR holds a dsmstream build;
#        the first is the baseline; tiles come from the first DIR with dsmgen)
# Env:   CASES ("1:1024 7:2048", seed:size), RUNS (5), WORK (/tmp/pair_time),
#        GEN (the dsmgen to use)
#
# Each build ingests the tiles into a store of its own (store formats may
# differ between versions; ingest is not timed: it is paid once per DSM).
set -euo pipefail

CASES=${CASES:-"1:1024 7:2048"}
RUNS=${RUNS:-5}
WORK=${WORK:-/tmp/pair_time}
[ $# -ge 1 ] || { echo "usage: $0 DIR..." >&2; exit 2; }
[ -x /usr/bin/time ] || { apt-get install -y -qq time >/dev/null; }
gen=${GEN:-}
for d in "$@"; do [ -n "$gen" ] || { [ -x "$d/dsmgen" ] && gen="$d/dsmgen"; }; done
[ -n "$gen" ] || { echo "no dsmgen in $*" >&2; exit 2; }
mkdir -p "$WORK"

echo "| case | build | median wall (s) | peak RSS (MiB) | time / first | memory / first |"
echo "|---|---|---|---|---|---|"
for case in $CASES; do
  seed=${case%%:*}; size=${case##*:}
  tiles="$WORK/t${seed}_${size}"
  rm -rf "$tiles"
  "$gen" tiles --count 2 --size "$size" --seed "$seed" --out "$tiles" >/dev/null
  for k in $(seq 1 $#); do
    d=${!k}
    rm -rf "$WORK/s${k}.zarr"
    "$d/dsmstream" ingest "$tiles" --store "$WORK/s${k}.zarr" -q >/dev/null
    : > "$WORK/runs_$k"
  done
  for r in $(seq 1 "$RUNS"); do
    for k in $(seq 1 $#); do
      d=${!k}
      /usr/bin/time -f "%e %M" -o "$WORK/one" "$d/dsmstream" pair "$WORK/s${k}.zarr" tile_00 tile_01 -q >/dev/null
      cat "$WORK/one" >> "$WORK/runs_$k"
    done
  done
  base_t=""; base_m=""
  for k in $(seq 1 $#); do
    d=${!k}
    read -r t m < <(sort -n "$WORK/runs_$k" | awk '{w[NR]=$1; if ($2>m) m=$2} END{print w[int((NR+1)/2)], m/1024}')
    [ -n "$base_t" ] || { base_t=$t; base_m=$m; }
    printf "| %s px (seed %s) | %s | %.2f | %.0f | %.2f | %.2f |\n" "$size" "$seed" "$d" "$t" "$m" \
      "$(echo "$t / $base_t" | bc -l)" "$(echo "$m / $base_m" | bc -l)"
  done
done
