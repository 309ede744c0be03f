#!/usr/bin/env bash
# Issue 11's collections at DEFAULT flags: grids of small tiles (narrow
# overlaps, many weak pairs) in several renderings and seeds. For each: dsmgen
# tiles, ingest, align, then `dsmgen score` against truth.json: per-DSM median
# and worst, pairwise worst over all tile pairs, edges dropped, the sigma
# calibration of the journaled pairs (fraction within 3 sigma on the worst
# axis), align wall time and peak RSS. Prints a Markdown table.
#
# Usage: tools/scripts/grid_accuracy.sh [SPEC ...]   (repository root, after
#        cargo build --release --bins)
#   SPEC = ROWSxCOLS:SIZE:SEED:RENDER, e.g. 10x10:512:4:centre (default: the
#   issue's 10x10:512:4 and 20x20:256:3 in the centre and lidar-max renderings).
# Env: WORK (default: a new temp dir), BIN (default target/release), KEEP=1.
set -euo pipefail

BIN=${BIN:-target/release}
WORK=${WORK:-$(mktemp -d /tmp/grid_accuracy.XXXXXX)}
[ "${KEEP:-0}" = 1 ] || trap 'rm -rf "$WORK"' EXIT
specs=("$@")
[ ${#specs[@]} -gt 0 ] || specs=(10x10:512:4:centre 10x10:512:4:lidar-max 20x20:256:3:centre 20x20:256:3:lidar-max)

echo "| collection | per-DSM median m | per-DSM worst m / deg | pairwise worst m / deg | edges (dropped) | pairs within 3 sigma (worst axis) | align s | align MB |"
echo "|---|---|---|---|---|---|---|---|"
for spec in "${specs[@]}"; do
  IFS=: read -r shape size seed render <<<"$spec"
  rows=${shape%x*}; cols=${shape#*x}
  dir="$WORK/${shape}_${size}_${seed}_${render}"
  rm -rf "$dir" && mkdir -p "$dir"
  "$BIN/dsmgen" tiles --layout grid --rows "$rows" --cols "$cols" --size "$size" \
    --overlap 0.3 --seed "$seed" --render "$render" --out "$dir/tiles" >/dev/null
  "$BIN/dsmstream" ingest "$dir/tiles" --store "$dir/c.zarr" -q >/dev/null
  /usr/bin/time -f "%e %M" -o "$dir/time" "$BIN/dsmstream" align "$dir/c.zarr" \
    --out "$dir/p.json" -q >"$dir/summary" 2>"$dir/stderr" || true
  read -r wall rss_kb <"$dir/time"
  if [ ! -f "$dir/p.json" ]; then
    echo "| $spec | align failed: $(head -c 200 "$dir/stderr") | | | | | $wall | $((rss_kb / 1024)) |"
    continue
  fi
  "$BIN/dsmgen" score --truth "$dir/tiles/truth.json" --poses "$dir/p.json" --json >"$dir/score.json"
  python3 - "$dir" "$spec" "$wall" "$rss_kb" <<'PY'
import json, sys
d, spec, wall, rss = sys.argv[1], sys.argv[2], float(sys.argv[3]), int(sys.argv[4])
s = json.load(open(f"{d}/score.json"))
p = json.load(open(f"{d}/p.json"))
edges = p.get("edges", [])
dropped = sum(1 for e in edges if e.get("dropped"))
cal = [c for c in s["calibration"] if c["with_sigma"] > 0]
within3 = min((c["within"][2] for c in cal), default=float("nan"))
axis = min(cal, key=lambda c: c["within"][2])["axis"] if cal else "-"
pd, pw = s["per_dsm"], s["pairwise"]
print(f"| {spec} | {pd['median_m']:.3f} | {pd['worst_m']:.3f} / {pd['worst_deg']:.3f} | "
      f"{pw['worst_m']:.3f} / {pw['worst_deg']:.3f} | {len(edges)} ({dropped}) | "
      f"{within3:.3f} ({axis}) | {wall:.0f} | {rss // 1024} |")
PY
done
