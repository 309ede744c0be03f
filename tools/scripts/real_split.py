#!/usr/bin/env python3
"""Pairs of real, independently gridded DSMs with a known answer: one lidar
cloud split at random into two halves of its points, each half moved by its
own known motion and gridded (highest or mean return per cell, on lattices a
random fraction of a pixel apart) into two overlapping DSMs; then
`dsmstream pair` at default flags and its answer against the truth, in units
of its own sigmas.

This is the check the generated collections cannot give: the surface, its
roughness, vegetation, voids and point pattern are real (CODEM's lidar,
fixtures/real/codem/pc.laz, 1.8 returns per m^2; each half has 0.9), and the
two DSMs share no point. What is assumed: both halves sample the same surface
(one survey), so the truth of the pair is the relative motion applied here.

Each case draws (deterministic per case number): the cell size (1 or 2 m),
the cell statistic (max or mean), the overlap width (30-120 m) and its
direction (a split along x or along y), each DSM's motion (shift up to 10 m
per axis, yaw up to 0.1 deg, height offset of 0, 1.5 or 30 m) and its
lattice offset. One line per case (tab-separated): the draws, the pair's
status, its error at the fit's centre (x, y, z metres; roll, pitch, yaw
degrees), its sigmas, and the largest |error| / sigma.

Usage: real_split.py BIN_DIR FIRST COUNT [--points LAS] [--work DIR]
"""
import argparse
import json
import math
import os
import random
import subprocess

import numpy as np

AXES = ['x', 'y', 'z', 'roll', 'pitch', 'yaw']


