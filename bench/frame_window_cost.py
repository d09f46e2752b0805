#!/usr/bin/env python3
"""Frame windows' cost (docs/BENCHMARKS.md section 17): one epr-master and one epr-worker on loopback
render frames of a fly-through as one batch per K (`--frame-window K`, one run of all the frames).

For each K it prints, from the frames' statistics files: the bytes of vertices a tile sends (16 per
packed vertex: the worker's culling), the vertices the master reprojected (each frame's own and its
neighbours') and the reprojection thread's seconds per vertex. And whether reprojection is on the
workers' critical path: the worker's tracing threads' split of their time over the batch (`kill -USR1`
on epr-worker: tracing, leasing -- a lease held at a round barrier --, waiting, submitting -- the
previous tile's submission not done, the master's back-pressure --, other), the CPU seconds of the
master's reprojection thread (`epr-reproject`, from /proc) and its busy share of the batch's wall time.

Then BENCHMARKS.md section 6's model of the worker cores one N-core master keeps busy, extended by the
window: each vertex a worker sends is reprojected into F = reprojected / sent frames (measured), so
V_K(N) = min( N / c_K, 1 / (s + s_n (F - 1) + F r / (eta N)) ), c_K = g + s + s_n (F - 1) + F r / eta,
with section 6's g, s, r, eta and s_n the serial rest of one neighbour's reprojection (0 .. s).

    /usr/bin/python3 bench/frame_window_cost.py [--build build] [--ks 0,2] [--size 128] [--spp 32]
        [--frames 1-8] [--scenes scenes/cornell-flythrough.json,...] [--keep]
"""
import argparse
import glob
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
TICK = os.sysconf("SC_CLK_TCK")
SPLIT = re.compile(r"epr-worker time: threads \d+ tracing ([0-9.]+) leasing ([0-9.]+) waiting ([0-9.]+) "
                   r"submitting ([0-9.]+) other ([0-9.]+)")
ACTIVITIES = ("tracing", "leasing", "waiting", "submitting", "other")

# BENCHMARKS.md section 6: ns per vertex into one frame; r's band is ingest_bench's .. real jobs'.
G, S, ETA, R_BAND = 21.0, 5.0, 0.93, (42.0, 70.0)
# Vertices a worker core sends per second (section 6, rp and skip at 512 x 512).
WORKER_RATE = {"cornell": 2.43e6, "conference": 1.73e6}


def cpu_seconds(path):
    """utime + stime of a /proc stat file."""
    fields = open(path).read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def reprojection_thread_cpu(pid):
    for task in glob.glob(f"/proc/{pid}/task/*"):
        if open(f"{task}/comm").read().strip() == "epr-reproject":
            return cpu_seconds(f"{task}/stat")
    return 0.0


class Farm:
    """epr-master (CPU reprojection) and one epr-worker with two tracing threads, in folder d."""

    def __init__(self, build, d):
        self.build, self.d = build, d
        self.master = subprocess.Popen([f"{build}/master/epr-master", "--listen", "127.0.0.1:0", "--http", "",
                                        "--state-dir", f"{d}/state"], stderr=open(f"{d}/master.err", "w"))
        self.port = None
        for _ in range(240):
            m = re.search(r"listening on port (\d+)", open(f"{d}/master.err").read())
            if m:
                self.port = m.group(1)
                break
            time.sleep(0.5)
        if not self.port:
            self.master.kill()
            sys.exit("epr-master did not start: " + open(f"{d}/master.err").read())
        self.worker = subprocess.Popen([f"{build}/worker/epr-worker", "--master", f"127.0.0.1:{self.port}",
                                        "--threads", "2", "--cache-dir", f"{d}/cache"],
                                       stderr=open(f"{d}/worker.err", "w"))
        # SIGUSR1 before the worker handles it would end it: wait for its registration.
        for _ in range(240):
            if ") registered" in open(f"{d}/master.err").read():
                break
            time.sleep(0.5)
        else:
            self.close()
            sys.exit("epr-worker did not register: " + open(f"{d}/worker.err").read())

    def split(self):
        """The worker's tracing threads' seconds by activity so far (its SIGUSR1 line)."""
        seen = len(SPLIT.findall(open(f"{self.d}/worker.err").read()))
        self.worker.send_signal(signal.SIGUSR1)
        for _ in range(1000):
            lines = SPLIT.findall(open(f"{self.d}/worker.err").read())
            if len(lines) > seen:
                return [float(x) for x in lines[seen]]
            time.sleep(0.01)
        sys.exit("epr-worker printed no time split")

    def close(self):
        for p in (self.worker, self.master):
            p.terminate()
            p.wait()


