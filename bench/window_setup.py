#!/usr/bin/python3
"""A window run's start (issue 36, docs/BENCHMARKS.md "Frame windows: a run's start"): one batch on a fresh
local farm (bench/frame_window.py's Farm: an epr-master and one epr-worker on loopback), the client polling
every frame's status; prints the seconds from submission to each frame's round 1 (its round 0 closed), the
batch's wall and CPU seconds (client, master, worker), the worker's tracing threads' time by activity
(SIGUSR1: leasing = held in lease calls) and the master's frame-build seconds (statistics files).

    /usr/bin/python3 bench/window_setup.py --build BUILD --scene SCENE --frames 1-12 --window 4 --spp 64
        [--width 160 --height 90 --threads 2 --master-args '...' --out DIR]
"""

import argparse
import json
import os
import re
import shutil
import signal
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.dont_write_bytecode = True
import frame_window as fw  # noqa: E402

# The client: submit_frames, every frame's round 1 by polling, then every frame's statistics.
SUBMIT = """
import json, sys, time
sys.path.insert(0, sys.argv[1])
import eprfarm
a = json.loads(sys.argv[2])
with eprfarm.Client(a.pop("master")) as c:
    out, frames = a.pop("out"), a.pop("frames")
    t0 = time.monotonic()
    batch, ids = c.submit_frames(a.pop("scene"), frames, **a)
    first, left = {}, set(ids)
    while left:
        for job in list(left):
            s = c.status(job)
            if s.round >= 1 or s.state not in ("QUEUED", "RUNNING"):
                first[job] = time.monotonic() - t0
                left.discard(job)
        time.sleep(0.05)
    for job in ids:
        if c.wait(job).state != "DONE":
            sys.exit(f"job {job} ended {c.status(job).state}")
    wall = time.monotonic() - t0
    stats = [c.get(job, out=f"{out}/frame.{i:04d}") for i, job in enumerate(ids)]
    print(json.dumps({"round1": [first[j] for j in ids], "wall": wall}))
"""


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", required=True)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--frames", default="1-12")
    ap.add_argument("--window", type=int, default=4)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--mode", default="skip")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=90)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--master-args", default="")
    ap.add_argument("--out", help="keep the frames' files and logs here")
    a = ap.parse_args()
    a.master, a.worker = (os.path.join(a.build, x, "epr-" + x) for x in ("master", "worker"))
    a.package_dir = os.path.join(a.build, "client", "python")
    folder = tempfile.mkdtemp(prefix="epr-window-setup-")
    out = a.out or os.path.join(folder, "out")
    os.makedirs(out, exist_ok=True)
    farm = fw.Farm(a, folder)
    try:
        job = {"master": farm.address, "out": out, "frames": a.frames, "scene": a.scene, "mode": a.mode,
               "spp": a.spp, "seed": 1, "width": a.width, "height": a.height, "frame_window": a.window}
        farm.run([sys.executable, "-c", SUBMIT, a.package_dir, json.dumps(job)], "submit.log")
        farm.worker[0].send_signal(signal.SIGUSR1)
        time.sleep(1.0)
    finally:
        cpu = farm.stop()
    with open(os.path.join(folder, "submit.log")) as f:
        res = json.loads(f.read().strip().splitlines()[-1])
    with open(os.path.join(folder, "worker.log"), errors="replace") as f:
        split = re.findall(r"epr-worker time: (.*)", f.read())
    builds = []
    for name in sorted(os.listdir(out)):
        if name.endswith(".json"):
            with open(os.path.join(out, name)) as f:
                builds.append(json.load(f).get("seconds_frame_build", 0))
    r1 = res["round1"]
    print(f"round 1 (s from submission): {' '.join(f'{x:.1f}' for x in r1)}; last {max(r1):.1f}")
    print(f"wall {res['wall']:.1f} s; CPU {cpu[0]:.1f} s (master {cpu[1]:.1f}, worker {cpu[2]:.1f})")
    print(f"worker threads: {split[-1] if split else '?'}")
    print(f"frame builds (s): sum {sum(builds):.2f}, max {max(builds or [0]):.2f}")
    if a.out:
        for log in ("master.log", "worker.log", "submit.log"):
            shutil.copy(os.path.join(folder, log), out)
    shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
