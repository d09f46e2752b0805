#!/usr/bin/env python3
"""Frame windows' cost (docs/BENCHMARKS.md "Frame windows"): one epr-master and one epr-worker on
loopback render frames 1-8 of scenes/cornell-flythrough.json as a batch without a window and with
--frame-window K, one run of 8 frames; from the frames' statistics files it prints the bytes of
vertices a tile sends (16 per packed vertex: the worker's culling), the vertices the master
reprojected (each frame's own and its neighbours') and the reprojection thread's seconds per vertex.

    /usr/bin/python3 bench/frame_window_cost.py [--build build] [--k 2] [--size 128] [--spp 32]
"""
import argparse
import glob
import json
import os
import re
import subprocess
import sys
import tempfile
import time


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--k", type=int, default=2)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--frames", default="1-8")
    a = ap.parse_args()
    scene = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes", "cornell-flythrough.json")
    d = tempfile.mkdtemp(prefix="epr-frame-window-")
    master = subprocess.Popen([f"{a.build}/master/epr-master", "--listen", "127.0.0.1:0", "--http", "", "--state-dir",
                               f"{d}/state"], stderr=open(f"{d}/master.err", "w"))
    port = None
    for _ in range(240):
        m = re.search(r"listening on port (\d+)", open(f"{d}/master.err").read())
        if m:
            port = m.group(1)
            break
        time.sleep(0.5)
    if not port:
        sys.exit("epr-master did not start: " + open(f"{d}/master.err").read())
    worker = subprocess.Popen([f"{a.build}/worker/epr-worker", "--master", f"127.0.0.1:{port}", "--threads", "2",
                               "--cache-dir", f"{d}/cache"], stderr=open(f"{d}/worker.err", "w"))
    try:
        for k in (0, a.k):
            subprocess.run([f"{a.build}/client/epr", "submit", scene, "--frames", a.frames, "--frame-window", str(k),
                            "--window-run", "8", "--width", str(a.size), "--height", str(a.size), "--spp",
                            str(a.spp), "--mode", "skip", "--reproject", "cpu", "--master", f"127.0.0.1:{port}",
                            "--wait", "--out", f"{d}/k{k}/f"], check=True, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
    finally:
        worker.terminate()
        master.terminate()
        worker.wait()
        master.wait()
    for k in (0, a.k):
        js = [json.load(open(f)) for f in sorted(glob.glob(f"{d}/k{k}/f.*.json"))]
        s = lambda key: sum(j[key] for j in js)
        reprojected = s("considered") - s("culled_worker")  # what the master's reprojectors were given
        print(f"K={k}: {len(js)} frames, {s('tiles_committed')} tiles, {16 * s('vertices_received') / s('tiles_committed'):.0f} "
              f"bytes of vertices per tile, {s('culled_worker')} culled by the worker, {reprojected} vertices "
              f"reprojected, {s('seconds_reprojecting'):.2f} s reprojecting = "
              f"{1e9 * s('seconds_reprojecting') / max(1, reprojected):.0f} ns per vertex, paths {s('paths_traced')}, "
              f"mean M' {s('mean_reprojected_per_pixel') / len(js):.1f}, mean spp {s('mean_spp') / len(js):.1f}")


if __name__ == "__main__":
    main()
