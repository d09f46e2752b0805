#!/usr/bin/env python3
"""Runs reproject_bench binaries alternately (A, B, A, B, ...) with --cpu-only and prints, per binary,
scene and row, the median over the invocations of the 1-thread and 2-thread figures (each already the
median of --runs runs), their ranges, and the 2/1 ratio. Alternating matters on a shared machine:
another tenant's load then hits every binary alike.

  bench/reproject_threads_compare.py OLD_BINARY,NEW_BINARY REPETITIONS [reproject_bench options...]
  e.g. bench/reproject_threads_compare.py /tmp/old_reproject_bench,build/bench/reproject_bench 5 \\
       --runs 5 --points 2000000
"""
import collections
import re
import statistics as st
import subprocess
import sys

bins = sys.argv[1].split(',')
reps = int(sys.argv[2])
extra = sys.argv[3:]
res = collections.defaultdict(list)
for _ in range(reps):
    for b in bins:
        out = subprocess.run([b, '--cpu-only'] + extra, capture_output=True, text=True, check=True).stdout
        scene = th = None
        for line in out.splitlines():
            m = re.match(r'^(\w+) \(builtin', line)
            if m:
                scene, th = m.group(1), None
            m = re.search(r'cpu \((\d+) TBB thread.*?([\d.]+) M points/s wall,\s+([\d.]+) M points/CPU-s', line)
            if m:
                th = m.group(1)
                res[(b, scene, 'reproject', th)].append(float(m.group(2)))
                res[(b, scene, 'reproject per CPU-s', th)].append(float(m.group(3)))
            m = re.search(r'cpu packed,\s+(\d+)-vertex calls:\s+([\d.]+) M points/s wall', line)
            if m:
                res[(b, scene, 'packed ' + m.group(1), th)].append(float(m.group(2)))
for b in bins:
    for scene in ['cornell', 'hall']:
        for kind in ['reproject', 'reproject per CPU-s', 'packed 1048576', 'packed 15000']:
            k1, k2 = (b, scene, kind, '1'), (b, scene, kind, '2')
            if k1 not in res or k2 not in res:
                continue
            m1, m2 = st.median(res[k1]), st.median(res[k2])
            print(f"{b:40s} {scene:8s} {kind:20s} 1 thread {m1:6.2f} ({min(res[k1]):.1f}-{max(res[k1]):.1f})"
                  f"  2 threads {m2:6.2f} ({min(res[k2]):.1f}-{max(res[k2]):.1f})  2/1 {m2 / m1:.2f}")
