#!/usr/bin/env python3
"""Pairwise accuracy against known truth, per --samples setting.

Generates tile pairs with `dsmgen tiles --count 2` (city terrain, 0.3 m noise,
spikes, voids, changed buildings), ingests them, runs `dsmstream pair` forward
and inverse at each sample count, and prints a table: worst displacement at the
overlap corners, rotation error, yaw error, the reported one-sigma yaw, and the
wall time per pair.

    python3 tools/scripts/pair_accuracy.py [--bin target/release] [--samples 50000 200000]
        [--cases 1:1024 3:768 ...]   (seed:size; with several sizes, a row per size too)
"""
import argparse, json, subprocess, tempfile, time, os, sys
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from truth_errors import pair_errors

ap = argparse.ArgumentParser()
ap.add_argument("--bin", default="target/release")
ap.add_argument("--samples", type=int, nargs="+", default=[50000, 100000, 200000, 400000])
ap.add_argument("--cases", nargs="+",
                default=["1:1024", "3:768", "4:768", "5:768", "7:2048", "8:2048"],
                help="seed:size pairs")
ap.add_argument("--pair-args", default="", help="extra flags for dsmstream pair, one string")
args = ap.parse_args()
dsmgen, dsm = os.path.join(args.bin, "dsmgen"), os.path.join(args.bin, "dsmstream")

def run(*cmd):
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout

def errors(truth, doc, a, b):
    return pair_errors(truth, doc["result"]["matrix_world"], a, b)

with tempfile.TemporaryDirectory() as tmp:
    stores = []
    for case in args.cases:
        seed, size = case.split(":")
        tiles, store = f"{tmp}/t{seed}", f"{tmp}/s{seed}.zarr"
        run(dsmgen, "tiles", "--count", "2", "--size", size, "--seed", seed, "--out", tiles)
        run(dsm, "ingest", tiles, "--store", store, "-q")
        stores.append((case, json.load(open(f"{tiles}/truth.json")), store))
    print("| samples | tiles | pairs | median / worst error (cm) | median / worst rotation (deg) | median / worst yaw (deg) | mean sigma yaw (deg) | mean s / pair |")
    print("|---|---|---|---|---|---|---|---|")
    for n in args.samples:
        rows = []  # (size, worst, angle, yaw, sigma yaw, seconds)
        for case, truth, store in stores:
            for a, b in ((0, 1), (1, 0)):
                t0 = time.time()
                doc = json.loads(run(dsm, "pair", store, f"tile_0{a}", f"tile_0{b}",
                                     "--json", "--samples", str(n), *args.pair_args.split()))
                secs = time.time() - t0
                rows.append((case.split(":")[1],) + errors(truth, doc, a, b)
                            + (doc["result"]["sigma"]["rot_deg"][2], secs))
        sizes = sorted({row[0] for row in rows}, key=int)
        groups = [("all", rows)] + ([(f"{z} px", [row for row in rows if row[0] == z]) for z in sizes]
                                    if len(sizes) > 1 else [])
        for label, group in groups:
            r = np.array([row[1:] for row in group])
            med, mx = np.median(r, axis=0), r.max(axis=0)
            print(f"| {n} | {label} | {len(group)} | {med[0]*100:.1f} / {mx[0]*100:.1f} "
                  f"| {med[1]:.4f} / {mx[1]:.4f} | {med[2]:.4f} / {mx[2]:.4f} "
                  f"| {r[:,3].mean():.4f} | {r[:,4].mean():.1f} |")
