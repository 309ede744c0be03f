#!/usr/bin/env bash
# Real-data figures (issue 5): the ttp2015 lidar DSM (1 m, EPSG:26917) cut into
# a 3 x 2 grid of overlapping tiles, each moved by a known rigid motion
# (`dsmgen cut`, tile_00 left in place), then ingest, align (full graph and
# spanning tree, gauge fixed on tile_00), fuse and eval. Prints the README table.
#
# Usage: tools/scripts/ttp_collection.sh            (from the repository root, after
#        cargo build --release --bins)
# Env:   WORK (default: a new temp dir), BIN (default target/release),
#        SEED (1), CUT_ARGS (default: the README's layout), KEEP=1 keeps WORK.
# Needs python3 with numpy (pose errors and JSON parsing only).
set -euo pipefail

BIN=${BIN:-target/release}
SEED=${SEED:-1}
CUT_ARGS=${CUT_ARGS:---layout grid --rows 3 --cols 2 --size 300 --overlap 0.6 --max-shift-m 3 --max-shift-z-m 2 --max-rot-deg 0.02}
SRC=fixtures/real/ttp2015/ttp_dsm_source.tif
LAZ=fixtures/real/ttp2015/TTP_15.laz
WORK=${WORK:-$(mktemp -d /tmp/ttp_collection.XXXXXX)}
[ "${KEEP:-0}" = 1 ] || trap 'rm -rf "$WORK"' EXIT
mkdir -p "$WORK"
ds="$BIN/dsmstream"

# shellcheck disable=SC2086
"$BIN/dsmgen" cut "$SRC" $CUT_ARGS --seed "$SEED" --anchor-first --out "$WORK/tiles" >"$WORK/cut.txt"
exec 3>&1 >"$WORK/log.txt"  # command output to the log; the table to stdout (fd 3)
"$ds" ingest "$WORK/tiles" --store "$WORK/c.zarr" -q
for g in full mst; do
  "$ds" align "$WORK/c.zarr" --out "$WORK/$g.json" --graph "$g" --anchor tile_00 -q
done
# pairs before/after and the median-fused surface against the source
"$ds" eval "$WORK/c.zarr" --reference "$SRC" --json >"$WORK/eval_none.json"
for g in full mst; do
  "$ds" eval "$WORK/c.zarr" --poses "$WORK/$g.json" --reference "$SRC" --json >"$WORK/eval_$g.json"
done
# the written fused GeoTIFFs, ingested and checked against the source and the lidar
"$ds" ingest "$SRC" --store "$WORK/src.zarr" -q
"$ds" eval "$WORK/src.zarr" --reference "$LAZ" --json >"$WORK/lidar_source.json"
for g in none full mst; do
  poses=()
  [ "$g" = none ] || poses=(--poses "$WORK/$g.json")
  "$ds" fuse "$WORK/c.zarr" "${poses[@]}" --out "$WORK/fused_$g.tif" -q
  "$ds" ingest "$WORK/fused_$g.tif" --store "$WORK/fused_$g.zarr" -q
  "$ds" eval "$WORK/fused_$g.zarr" --reference "$SRC" --json >"$WORK/fused_src_$g.json"
  "$ds" eval "$WORK/fused_$g.zarr" --reference "$LAZ" --json >"$WORK/fused_lidar_$g.json"
done

python3 - "$WORK" >&3 <<'EOF'
import json, sys
import numpy as np

work = sys.argv[1]
load = lambda name: json.load(open(f"{work}/{name}"))
truth = load("tiles/truth.json")
pivot = truth.get("pivot_z_m", 200.0)
tru = {t["id"]: np.array(t["matrix_world"]) for t in truth["tiles"]}


def pose_errors(poses):
    est = {p["id"]: np.array(p["matrix_world"]) for p in poses["poses"]}
    disp, ang = [], []
    tiles = truth["tiles"]
    for a in range(len(tiles)):
        for tb in tiles[a + 1:]:
            i, j = tiles[a]["id"], tb["id"]
            d = np.linalg.inv(np.linalg.inv(tru[i]) @ tru[j]) @ (np.linalg.inv(est[i]) @ est[j])
            g = tb["geotransform"]
            c = np.array([g[0] + g[1] * tb["width"] / 2, g[3] + g[5] * tb["height"] / 2, pivot, 1.0])
            disp.append(np.linalg.norm((d @ c - c)[:3]))
            ang.append(np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1))))
    return np.mean(disp), np.max(disp), np.max(ang)


print(open(f"{work}/cut.txt").read())
print("pose error vs truth (every pair, relative pose, displacement of the tile centre at the pivot height)")
print("| graph | mean (m) | worst (m) | worst (deg) |")
print("|---|---|---|---|")
for g in ["full", "mst"]:
    m, w, d = pose_errors(load(f"{g}.json"))
    print(f"| {g} | {m:.4f} | {w:.4f} | {d:.5f} |")
print()
print("| poses | pairs rmse_tau (m) | pairs NMAD (m) | fused vs source rmse_tau (m) | NMAD (m) | median (m) | written fused vs source rmse_tau (m) | NMAD (m) | written fused vs lidar rmse_tau (m) | NMAD (m) | median (m) | lidar samples |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for g in ["none", "mst", "full"]:
    e = load(f"eval_{g}.json")
    pairs = e["mean_after"] or e["mean_before"]
    ref = e["reference"]["after"] or e["reference"]["before"]
    fs = load(f"fused_src_{g}.json")["reference"]["before"]
    fl = load(f"fused_lidar_{g}.json")["reference"]["before"]
    print(f"| {g} | {pairs['rmse_tau_m']:.3f} | {pairs['nmad_m']:.3f} | {ref['rmse_tau_m']:.3f} | {ref['nmad_m']:.3f} "
          f"| {ref['median_m']:.3f} | {fs['rmse_tau_m']:.3f} | {fs['nmad_m']:.3f} "
          f"| {fl['rmse_tau_m']:.3f} | {fl['nmad_m']:.3f} | {fl['median_m']:.3f} | {fl['samples']} |")
src = load("lidar_source.json")["reference"]["before"]
print(f"| source DSM itself | | | 0 | 0 | 0 | | | {src['rmse_tau_m']:.3f} | {src['nmad_m']:.3f} | {src['median_m']:.3f} | {src['samples']} |")
print("\ntau = 10 m; rmse_tau, NMAD and median over the inliers (|dh| < tau); lidar: first returns, point to surface")
EOF
echo >&3 "work dir: $WORK$([ "${KEEP:-0}" = 1 ] || echo ' (removed)')"
