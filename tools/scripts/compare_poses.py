#!/usr/bin/env python3
"""Compare a poses.json with a generator truth.json up to the common gauge.

Prints, per DSM pair (i, j), the disagreement of the relative correction
M_i^-1 M_j with the truth's, as displacement at the tile centres (m) and angle
(deg); then, per DSM, the error after the best rigid gauge G (least squares
over all tile corners, mapping the true corrected corners onto the estimated
ones): T_i^-1 G^-1 E_i at the tile centre. The same figures as
`Truth::pairwise_error` / `Truth::per_dsm_error` in src/synth/score.rs.
Usage: compare_poses.py poses.json truth.json
"""
import json
import sys

import numpy as np


def load(path, key):
    doc = json.load(open(path))
    return {p["id"]: np.array(p["matrix_world"], dtype=float) for p in doc[key]}


def main():
    est = load(sys.argv[1], "poses")
    truth_doc = json.load(open(sys.argv[2]))
    tru = {t["id"]: np.array(t["matrix_world"], dtype=float) for t in truth_doc["tiles"]}
    ids = sorted(tru)
    # test points at the pivot height (dsmgen cut records it; dsmgen tiles: 200 m)
    pivot_z = truth_doc.get("pivot_z_m", 200.0)
    worst_m, worst_deg, rows = 0.0, 0.0, []
    for a in range(len(ids)):
        for b in range(a + 1, len(ids)):
            i, j = ids[a], ids[b]
            rel_e = np.linalg.inv(est[i]) @ est[j]
            rel_t = np.linalg.inv(tru[i]) @ tru[j]
            d = np.linalg.inv(rel_t) @ rel_e
            gt = truth_doc["tiles"][b]["geotransform"]
            w = truth_doc["tiles"][b]["width"]
            c = np.array([gt[0] + gt[1] * w / 2, gt[3] + gt[5] * w / 2, pivot_z, 1.0])
            disp = np.linalg.norm((d @ c - c)[:3])
            ang = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
            rows.append((i, j, disp, ang))
            worst_m, worst_deg = max(worst_m, disp), max(worst_deg, ang)
    for i, j, disp, ang in rows:
        print(f"{i} {j} {disp:8.4f} m {ang:9.5f} deg")
    print(f"worst {worst_m:.4f} m {worst_deg:.5f} deg")
    per_dsm(est, truth_doc, pivot_z)


def centre(t, pivot_z, fx=0.5, fy=0.5):
    gt = t["geotransform"]
    return np.array([gt[0] + gt[1] * t["width"] * fx, gt[3] + gt[5] * t["height"] * fy, pivot_z, 1.0])


def per_dsm(est, truth_doc, pivot_z):
    tiles = [t for t in truth_doc["tiles"] if t["id"] in est]
    src, dst = [], []
    for t in tiles:
        tm, em = np.array(t["matrix_world"], dtype=float), est[t["id"]]
        for fx, fy in [(0, 0), (1, 0), (0, 1), (1, 1)]:
            c = centre(t, pivot_z, fx, fy)
            src.append((tm @ c)[:3])
            dst.append((em @ c)[:3])
    src, dst = np.array(src), np.array(dst)
    ms, md = src.mean(0), dst.mean(0)
    u, _, vt = np.linalg.svd((src - ms).T @ (dst - md))
    r = vt.T @ np.diag([1, 1, np.sign(np.linalg.det(vt.T @ u.T))]) @ u.T
    g = np.eye(4)
    g[:3, :3], g[:3, 3] = r, md - r @ ms
    g_inv = np.linalg.inv(g)
    worst_m, worst_deg = 0.0, 0.0
    for t in tiles:
        d = np.linalg.inv(np.array(t["matrix_world"], dtype=float)) @ g_inv @ est[t["id"]]
        c = centre(t, pivot_z)
        disp = np.linalg.norm((d @ c - c)[:3])
        ang = np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1, 1)))
        print(f"{t['id']} {disp:8.4f} m {ang:9.5f} deg (per DSM)")
        worst_m, worst_deg = max(worst_m, disp), max(worst_deg, ang)
    print(f"per-DSM worst {worst_m:.4f} m {worst_deg:.5f} deg")


if __name__ == "__main__":
    main()
