#!/usr/bin/env python3
"""Per-thread CPU of a command: runs it under /usr/bin/time -v and samples
the per-thread CPU time of its process from /proc every 0.2 s. Prints the time
figures, CPU seconds per thread and the most threads that gained CPU time
within one sampling interval. Usage: thread_cpu.py dsmstream align ... --threads 1"""
import os, subprocess, sys, time
HZ = os.sysconf('SC_CLK_TCK')
cmd = ['/usr/bin/time', '-v'] + sys.argv[1:]
p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
target = None
last = {}   # tid -> (name, ticks)
max_busy = 0
busy_hist = {}
while p.poll() is None:
    if target is None:
        try:
            kids = open(f'/proc/{p.pid}/task/{p.pid}/children').read().split()
            target = int(kids[0]) if kids else None
        except OSError:
            pass
    if target is not None:
        now = {}
        try:
            for tid in os.listdir(f'/proc/{target}/task'):
                try:
                    s = open(f'/proc/{target}/task/{tid}/stat').read()
                except OSError:
                    continue
                name = s[s.index('(') + 1:s.rindex(')')]
                f = s[s.rindex(')') + 2:].split()
                now[tid] = (name, int(f[11]) + int(f[12]))
        except OSError:
            pass
        busy = sum(1 for t, (n, k) in now.items() if k > last.get(t, (n, 0))[1])
        busy_hist[busy] = busy_hist.get(busy, 0) + 1
        max_busy = max(max_busy, busy)
        last.update(now)
    time.sleep(0.2)
err = p.stderr.read()
keep = ('User time', 'System time', 'Percent of CPU', 'Elapsed (wall', 'Maximum resident', 'Exit status')
for line in err.splitlines():
    if any(k in line for k in keep):
        print(line.strip())
    elif 'error' in line.lower():
        print(line.strip())
threads = sorted(((k / HZ, n, t) for t, (n, k) in last.items()), reverse=True)
print('threads seen:', len(threads))
print('per-thread CPU s:', ', '.join(f'{n}={s:.2f}' for s, n, t in threads if s > 0))
print('max threads gaining CPU within one 0.2 s interval:', max_busy, 'histogram', dict(sorted(busy_hist.items())))