def motion(yaw_deg, shift, dz, centre):
    """The 4x4 motion dsmgen grid applies: turn about `centre`, then shift
    (and `dz` added to heights)."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    cen = np.array([centre[0], centre[1], 0.0])
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = cen - r @ cen + np.array([shift[0], shift[1], dz])
    return m


def settings(k):
    r = random.Random(7000 + k)
    return dict(
        gsd=r.choice([1.0, 2.0]),
        stat=r.choice(['max', 'mean']),
        width=r.choice([30, 60, 90, 120]),
        along=r.choice(['x', 'y']),
        motions=[dict(shift=[r.uniform(-10, 10), r.uniform(-10, 10)],
                      yaw=r.uniform(-0.1, 0.1), dz=r.choice([0.0, 1.5, 30.0]),
                      lattice=[r.random(), r.random()]) for _ in range(2)],
    )


def windows(s, bounds):
    """The two DSMs' windows (xmin ymin xmax ymax), overlapping by `width`
    across the middle of the cloud's bounds, kept clear of its edges by the
    largest shift."""
    x0, y0, x1, y1 = bounds
    x0, y0, x1, y1 = x0 + 12, y0 + 12, x1 - 12, y1 - 12
    half = s['width'] / 2
    if s['along'] == 'x':
        mid = (x0 + x1) / 2
        return [[x0, y0, mid + half, y1], [mid - half, y0, x1, y1]]
    mid = (y0 + y1) / 2
    return [[x0, mid - half, x1, y1], [x0, y0, x1, mid + half]]


def run_case(k, args, bounds):
    s = settings(k)
    work = os.path.join(args.work, f'case{k}')
    os.makedirs(work, exist_ok=True)
    truth = []
    for i, (win, m) in enumerate(zip(windows(s, bounds), s['motions'])):
        # the lattice starts a random fraction of a cell off the window's corner
        w = [win[0] + m['lattice'][0] * s['gsd'], win[1], win[2],
             win[3] - m['lattice'][1] * s['gsd']]
        centre = [(w[0] + w[2]) / 2, (w[1] + w[3]) / 2]
        subprocess.run([os.path.join(args.bin, 'dsmgen'), 'grid', '--points', args.points,
                        '--gsd', str(s['gsd']), '--stat', s['stat'], '--subset', f'{i}/2',
                        '--shift', f"{m['shift'][0]:.6f}", f"{m['shift'][1]:.6f}",
                        f"--yaw-deg={m['yaw']:.8f}", '--dz', str(m['dz']),
                        '--window', *(f'{v:.6f}' for v in w), '--out', os.path.join(work, f'd{i}.tif')],
                       check=True, capture_output=True)
        truth.append(motion(m['yaw'], m['shift'], m['dz'], centre))
    store = os.path.join(work, 's.zarr')
    subprocess.run([os.path.join(args.bin, 'dsmstream'), 'ingest', '--store', store, '--force',
                    '-q', os.path.join(work, 'd0.tif'), os.path.join(work, 'd1.tif')],
                   check=True, capture_output=True)
    out = subprocess.run([os.path.join(args.bin, 'dsmstream'), 'pair', store, 'd0', 'd1',
                          '--json'], capture_output=True, text=True)
    if not out.stdout.strip():
        return s, dict(status='error: ' + out.stderr.strip().splitlines()[-1])
    doc = json.loads(out.stdout)
    # p_ref = M p_moving; the truth maps d1's points back to d0's frame:
    # T0 T1^-1 (each DSM's points were moved by its own motion).
    want = truth[0] @ np.linalg.inv(truth[1])
    got = np.array(doc['matrix_world'])
    d = np.linalg.inv(want) @ got
    c = np.append(np.array(doc['centre_m']), 1.0)
    shift_err = (d @ c - c)[:3]
    rot = d[:3, :3]
    # small angles: roll about x, pitch about y, yaw about z
    rot_err = np.degrees([rot[2, 1], rot[0, 2], rot[1, 0]])
    err = list(shift_err) + list(rot_err)
    sig = doc['sigma']['shift_m'] + doc['sigma']['rotation_deg']
    held = set(doc.get('degenerate') or [])
    ratios = [abs(e) / sg if sg and sg > 0 and AXES[i] not in held else float('nan')
              for i, (e, sg) in enumerate(zip(err, sig))]
    return s, dict(status=doc['status'], err=err, sigma=sig, ratios=ratios,
                   inliers=doc['result']['inliers'], samples=doc['result']['samples'])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('bin')
    ap.add_argument('first', type=int)
    ap.add_argument('count', type=int)
    ap.add_argument('--points', default=os.path.join(os.path.dirname(__file__), '..', '..',
                                                     'fixtures', 'real', 'codem', 'pc.laz'))
    ap.add_argument('--bounds', type=float, nargs=4, default=[626997, 4323537, 627311, 4323936],
                    help='the cloud\'s bounds (xmin ymin xmax ymax)')
    ap.add_argument('--work', default='/tmp/real_split')
    args = ap.parse_args()
    for k in range(args.first, args.first + args.count):
        s, r = run_case(k, args, args.bounds)
        head = (f"{k}\tgsd {s['gsd']:g} {s['stat']} overlap {s['width']} m along {s['along']}"
                f"\tdz {s['motions'][0]['dz']:g}/{s['motions'][1]['dz']:g}")
        if 'err' not in r:
            print(f"{head}\t{r['status']}", flush=True)
            continue
        worst = max((x for x in r['ratios'] if x == x), default=float('nan'))
        e = ' '.join(f'{v:+.3f}' for v in r['err'][:3]) + ' m ' + \
            ' '.join(f'{v:+.4f}' for v in r['err'][3:]) + ' deg'
        fmt = lambda v, f: 'held' if v is None else format(v, f)
        sg = ' '.join(fmt(v, '.3f') for v in r['sigma'][:3]) + ' m ' + \
            ' '.join(fmt(v, '.4f') for v in r['sigma'][3:]) + ' deg'
        rt = ' '.join(f'{v:.2f}' for v in r['ratios'])
        print(f"{head}\t{r['status']}\terr {e}\tsigma {sg}\tratio {rt}\tworst {worst:.2f}"
              f"\tinliers {r['inliers']}/{r['samples']}", flush=True)


if __name__ == '__main__':
    main()
