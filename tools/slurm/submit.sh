#!/usr/bin/env bash
# Submits the whole collection run: ingest array -> align shard array -> merge,
# chained with --dependency=afterok. Prints the merge job id.
#   tools/slurm/submit.sh LIST STORE POSES SHARDS [align flags...]
# LIST: one GeoTIFF (or directory) per line, on a filesystem every node sees.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
list=$1; store=$2; poses=$3; shards=$4; shift 4
n=$(grep -c . "$list")
[ "$n" -gt 0 ] || { echo "submit.sh: $list lists no input" >&2; exit 2; }
ingest=$(sbatch --parsable --array=0-$((n - 1)) "$here/ingest.sbatch" "$list" "$store")
align=$(sbatch --parsable --dependency=afterok:"$ingest" --array=0-$((shards - 1)) \
  "$here/align_shard.sbatch" "$store" "$poses" "$@")
merge=$(sbatch --parsable --dependency=afterok:"$align" "$here/merge.sbatch" "$store" "$poses" "$@")
echo "$merge"
