#!/usr/bin/env python3
"""Pairs that differ between two `dsmgen score --pairs` TSVs of one collection
(two builds or two flag sets): counts by status, converged pairs beyond 3 of
their sigmas, the share of every pair within 3 sigma per axis, and the
changed pairs (largest change of the shift error first).

Usage: pair_diff.py A.tsv B.tsv [N]   (N changed pairs listed, default 30)
"""
import csv, sys
from pair_battery import AXES as AX, number as f


def load(p):
    return {(r['reference'], r['moving']): r for r in csv.DictReader(open(p), delimiter='\t')}


def ratio(r):
    v = [abs(f(r['err_' + a])) / f(r['sigma_' + a]) for a in AX if f(r['sigma_' + a]) > 0]
    return max(v) if v else float('nan')
def err(r): return max(abs(f(r['err_' + a])) for a in 'xyz')
a, b = load(sys.argv[1]), load(sys.argv[2])
changed = [k for k in a if k in b and any(abs(f(a[k]['err_' + x]) - f(b[k]['err_' + x])) > 1e-3 for x in 'xyz')]
print(f'{len(a)} / {len(b)} pairs, {len(changed)} changed')
for name, d in (('A', a), ('B', b)):
    conv = [r for r in d.values() if r['status'] == 'Converged']
    bad = [r for r in conv if ratio(r) > 3]
    within = lambda ax: sum(abs(f(r['err_' + ax])) <= 3 * f(r['sigma_' + ax]) for r in d.values()) / len(d)
    st = {}
    for r in d.values(): st[r['status']] = st.get(r['status'], 0) + 1
    print(name, st, f'converged beyond 3 sigma: {len(bad)}', 'all pairs within 3 sigma x/y/z: ' + ' / '.join(f'{within(x):.4f}' for x in 'xyz'))
changed.sort(key=lambda k: -abs(err(a[k]) - err(b[k])))
up = down = 0
for k in changed:
    ea, eb = err(a[k]), err(b[k])
    if eb < ea - 0.05: up += 1
    if eb > ea + 0.05: down += 1
print(f'better by >5 cm: {up}, worse by >5 cm: {down}')
for k in changed[:int(sys.argv[3]) if len(sys.argv) > 3 else 30]:
    print(f'{k[0]}>{k[1]}  {a[k]["status"]:>11} e{err(a[k]):8.3f} r{ratio(a[k]):7.2f}  ->  {b[k]["status"]:>11} e{err(b[k]):8.3f} r{ratio(b[k]):7.2f}')
