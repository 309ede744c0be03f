#!/usr/bin/env bash
# Sigma calibration of the pairs (issue 11): over generated collections in
# several renderings, seeds and tile sizes, the fraction of journaled pairs whose
# error on each axis is within 1, 2, 3 of the sigma they reported (converged
# pairs only, axes the fit held excluded). Prints a Markdown table.
#
# Usage: tools/scripts/calibration.sh [SPEC ...]   (repository root, after
#        cargo build --release --bins)
#   SPEC = ROWSxCOLS:SIZE:OVERLAP:SEED:RENDER (default: 3x3 grids of 512 px at
#   0.3 overlap, seeds 1-2, renderings centre, lidar-max, tin, smooth).
# Env: WORK (default: a new temp dir), BIN (default target/release), KEEP=1.
set -euo pipefail

BIN=${BIN:-target/release}
WORK=${WORK:-$(mktemp -d /tmp/calibration.XXXXXX)}
[ "${KEEP:-0}" = 1 ] || trap 'rm -rf "$WORK"' EXIT
specs=("$@")
if [ ${#specs[@]} -eq 0 ]; then
  for render in centre lidar-max tin smooth; do
    for seed in 1 2; do specs+=("3x3:512:0.3:$seed:$render"); done
  done
fi
scores=()
for spec in "${specs[@]}"; do
  IFS=: read -r shape size overlap seed render <<<"$spec"
  dir="$WORK/${shape}_${size}_${overlap}_${seed}_${render}"
  rm -rf "$dir" && mkdir -p "$dir"
  "$BIN/dsmgen" tiles --layout grid --rows "${shape%x*}" --cols "${shape#*x}" --size "$size" \
    --overlap "$overlap" --seed "$seed" --render "$render" --out "$dir/tiles" >/dev/null
  "$BIN/dsmstream" ingest "$dir/tiles" --store "$dir/c.zarr" -q >/dev/null
  "$BIN/dsmstream" align "$dir/c.zarr" --out "$dir/p.json" -q >/dev/null 2>&1 || true
  [ -f "$dir/p.json" ] || { echo "$spec: align failed" >&2; continue; }
  "$BIN/dsmgen" score --truth "$dir/tiles/truth.json" --poses "$dir/p.json" --json \
    --worst 1000000 >"$dir/score.json"
  scores+=("$dir/score.json")
done
python3 - "${scores[@]}" <<'PY'
import json, sys
axes = ["x", "y", "z", "roll", "pitch", "yaw"]
ratios = {a: [] for a in axes}
pairs = 0
for path in sys.argv[1:]:
    for e in json.load(open(path))["worst_ratio_edges"]:
        if e["status"] != "converged":
            continue
        pairs += 1
        for k, a in enumerate(axes):
            if e["sigma"][k]:
                ratios[a].append(abs(e["error"][k]) / e["sigma"][k])
print(f"{len(sys.argv) - 1} collections, {pairs} converged pairs")
print("| axis | pairs with sigma | <= 1 sigma | <= 2 sigma | <= 3 sigma | worst |error|/sigma |")
print("|---|---|---|---|---|---|")
for a in axes:
    r = ratios[a]
    f = lambda m: sum(v <= m for v in r) / max(len(r), 1)
    print(f"| {a} | {len(r)} | {f(1):.3f} | {f(2):.3f} | {f(3):.3f} | {max(r, default=0):.2f} |")
PY
