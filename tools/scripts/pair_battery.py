#!/usr/bin/env python3
"""A battery of small generated collections at default flags, drawn at random
(deterministic per case number), to find pairs that fail silently: converged,
yet beyond three of their own sigmas.

Each case is `dsmgen tiles` (a chain of 2 or a 2 x 2 grid) with a random
ground sample distance, tile size, overlap, rendering, per-tile offsets,
vertical datum offset, relief, buildings, lakes, water and noise; then
`dsmstream ingest`, `dsmstream align` (defaults) and `dsmgen score --pairs`.
One line per case on stdout (tab-separated): the settings, `BAD r` when a
converged pair's largest |error| / sigma (x, y, z, roll, pitch, yaw) is above
3 (else `ok r`), then each pair as reference>moving:status:e<largest shift
error, m>:r<largest ratio>, and the per-DSM line of `dsmgen score`.

Usage: pair_battery.py BIN_DIR FIRST COUNT [--narrow] [--odd-gsd-factor K] [--work DIR]
  BIN_DIR  holds dsmstream and dsmgen
  --narrow overlaps of 0.15-0.3, 0.5-2 m pixels, offsets of 20 or 50 m per
           tile and axis (the cases the search radius cut to half the overlap
           missed); default: the general mix (also 30 m DSMs, offsets up to
           1 km, datum offsets up to 300 m)
  --odd-gsd-factor K  every tile with odd row + col written at K times the
           pixel over the same footprint (mixed resolutions); the cases'
           other draws are those without it, so the two runs compare case by
           case
"""
import argparse
import csv
import os
import random
import subprocess

AXES = ['x', 'y', 'z', 'roll', 'pitch', 'yaw']


def settings(k, narrow):
    r = random.Random(1000 + k if narrow else k)
    if narrow:
        gsd = r.choice([0.5, 1.0, 2.0])
    else:
        gsd = r.choice([0.5, 0.5, 1.0, 2.0, 30.0])
    size = r.choice([256, 512, 1024])
    ov = r.choice([0.15, 0.2, 0.25, 0.3] if narrow else [0.15, 0.25, 0.4, 0.6])
    render = r.choice(['centre', 'lidar-max', 'lidar-mean', 'tin', 'idw', 'smooth'])
    if gsd < 30:
        shift = r.choice([20, 50] if narrow else [3, 3, 20, 50])
        dz = r.choice([0, 0, 0, 150])
    else:
        shift = r.choice([100, 500, 1000])
        dz = r.choice([0, 300])
    relief = r.choice([1, 1, 0.3])
    buildings = r.choice([0.55, 0.55, 0.1, 0.0])
    lakes = r.choice([0.2, 0.2, 0.5])
    water = r.choice(['nan', 'flat'])
    noise = r.choice([0.3, 0.3, 1.0]) if gsd < 30 else r.choice([1.0, 3.0])
    layout = r.choice(['chain', 'chain', 'grid'])
    seed = r.randrange(1, 10000)
    return dict(layout=layout, gsd=gsd, size=size, overlap=ov, render=render,
                shift=shift, dz=dz, relief=relief, buildings=buildings,
                lakes=lakes, water=water, noise=noise, seed=seed)


def number(text):
    try:
        return float(text)
    except ValueError:
        return float('nan')


def run_case(bin_dir, work, k, s, factor=1):
    d = os.path.join(work, f'case{k}')
    subprocess.run(['rm', '-rf', d], check=True)
    os.makedirs(d)
    layout = (['--layout', 'chain', '--count', '2'] if s['layout'] == 'chain'
              else ['--layout', 'grid', '--rows', '2', '--cols', '2'])
    gen = [f'{bin_dir}/dsmgen', 'tiles', *layout, '--size', str(s['size']),
           '--gsd', str(s['gsd']), '--overlap', str(s['overlap']),
           '--render', s['render'], '--max-shift-m', str(s['shift']),
           '--dz-offset', str(s['dz']), '--relief', str(s['relief']),
           '--buildings', str(s['buildings']), '--lakes', str(s['lakes']),
           '--water', s['water'], '--noise', str(s['noise']),
           '--seed', str(s['seed']), '--out', f'{d}/tiles']
    if factor != 1:
        gen += ['--odd-gsd-factor', str(factor)]
    label = f'k={k} ' + ' '.join(f'{a}={b}' for a, b in s.items())
    if factor != 1:
        label += f' odd_gsd_factor={factor}'
    g = subprocess.run(gen, capture_output=True, text=True)
    if g.returncode:
        return f'{label}\tGENERATE_EXIT {g.returncode}\t{g.stderr.strip()[-200:]}'
    subprocess.run([f'{bin_dir}/dsmstream', 'ingest', f'{d}/tiles', '--store',
                    f'{d}/c.zarr', '-q'], capture_output=True, check=True)
    a = subprocess.run([f'{bin_dir}/dsmstream', 'align', f'{d}/c.zarr', '--out',
                        f'{d}/p.json', '-q'], capture_output=True, text=True)
    if a.returncode:
        return f'{label}\tALIGN_EXIT {a.returncode}\t{a.stderr.strip()[-300:]}'
    sc = subprocess.run([f'{bin_dir}/dsmgen', 'score', '--truth', f'{d}/tiles/truth.json',
                         '--poses', f'{d}/p.json', '--pairs', f'{d}/pairs.tsv'],
                        capture_output=True, text=True, check=True)
    worst = 0.0
    pairs = []
    for row in csv.DictReader(open(f'{d}/pairs.tsv'), delimiter='\t'):
        ratios = [abs(number(row['err_' + x])) / number(row['sigma_' + x]) for x in AXES
                  if number(row['sigma_' + x]) > 0]
        ratio = max(ratios) if ratios else float('nan')
        shift = max(abs(number(row['err_' + x])) for x in 'xyz')
        pairs.append(f"{row['reference']}>{row['moving']}:{row['status']}:e{shift:.3f}:r{ratio:.2f}")
        if row['status'] == 'Converged' and ratio == ratio:
            worst = max(worst, ratio)
    per_dsm = [line for line in sc.stdout.splitlines() if line.startswith('per DSM (')]
    flag = 'BAD' if worst > 3 else 'ok'
    return f'{label}\t{flag} {worst:.2f}\t{" ".join(pairs)} | {" ".join(per_dsm)}'


def main():
    p = argparse.ArgumentParser()
    p.add_argument('bin_dir')
    p.add_argument('first', type=int)
    p.add_argument('count', type=int)
    p.add_argument('--narrow', action='store_true')
    p.add_argument('--odd-gsd-factor', type=int, default=1)
    p.add_argument('--work', default='/tmp/pair_battery')
    args = p.parse_args()
    for k in range(args.first, args.first + args.count):
        s = settings(k, args.narrow)
        print(run_case(args.bin_dir, args.work, k, s, args.odd_gsd_factor), flush=True)


if __name__ == '__main__':
    main()
