#!/usr/bin/env python3
"""Runs ingest_bench binaries alternately (A, B, A, B, ...) and prints, per binary and table row
(reprojector, batch records where the binary has them, clients), the median over the invocations of
the reprojected rate, the master's CPU per vertex and its parts, with ranges. Alternating matters on
a shared machine: another tenant's load then hits every binary alike. Options after the first two
arguments go to every binary; "NEW:" options only to binaries that understand them (those whose
--help mentions them).

  bench/ingest_compare.py OLD_BINARY,NEW_BINARY REPETITIONS [ingest_bench options...]
  e.g. bench/ingest_compare.py /tmp/old/ingest_bench,build/bench/ingest_bench 3 --rounds 16 \\
       NEW:--batch-records=1048576,0
"""
import collections
import re
import statistics as st
import subprocess
import sys

bins = sys.argv[1].split(',')
reps = int(sys.argv[2])
common = [a for a in sys.argv[3:] if not a.startswith('NEW:')]
new_only = [a[4:] for a in sys.argv[3:] if a.startswith('NEW:')]
helps = {b: subprocess.run([b, '--help'], capture_output=True, text=True).stdout for b in bins}
rows = collections.defaultdict(lambda: collections.defaultdict(list))
threads = collections.defaultdict(lambda: collections.defaultdict(list))
order = []
for _ in range(reps):
    for b in bins:
        extra = [a for a in new_only if a.split('=')[0] in helps[b]]
        out = subprocess.run([b] + common + extra, capture_output=True, text=True, check=True).stdout
        sys.stdout.write(out)
        sys.stdout.flush()
        offline = re.search(r'offline reprojection \(cpu.*?packed ([\d.]+) ns', out)
        for line in out.splitlines():
            # "cpu  1048576   2 |  recv reproj | master ns/vert clients | ... | reproj parse assmbl other | busy waits load"
            m = re.match(r'^(cpu|gl)\s+(?:(\d+)\s+)?(\d+) \|(.*)$', line)
            if m:
                key = (b, m.group(1), m.group(2) or 'per tile (old)', m.group(3))
                if key not in order:
                    order.append(key)
                nums = [float(x.rstrip('%')) for x in re.findall(r'[\d.]+%?', m.group(4))]
                for name, v in zip(['recv', 'reproj M/s', 'master CPU-s', 'ns/vertex', 'clients CPU-s',
                                    'M/master-CPU-s', 'M/CPU-s', 'reproj %', 'parse %', 'assemble %',
                                    'other %', 'rp busy %', 'waits', 'load'], nums):
                    rows[key][name].append(v)
            m = re.match(r'^\s+(cpu|gl), batch (\d+), (\d+) client.*', line)
            if m:
                last = (b, m.group(1), m.group(2), m.group(3))
            m = re.match(r'^\s+master threads, ns/vertex:(.*)$', line)
            if m:
                for name, v in re.findall(r'(\S+) ([\d.]+)', m.group(1)):
                    threads[last][name].append(float(v))


def med(v):
    return f'{st.median(v):.1f} ({min(v):.1f}-{max(v):.1f})'


for key in order:
    r = rows[key]
    b, rp, batch, cli = key
    print(f'{b}  {rp} batch {batch} clients {cli}: reprojected {med(r["reproj M/s"])} M/s, master '
          f'{med(r["ns/vertex"])} ns/vertex, rp busy {med(r["rp busy %"])} %, load {med(r["load"])}')
    if key in threads:
        print('    threads ns/vertex: ' + ', '.join(f'{n} {med(v)}' for n, v in sorted(threads[key].items())))
