#!/usr/bin/python3
"""What several masters cost a Python client's calls: the median time of status, list, submit and
get(as_arrays) through eprfarm.Client on one master and on two (the job's master found by name,
GetMasterInfo of both first), against real epr-master processes on loopback (no worker: the jobs
stay queued, except one rendered job for get, by a worker given both addresses).

    measure_multi_master.py --package-dir BUILD/client/python --epr EPR --master EPR_MASTER \\
        --worker EPR_WORKER [--calls 200]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import test_client as base  # noqa: E402


def median_ms(fn, calls: int) -> float:
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    for flag in ("--package-dir", "--epr", "--master", "--worker"):
        parser.add_argument(flag, required=True)
    parser.add_argument("--calls", type=int, default=200)
    args = parser.parse_args()
    base.ARGS.__dict__.update(vars(args))
    sys.path.insert(0, os.path.abspath(args.package_dir))
    import eprfarm

    tmp = tempfile.mkdtemp(prefix="epr-python-measure-")
    farms = []
    try:
        for name in ("m1", "m2"):
            os.makedirs(os.path.join(tmp, name))
            farms.append(base.Farm(os.path.join(tmp, name), ["--name", name], worker=False))
        addresses = [f.address for f in farms]
        worker = base.Process([args.worker, "--master", ",".join(addresses), "--threads", "2",
                               "--cache-dir", os.path.join(tmp, "cache")], os.path.join(tmp, "worker.log"))
        one, two = eprfarm.Client(addresses[1]), eprfarm.Client(",".join(addresses))
        job = one.submit("builtin:cornell", width=64, height=64, spp=4, mode="pt")  # on m2
        one.wait(job)
        worker.stop()
        for i in range(20):  # queued jobs to list, ten on each master
            eprfarm.Client(addresses[i % 2]).submit("builtin:cornell", width=8, height=8, spp=1, name=f"q{i}")
        small = {"width": 8, "height": 8, "spp": 1, "mode": "pt"}
        rows = [
            ("status(job)", lambda c: c.status(job), args.calls),
            ("list()", lambda c: c.list(), args.calls),
            ("submit(builtin:cornell 8x8)", lambda c: c.submit("builtin:cornell", **small), args.calls),
            ("get(job, as_arrays=True) 64x64", lambda c: c.get(job, as_arrays=True), max(1, args.calls // 4)),
        ]
        print(f"| call | one master (ms) | two masters (ms) | ratio |  (medians of {args.calls} calls)")
        print("|---|---|---|---|")
        for what, fn, calls in rows:
            fn(one), fn(two)  # warm: connections made, modules imported
            a, b = median_ms(lambda: fn(one), calls), median_ms(lambda: fn(two), calls)
            print(f"| {what} | {a:.2f} | {b:.2f} | {b / a:.2f} |")
        one.close()
        two.close()
    finally:
        for f in farms:
            f.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