def render(farm, scene, k, a, out):
    """One batch with window K; its frames' statistics and the measures around it."""
    before = farm.split()
    rt0, m0 = reprojection_thread_cpu(farm.master.pid), cpu_seconds(f"/proc/{farm.master.pid}/stat")
    t0 = time.monotonic()
    subprocess.run([f"{farm.build}/client/epr", "submit", scene, "--frames", a.frames, "--frame-window", str(k),
                    "--window-run", str(a.window_run), "--width", str(a.size), "--height", str(a.size), "--spp",
                    str(a.spp), "--mode", "skip", "--reproject", "cpu", "--master", f"127.0.0.1:{farm.port}",
                    "--wait", "--out", f"{out}/f"], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.monotonic() - t0
    rt = reprojection_thread_cpu(farm.master.pid) - rt0
    mc = cpu_seconds(f"/proc/{farm.master.pid}/stat") - m0
    split = [x - y for x, y in zip(farm.split(), before)]
    js = [json.load(open(f)) for f in sorted(glob.glob(f"{out}/f.*.json"))]
    return {"wall": wall, "reproject_cpu": rt, "master_cpu": mc, "split": split, "frames": js}


def report(k, m):
    js = m["frames"]
    s = lambda key: sum(j[key] for j in js)
    sent = s("vertices_received")
    reprojected = s("considered") - s("culled_worker")  # what the master's reprojectors were given
    print(f"K={k}: {len(js)} frames, {s('tiles_committed')} tiles, {16 * sent / s('tiles_committed'):.0f} "
          f"bytes of vertices per tile, {s('culled_worker')} culled by the worker, {reprojected} vertices "
          f"reprojected, {s('seconds_reprojecting'):.2f} s reprojecting = "
          f"{1e9 * s('seconds_reprojecting') / max(1, reprojected):.0f} ns per vertex, paths {s('paths_traced')}, "
          f"mean M' {s('mean_reprojected_per_pixel') / len(js):.1f}, mean spp {s('mean_spp') / len(js):.1f}")
    total = sum(m["split"])
    shares = ", ".join(f"{a} {100 * x / total:.1f} %" for a, x in zip(ACTIVITIES, m["split"]))
    print(f"      worker threads' time ({total:.1f} thread-s): {shares}")
    print(f"      wall {m['wall']:.1f} s; reprojection thread {m['reproject_cpu']:.2f} CPU-s = "
          f"{100 * m['reproject_cpu'] / m['wall']:.1f} % of the wall, "
          f"{1e9 * m['reproject_cpu'] / max(1, reprojected):.0f} ns per vertex and frame; master {m['master_cpu']:.2f} "
          f"CPU-s = {1e9 * m['master_cpu'] / max(1, sent):.0f} ns per vertex sent; "
          f"reprojections per vertex sent F = {reprojected / max(1, sent):.2f}")
    return reprojected / max(1, sent)


def worker_cores(n, f, r, s_n, rate):
    """Section 6's model with each vertex sent reprojected into f frames: the worker cores an n-core
    master keeps busy, what bounds it (the master's cores, or the reprojection thread: its serial part
    plus its parallel part over n cores), and the thread's serial and parallel ns per vertex sent."""
    serial, parallel = S + s_n * (f - 1), f * r / (ETA * n)
    by_cores, by_thread = n / (G + serial + f * r / ETA), 1 / (serial + parallel)
    return min(by_cores, by_thread) * 1e9 / rate, "thread" if by_thread < by_cores else "cores", serial, parallel


def model(scene_name, fs):
    rate = next((v for key, v in WORKER_RATE.items() if key in scene_name), WORKER_RATE["cornell"])
    print(f"  model, {scene_name} ({rate / 1e6:.2f} M vertices/s per worker core): worker cores one master keeps "
          f"busy over r = {R_BAND[0]:.0f} .. {R_BAND[1]:.0f} ns and s_n = 0 .. {S:.0f} ns, the bound (cores: the "
          f"master's CPU; thread: the reprojection thread), and the thread's ns per vertex sent, serial / parallel")
    for k, f in fs:
        row = []
        for n in (8, 32):
            cells = [worker_cores(n, f, r, s_n, rate) for r in R_BAND for s_n in (0.0, S)]
            lo, hi = min(c[0] for c in cells), max(c[0] for c in cells)
            bounds = "/".join(sorted({c[1] for c in cells}))
            serial = f"{min(c[2] for c in cells):.0f}..{max(c[2] for c in cells):.0f}"
            parallel = f"{min(c[3] for c in cells):.1f}..{max(c[3] for c in cells):.1f}"
            row.append(f"{n}-core {lo:.0f} .. {hi:.0f} ({bounds}; {serial} / {parallel} ns)")
        print(f"    K={k} (F = {f:.2f}): " + "; ".join(row))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default="build")
    ap.add_argument("--ks", default="0,2")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--frames", default="1-8")
    ap.add_argument("--window-run", type=int, default=8)
    ap.add_argument("--model-ks", type=lambda v: [int(k) for k in v.split(",") if k], default=[],
                    help="also model these K with F = 2K + 1 (every vertex into its whole window)")
    ap.add_argument("--keep", action="store_true", help="keep each scene's folder of frames and logs (printed)")
    ap.add_argument("--scenes", default=os.path.join(ROOT, "scenes", "cornell-flythrough.json"))
    a = ap.parse_args()
    ks = [int(k) for k in a.ks.split(",")]
    for scene in a.scenes.split(","):
        name = os.path.basename(scene)
        d = tempfile.mkdtemp(prefix="epr-frame-window-cost-")
        print(f"{name}, frames {a.frames}, {a.size} x {a.size}, {a.spp} spp, load {os.getloadavg()[0]:.1f}")
        farm = Farm(a.build, d)
        try:
            results = [(k, render(farm, scene, k, a, f"{d}/k{k}")) for k in ks]
        finally:
            farm.close()
            if a.keep:
                print(f"  kept in {d}")
            else:
                shutil.rmtree(d, ignore_errors=True)
        fs = [(k, report(k, m)) for k, m in results]
        print(f"  load {os.getloadavg()[0]:.1f}")
        model(name, fs + [(k, 2 * k + 1) for k in a.model_ks])


if __name__ == "__main__":
    main()
