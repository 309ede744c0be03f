#!/usr/bin/env bash
# End-to-end check of the Slurm scripts on a one-node cluster brought up on this machine:
# generates a 16-DSM collection, submits ingest (job array) -> align shards (job array) ->
# merge (afterok) through submit.sh, waits, then aligns the same store in one process and
# checks the poses agree to 1e-9. Exits 0 on success; always tears the cluster down.
#   tools/slurm/selftest.sh [SHARDS]      (run as root; installs slurm-wlm and munge if absent)
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
shards=${1:-3}
work=$(mktemp -d /tmp/dsmstream-slurm.XXXXXX)
export SLURM_CONF=$work/cluster/slurm.conf
cleanup() {
  "$root/tools/slurm/cluster.sh" down "$work/cluster" || true
  rm -rf "$work"
}
trap cleanup EXIT

cargo build --release --quiet --manifest-path "$root/Cargo.toml" --bin dsmstream --bin dsmgen
export DSMSTREAM=$root/target/release/dsmstream
"$root/tools/slurm/cluster.sh" up "$work/cluster"

"$root/target/release/dsmgen" tiles --layout grid --rows 4 --cols 4 --size 256 --overlap 0.4 \
  --seed 7 --out "$work/tiles" >/dev/null
ls "$work"/tiles/*.tif >"$work/list.txt"
cd "$work"
merge=$("$root/tools/slurm/submit.sh" "$work/list.txt" "$work/store.zarr" "$work/poses.json" "$shards")
echo "selftest: submitted; merge job $merge"

state=""
for _ in $(seq 600); do
  state=$(scontrol show job "$merge" 2>/dev/null | sed -n 's/.*JobState=\([A-Z_]*\).*/\1/p')
  case $state in COMPLETED|FAILED|CANCELLED|TIMEOUT|NODE_FAIL|OUT_OF_MEMORY) break ;; esac
  if squeue -h -j "$merge" -o %r 2>/dev/null | grep -q DependencyNeverSatisfied; then
    state=DEPENDENCY_NEVER_SATISFIED; break
  fi
  sleep 1
done
if [ "$state" != COMPLETED ]; then
  echo "selftest: merge job $merge ended as '${state:-unknown}'; logs:" >&2
  tail -n 5 "$work"/*.log >&2 || true
  exit 1
fi

n=$("$DSMSTREAM" info "$work/store.zarr" --json | python3 -c 'import json,sys; print(len(json.load(sys.stdin)["dsms"]))')
[ "$n" = 16 ] || { echo "selftest: the store holds $n DSMs, expected 16" >&2; exit 1; }
"$DSMSTREAM" align "$work/store.zarr" --out "$work/single.json" --threads 2 -q
python3 - "$work/poses.json" "$work/single.json" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
pa = {p["id"]: p["matrix_world"] for p in a["poses"]}
pb = {p["id"]: p["matrix_world"] for p in b["poses"]}
assert pa.keys() == pb.keys(), f"ids differ: {sorted(pa.keys() ^ pb.keys())}"
worst = max(abs(x - y) for k in pa for ra, rb in zip(pa[k], pb[k]) for x, y in zip(ra, rb))
print(f"selftest: {len(pa)} poses, largest difference sharded vs single run {worst:.3g}")
sys.exit(0 if worst <= 1e-9 else 1)
PY
echo "selftest: passed"
