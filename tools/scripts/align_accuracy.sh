#!/usr/bin/env bash
# Accuracy of `dsmstream align` on generated collections (issue 4): for each
# collection, one ICP run (full graph, information weights), then the paper's
# weights and the spanning tree replayed from a copy of its journal (`--resume`:
# the same pairwise results). Prints a Markdown table of the pose errors against
# truth.json up to the gauge: pairwise (worst m / worst deg over all tile pairs)
# and per DSM (worst m / worst deg after the best rigid gauge), edges dropped,
# and the align time.
#
# Usage: tools/scripts/align_accuracy.sh [SPEC ...]   (from the repository root, after
#        cargo build --release --bins)
#   SPEC = chain:SIZE:SEED or grid:SIZE:SEED (default: chains and 4x4 grids of
#   384, 1024 and 2048 px, seed 12).
# Env:   WORK (default: a new temp dir), BIN (default target/release),
#        ALIGN_ARGS (extra align flags, e.g. "--samples 50000"), KEEP=1 keeps WORK.
# Needs python3 with numpy (tools/scripts/compare_poses.py).
set -euo pipefail

BIN=${BIN:-target/release}
ALIGN_ARGS=${ALIGN_ARGS:-}
WORK=${WORK:-$(mktemp -d /tmp/align_accuracy.XXXXXX)}
[ "${KEEP:-0}" = 1 ] || trap 'rm -rf "$WORK"' EXIT
specs=("$@")
[ ${#specs[@]} -gt 0 ] || specs=(chain:384:12 grid:384:12 chain:1024:12 grid:1024:12 chain:2048:12 grid:2048:12)
ds="$BIN/dsmstream"

errors() {  # poses truth -> "pair_m pair_deg dsm_m dsm_deg"
  python3 tools/scripts/compare_poses.py "$1" "$2" | awk '
    /^worst/ {pm=$2; pd=$4}
    /^per-DSM worst/ {dm=$3; dd=$5}
    END {printf "%.3f / %.4f | %.3f / %.4f", pm, pd, dm, dd}'
}

echo "| collection | graph, weights | pairwise worst m / deg | per DSM worst m / deg | dropped | align s |"
echo "|---|---|---|---|---|---|"
for spec in "${specs[@]}"; do
  IFS=: read -r layout size seed <<<"$spec"
  dir="$WORK/${layout}_${size}_${seed}"
  rm -rf "$dir" && mkdir -p "$dir"
  if [ "$layout" = grid ]; then
    gen=(--layout grid --rows 4 --cols 4)
    name="grid 4x4 x $size px, seed $seed"
  else
    gen=(--count 12)
    name="chain 12 x $size px, seed $seed"
  fi
  "$BIN/dsmgen" tiles "${gen[@]}" --size "$size" --seed "$seed" --out "$dir/tiles" >/dev/null
  "$ds" ingest "$dir/tiles" --store "$dir/c.zarr" -q >/dev/null
  for variant in "full information" "full paper" "mst -"; do
    read -r graph weights <<<"$variant"
    out="$dir/${graph}_${weights}.json"
    args=(--graph "$graph")
    [ "$weights" = - ] || args+=(--weights "$weights")
    if [ "$variant" != "full information" ]; then
      cp "$dir/full_information.json.journal" "$out.journal"
      args+=(--resume)
    fi
    start=$(date +%s%N)
    # shellcheck disable=SC2086
    "$ds" align "$dir/c.zarr" --out "$out" "${args[@]}" $ALIGN_ARGS -q >/dev/null 2>&1
    ms=$((($(date +%s%N) - start) / 1000000))
    dropped=$(python3 -c "import json,sys; print(sum(e.get('dropped', False) for e in json.load(open(sys.argv[1]))['edges']))" "$out")
    label="$graph, $weights"
    [ "$graph" = mst ] && label="mst"
    printf "| %s | %s | %s | %s | %d.%d |\n" "$name" "$label" "$(errors "$out" "$dir/tiles/truth.json")" \
      "$dropped" $((ms / 1000)) $((ms % 1000 / 100))
  done
done
