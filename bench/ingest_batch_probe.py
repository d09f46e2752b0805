#!/usr/bin/env python3
"""Vertices per reprojector call on a master's reprojection thread, counted with uprobes (perf probe,
needs root and tracefs): runs BINARY (ingest_bench, round_bench, epr-master, ...) under `perf record`
with a probe at the entry of CpuReprojector::reproject_packed and GlReprojector::reproject_packed
(the packed call the master makes; its string_view's length is the second argument, %si), then
prints per back-end and thread name the number of calls and the vertices per call (mean, median,
quartiles, largest). The probes cost a few microseconds per call; calls are >= one tile (~15 000
vertices, ~0.5 ms), so the run's timing changes by well under 1 %.

  bench/ingest_batch_probe.py BINARY [BINARY's options...]
  e.g. bench/ingest_batch_probe.py build/bench/ingest_bench --backends cpu --clients 2 --rounds 8 \\
       --batch-records 1048576,0

Calls are grouped by thread name and, for ingest_bench's --batch-records series, split at the
master's restarts (each master's reprojection thread is a new thread id), in the order they ran.
"""
import collections
import os
import re
import statistics as st
import subprocess
import sys
import tempfile

PACKED_BYTES = 16


def symbol_address(binary, cls):
    out = subprocess.run(['nm', binary], capture_output=True, text=True, check=True).stdout
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[1] == 'T' and f'{len(cls)}{cls}16reproject_packed' in parts[2]:
            return '0x' + parts[0].lstrip('0')
    return None


def main():
    binary, args = sys.argv[1], sys.argv[2:]
    group = 'eprbatch%d' % os.getpid()
    events = []
    for cls, event in [('CpuReprojector', 'cpu'), ('GlReprojector', 'gl')]:
        addr = symbol_address(binary, cls)
        if addr is None:
            continue
        subprocess.run(['perf', 'probe', '-q', '-x', binary, '-a', f'{group}:{event}={addr} len=%si:u64'], check=True)
        events.append(f'{group}:{event}')
    try:
        with tempfile.TemporaryDirectory() as tmp:
            data = os.path.join(tmp, 'perf.data')
            cmd = ['perf', 'record', '-q', '-o', data]
            for e in events:
                cmd += ['-e', e]
            subprocess.run(cmd + ['--', binary] + args, check=True)
            script = subprocess.run(['perf', 'script', '-i', data, '-F', 'comm,tid,event,trace'],
                                    capture_output=True, text=True, check=True).stdout
    finally:
        subprocess.run(['perf', 'probe', '-q', '-d', f'{group}:*'], check=False)
    calls = collections.OrderedDict()  # (event, comm, tid) -> vertices per call
    for line in script.splitlines():
        m = re.match(r'\s*(\S.*?)\s+(\d+)\s+\S+:(\w+):.*len=(0x[0-9a-f]+|\d+)', line)
        if not m:
            continue
        comm, tid, event, length = m.group(1), m.group(2), m.group(3), int(m.group(4), 0)
        calls.setdefault((event, comm, tid), []).append(length // PACKED_BYTES)
    print(f'{"back-end":8s} {"thread":16s} {"tid":>8s} {"calls":>7s} {"vertices":>11s} {"mean":>9s} '
          f'{"median":>9s} {"q1":>9s} {"q3":>9s} {"max":>9s}')
    for (event, comm, tid), v in calls.items():
        q = st.quantiles(v, n=4) if len(v) > 1 else [v[0]] * 3
        print(f'{event:8s} {comm:16s} {tid:>8s} {len(v):7d} {sum(v):11d} {sum(v) / len(v):9.0f} '
              f'{st.median(v):9.0f} {q[0]:9.0f} {q[2]:9.0f} {max(v):9d}')


if __name__ == '__main__':
    main()
