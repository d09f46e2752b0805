#!/usr/bin/python3
"""Frame windows (issue 36) on a camera fly-through: per-frame error against the CPU seconds of a whole
local farm, for independent frames (skip, K = 0), the plain path tracer and frame windows K = 1, 2, 4, 8
(docs/BENCHMARKS.md and docs/RESULTS.md, "Frame windows").

    /usr/bin/python3 bench/frame_window.py --build BUILD --out OUT --refs REFS
        [--scene scenes/conference-flythrough.json --frames 1-12 --width 160 --height 90]
        [--spp 4,8,16,32 --ref-spp 1024 --windows 1,2,4,8 --rr albedo]
        [--variants scenes/conference-cut.json:19-30,scenes/conference-fast.json:1-12] [--strip docs/x.png]
        [--master-args '--window-cut-share 0']

Every render is one batch on a fresh local farm, an epr-master (loopback, its own --state-dir) and
one epr-worker (--threads, default 2), submitted by the eprfarm Python client of the build
(BUILD/client/python: submit_frames, then each frame's files); its CPU seconds are those of the three
processes while the batch runs (user + system: the client's from wait4, the master's and worker's
from /proc from once their start-up has settled, as on a farm whose processes outlive the batch;
loading the batch's scene is counted). Configurations: `pt` (mode pt, roulette --rr, the best plain
path tracer), `skip` (mode skip, the master's default roulette, every frame alone) and `kN` (skip
with frame_window=N: runs of at most 16 consecutive frames, each frame's seed 1 plus its number).

References: per frame, --ref-spp paths per pixel of --mode pt as two batches of half as many (seeds
1000001 and 1000002), cached in REFS/STEM_WxH_FRAMES_REFSPP/ (made once, reused while the scene file
is the same: its SHA-256 is kept beside them). (a - b)^2 / 4 estimates the reference's own variance
per pixel, which is subtracted from every error, as bench/garden_error_time.py does.

Error of a frame: relative MSE, the mean over pixels and channels of (x - r)^2 / (r^2 + 0.01), full
and trimmed (the 1 % largest per-pixel terms left out); a batch's error is the mean over its frames.
Ratios against a baseline curve (log-log interpolation between its points; none outside its range):
error at equal CPU (x's error / the baseline's error at x's CPU seconds) and CPU at equal error
(x's CPU / the baseline's CPU at x's error). Variants (a cut between shots, fast motion) repeat the
skip and window runs; the cost of a variant is its window's gain over skip against the main scene's.
Writes OUT/csv/TAG_CONFIG.csv (spp, cpu_s, rel_mse, rel_mse_trim, worst frame), OUT/csv/TAG_CONFIG_frames.csv
(per spp and frame: its errors, the frames that fed it and its view's share with the next frame's,
from its statistics file; DESIGN.md "Frame windows"), OUT/summary.md, with
--charts DIR the error-against-CPU charts and with --strip PNG a strip of frames.
"""

import argparse
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
import OpenImageIO as oiio

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.dont_write_bytecode = True
import garden_error_time as garden  # noqa: E402  (read: an EXR's RGB; errors: relMSE full and trimmed 1 %)

ROOT = garden.ROOT
read = garden.read


def parse_frames(text):
    out = []
    for part in text.split(","):
        m = re.fullmatch(r"(\d+)(?:-(\d+)(?:x(\d+))?)?", part)
        if not m:
            raise SystemExit(f"--frames: '{part}' is not A, A-B or A-BxS")
        a, b, s = int(m[1]), int(m[2] or m[1]), int(m[3] or 1)
        out += range(a, b + 1, s)
    return sorted(set(out))


def process_cpu(pid):
    """User + system CPU seconds of a running process, all its threads (/proc/PID/stat)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Farm:
    """An epr-master and an epr-worker on loopback for one batch; cpu() after stop(): their CPU seconds."""

    def __init__(self, a, folder):
        self.folder, self.seconds, self.parts = folder, 0.0, [0.0, 0.0]
        os.makedirs(folder, exist_ok=True)
        self.master = self._start([a.master, "--listen", "127.0.0.1:0", "--http", "127.0.0.1:0", "--state-dir",
                                  os.path.join(folder, "state")] + a.master_args.split(),
                                  "master.log")  # fmt: skip
        end = time.monotonic() + 120
        while not (m := re.search(r"listening on port ([0-9]+)", self._log("master.log"))):
            if time.monotonic() > end or self.master[0].poll() is not None:
                raise SystemExit(f"epr-master did not start: see {folder}/master.log")
            time.sleep(0.1)
        self.address = f"127.0.0.1:{m[1]}"
        self.worker = self._start([a.worker, "--master", self.address, "--threads", str(a.threads), "--cache-dir",
                                   os.path.join(folder, "cache")], "worker.log")  # fmt: skip

    def _start(self, argv, log):
        f = open(os.path.join(self.folder, log), "wb")
        return subprocess.Popen(argv, stdout=f, stderr=subprocess.STDOUT), f

    def _log(self, log):
        with open(os.path.join(self.folder, log), "rb") as f:
            return f.read().decode(errors="replace")

    def _servers_cpu(self):
        return [process_cpu(p.pid) for p, _ in (self.master, self.worker)]

    def run(self, argv, log):
        """Runs a client command to its end; its CPU seconds and the master's and worker's meanwhile
        (from once their start-up has settled: a farm's processes outlive its jobs)."""
        before, end = None, time.monotonic() + 20
        while (now := self._servers_cpu()) != before and time.monotonic() < end:
            before = now
            time.sleep(0.5)
        p, f = self._start(argv, log)
        status = self._reap(p, f)
        spent = [x - y for x, y in zip(self._servers_cpu(), before)]
        self.parts = [x + y for x, y in zip(self.parts, spent)]
        self.seconds += sum(spent)
        if status != 0:
            raise SystemExit(f"{' '.join(argv)} failed ({status}): see {self.folder}/{log}")

    def _reap(self, p, f):
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        f.close()
        self.seconds += usage.ru_utime + usage.ru_stime
        return p.returncode

    def stop(self):
        """Stops the master and the worker; the CPU seconds of the batch run(): all, the master's, the worker's."""
        batch = (self.seconds, *self.parts)
        for p, f in (self.worker, self.master):
            p.send_signal(signal.SIGTERM)
            self._reap(p, f)
        return batch


# The client: the eprfarm package's submit_frames (frame windows included), then every frame's files.
SUBMIT = """
import json, sys
sys.path.insert(0, sys.argv[1])
import eprfarm
a = json.loads(sys.argv[2])
with eprfarm.Client(a.pop("master")) as c:
    prefix, frames = a.pop("prefix"), a.pop("frames")
    batch, ids = c.submit_frames(a.pop("scene"), frames, **a)
    for frame, job in zip(eprfarm.frames.parse_frames(frames), ids):
        if c.wait(job).state != "DONE":
            sys.exit(f"frame {frame}: job {job} ended {c.status(job).state}")
        c.get(job, out=f"{prefix}.{frame:04d}")
"""


def render(a, scene, frames, mode, spp, seed, prefix, window=0, rr=None, extra=None):
    """One batch on a fresh farm: the frames' images as PREFIX.NNNN.exr, and the farm's CPU seconds (all, the
    master's, the worker's). `extra`: more submit_frames options."""
    folder = tempfile.mkdtemp(prefix="epr-frame-window-", dir=a.tmp)
    farm = Farm(a, folder)
    try:
        job = {"master": farm.address, "prefix": prefix, "frames": frames, "scene": scene, "mode": mode, "spp": spp,
               "seed": seed, "width": a.width, "height": a.height, "rr": rr}  # fmt: skip
        if window:
            job["frame_window"] = window
        job.update(extra or {})
        farm.run([sys.executable, "-c", SUBMIT, a.package_dir, json.dumps(job)], "submit.log")
    finally:
        cpu = farm.stop()
    shutil.rmtree(folder, ignore_errors=True)
    return cpu


def references(a, scene, frames_text, frames):
    """The per-frame references (mean of the two halves) and the floor (their noise per pixel term)."""
    stem = os.path.splitext(os.path.basename(scene))[0]
    folder = os.path.join(a.refs, f"{stem}_{a.width}x{a.height}_{frames_text.replace(',', '+')}_{a.ref_spp}")
    digest = hashlib.sha256(open(scene, "rb").read()).hexdigest()
    stamp = os.path.join(folder, "scene.sha256")
    if not (os.path.exists(stamp) and open(stamp).read().strip() == digest):
        shutil.rmtree(folder, ignore_errors=True)
        os.makedirs(folder)
        cpu = sum(render(a, scene, frames_text, "pt", a.ref_spp // 2, s, os.path.join(folder, f"h{s}"), rr=a.rr)[0]
                  for s in (1000001, 1000002))  # fmt: skip
        with open(os.path.join(folder, "cpu_s"), "w") as f:
            f.write(f"{cpu:.1f}\n")
        with open(stamp, "w") as f:
            f.write(digest + "\n")
    refs = []
    for frame in frames:
        ha, hb = (read(os.path.join(folder, f"h{s}.{frame:04d}.exr")) for s in (1000001, 1000002))
        ref = (ha + hb) / 2
        refs.append((ref, ((ha - hb) ** 2 / 4 / (ref**2 + 0.01)).mean(axis=2).ravel()))
    return refs, folder


def errors(prefix, frames, refs, per_frame=None):
    """Mean over frames of relMSE (full, trimmed), and the worst frame's trimmed one. `per_frame`, a
    list: gets (frame, relMSE, trimmed, fed_by_first, fed_by_last, view_share_next) of each frame
    (the window fields from its statistics file, empty without a window)."""
    full, trim = [], []
    for frame, (ref, floor) in zip(frames, refs):
        e = garden.errors(read(f"{prefix}.{frame:04d}.exr"), ref, floor)
        full.append(e[0])
        trim.append(e[1])
        if per_frame is not None:
            with open(f"{prefix}.{frame:04d}.json") as f:
                w = json.load(f).get("frame_window", {})
            share = w.get("view_share_next")
            per_frame.append((frame, e[0], e[1], w.get("fed_by_first", ""), w.get("fed_by_last", ""),
                              "" if share is None else f"{share:.3f}"))  # fmt: skip
    return float(np.mean(full)), float(np.mean(trim)), float(np.max(trim))


def interp(xs, ys, x):
    """ys at x on the log-log polyline through (xs, ys), sorted by xs; None outside."""
    pts = sorted(zip(xs, ys))
    for (x0, y0), (x1, y1) in zip(pts, pts[1:]):
        if x0 <= x <= x1 and x0 > 0 and x1 > 0 and y0 > 0 and y1 > 0:
            t = 0 if x1 == x0 else (np.log(x) - np.log(x0)) / (np.log(x1) - np.log(x0))
            return float(np.exp(np.log(y0) + t * (np.log(y1) - np.log(y0))))
    return None


def ratios(rows, base, col=3):
    """Median over rows' points of (error at equal CPU, CPU at equal error) against `base`; the error
    in column `col` (2: relMSE, 3: trimmed)."""
    cpu_b, err_b = [r[1] for r in base], [r[col] for r in base]
    at_cpu = [r[col] / e for r in rows if (e := interp(cpu_b, err_b, r[1]))]
    at_err = [r[1] / c for r in rows if (c := interp(err_b, cpu_b, r[col]))]
    med = lambda v: float(np.median(v)) if v else None  # noqa: E731
    return med(at_cpu), med(at_err)


def number(text):
    """An option's value: an int, a float or the text."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def fmt(x):
    return "—" if x is None else f"{x:.2f}"


def sweep(a, scene, frames_text, configs, tag):
    frames = parse_frames(frames_text)
    out = {}
    if a.from_csv:
        for name, *_ in configs:
            with open(os.path.join(a.out, "csv", f"{tag}_{name}.csv")) as f:
                out[name] = [(int(r[0]), *map(float, r[1:])) for r in (line.split(",") for line in f.readlines()[1:])]
        return out, "(as measured)"
    refs, ref_folder = references(a, scene, frames_text, frames)
    for name, mode, window, rr, *extra in configs:
        rows, per_frame = [], []
        for spp in a.spp:
            prefix = os.path.join(a.out, "img", tag, f"{name}_{spp}", "f")
            os.makedirs(os.path.dirname(prefix), exist_ok=True)
            cpu, *parts = render(a, scene, frames_text, mode, spp, 1, prefix, window, rr, *extra)
            frame_rows = []
            rows.append((spp, cpu, *errors(prefix, frames, refs, frame_rows), *parts))
            per_frame += [(spp, *r) for r in frame_rows]
            print(f"{tag} {name} spp {spp}: {cpu:.1f} CPU-s, relMSE {rows[-1][2]:.4g}, trimmed {rows[-1][3]:.4g}",
                  flush=True)  # fmt: skip
        out[name] = rows
        with open(os.path.join(a.out, "csv", f"{tag}_{name}.csv"), "w") as f:
            f.write("spp,cpu_s,rel_mse,rel_mse_trim,worst_frame_trim,master_cpu_s,worker_cpu_s\n")
            for r in rows:
                f.write("%d,%.3f,%.6g,%.6g,%.6g,%.3f,%.3f\n" % r)
        with open(os.path.join(a.out, "csv", f"{tag}_{name}_frames.csv"), "w") as f:
            f.write("spp,frame,rel_mse,rel_mse_trim,fed_by_first,fed_by_last,view_share_next\n")
            for r in per_frame:
                f.write("%d,%d,%.6g,%.6g,%s,%s,%s\n" % r)
    return out, ref_folder


def table(results, tag, frames_text):
    lines = [f"### {tag}, frames {frames_text}\n",
             "| config | " + " | ".join(f"spp {s}: CPU-s / relMSE / trimmed" for s in [r[0] for r in
                                         next(iter(results.values()))]) + " |",  # fmt: skip
             "|---|" + "---|" * len(next(iter(results.values())))]
    for name, rows in results.items():
        lines.append(f"| {name} | " + " | ".join(f"{r[1]:.1f} / {r[2]:.4g} / {r[3]:.4g}" for r in rows) + " |")
    lines += ["", "Ratios (median over the sample counts; relMSE, then trimmed):", "",
              "| config | error at equal CPU vs skip | CPU at equal error vs skip | error at equal CPU vs pt "
              "| CPU at equal error vs pt |", "|---|---|---|---|---|"]  # fmt: skip
    for name, rows in results.items():
        cells = []
        for base in ("skip", "pt"):
            both = [ratios(rows, results[base], col) if base in results else (None, None) for col in (2, 3)]
            cells += [f"{fmt(both[0][i])} / {fmt(both[1][i])}" for i in (0, 1)]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def charts(a, tag, names):
    os.makedirs(a.charts, exist_ok=True)
    csv = os.path.join(a.out, "csv")
    for ycol, what in ((4, "trimmed 1 %"), (3, "all pixels")):
        out = os.path.join(a.charts, f"frame_window_{tag}" + ("" if ycol == 4 else "_full"))
        plots = ", ".join(f"'{csv}/{tag}_{n}.csv' using 2:{ycol} with linespoints pt 7 ps 0.5 lw 1.5 title '{n}'"
                          for n in names)  # fmt: skip
        script = (f"set datafile separator ','; set logscale xy; set key top right; set grid; "
                  f"set xlabel 'CPU seconds of the farm (client, master, worker)'; "
                  f"set ylabel 'relative MSE per frame ({what}, reference noise subtracted)'; "
                  f"set title '{tag}' noenhanced; set terminal pngcairo size 720,480 font 'DejaVu Sans,10'; "
                  f"set output '{out}.png'; plot {plots}")  # fmt: skip
        subprocess.run(["gnuplot", "-e", script], check=True)


def strip(a, tag, frames, config, spp, ref_folder, path, count=6):
    """`count` frames spread over the batch: the reference above, `config` at `spp` below (sRGB PNGs)."""
    picks = [frames[round(i * (len(frames) - 1) / (count - 1))] for i in range(count)]
    rows = []
    for folder, name in ((ref_folder, "h1000001"), (os.path.join(a.out, "img", tag, f"{config}_{spp}"), "f")):
        row = [oiio.ImageBuf(os.path.join(folder, f"{name}.{f:04d}.png")).get_pixels(oiio.UINT8) for f in picks]
        rows.append(np.concatenate(row, axis=1))
    image = np.concatenate(rows, axis=0)
    out = oiio.ImageBuf(oiio.ImageSpec(image.shape[1], image.shape[0], image.shape[2], oiio.UINT8))
    out.set_pixels(oiio.ROI(), image)
    if not out.write(path):
        raise SystemExit(f"cannot write {path}: {out.geterror()}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", required=True,
                    help="the build folder (client/python, master/epr-master, worker/epr-worker)")  # fmt: skip
    ap.add_argument("--out", required=True)
    ap.add_argument("--refs", required=True, help="folder caching the per-frame references")
    ap.add_argument("--scene", default=os.path.join(ROOT, "scenes", "conference-flythrough.json"))
    ap.add_argument("--frames", default="1-12")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=90)
    ap.add_argument("--spp", default="4,8,16,32")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--windows", default="1,2,4,8")
    ap.add_argument("--rr", default="albedo", help="the plain path tracer's roulette")
    ap.add_argument("--extra", default="", help="more configurations, NAME:K:OPTION=VALUE+OPTION=VALUE;... "
                    "(skip with frame_window K and these submit_frames options, e.g. k4v:4:combine=variance)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--variants", default=",".join(os.path.join(ROOT, "scenes", v) for v in
                                                   ("conference-cut.json:19-30", "conference-fast.json:1-12")))  # fmt: skip
    ap.add_argument("--master-args", default="", help="more epr-master flags, e.g. '--window-cut-share 0'")
    ap.add_argument("--from-csv", action="store_true", help="render nothing: the tables and charts of OUT/csv")
    ap.add_argument("--charts", help="folder for the charts (gnuplot): frame_window_TAG.png and _full.png")
    ap.add_argument("--strip", help="PNG: six frames, reference above and the widest window (else skip) at the "
                                    "middle spp below")  # fmt: skip
    a = ap.parse_args()
    a.package_dir, a.master, a.worker = (os.path.join(a.build, p) for p in ("client/python", "master/epr-master",
                                                                            "worker/epr-worker"))  # fmt: skip
    a.spp = [int(s) for s in a.spp.split(",")]
    for d in ("csv", "img"):
        os.makedirs(os.path.join(a.out, d), exist_ok=True)
    os.makedirs(a.refs, exist_ok=True)
    a.tmp = tempfile.mkdtemp(prefix="epr-frame-window-")
    windows = [int(k) for k in a.windows.split(",") if k]
    configs = [("pt", "pt", 0, a.rr), ("skip", "skip", 0, None)] + [(f"k{k}", "skip", k, None) for k in windows]
    for spec in [e for e in a.extra.split(";") if e]:
        name, k, opts = spec.split(":", 2)
        extra = {o: number(v) for o, _, v in (x.partition("=") for x in opts.split("+") if x)}
        configs.append((name, "skip", int(k), None, extra))
    load = [os.getloadavg()[0]]
    tag = f"{os.path.splitext(os.path.basename(a.scene))[0]}_{a.width}x{a.height}"
    results, ref_folder = sweep(a, a.scene, a.frames, configs, tag)
    text = [table(results, tag, a.frames)]
    gains = {}
    for variant in [v for v in a.variants.split(",") if v]:
        scene, _, frames = variant.rpartition(":")
        vtag = f"{os.path.splitext(os.path.basename(scene))[0]}_{a.width}x{a.height}"
        vres, _ = sweep(a, scene, frames, [c for c in configs if c[0] != "pt"], vtag)
        text.append(table(vres, vtag, frames))
        for name in vres:
            if name != "skip":
                gains[(vtag, name)] = [ratios(r[name], r["skip"], col)[0] for r in (results, vres) for col in (2, 3)]
    if gains:
        text.append("Error at equal CPU against skip, relMSE / trimmed:\n\n"
                    "| variant | config | main scene | variant |\n|---|---|---|---|")  # fmt: skip
        text += [f"| {v} | {n} | {fmt(g[0])} / {fmt(g[1])} | {fmt(g[2])} / {fmt(g[3])} |" for (v, n), g in gains.items()]
    load.append(os.getloadavg()[0])
    with open(os.path.join(a.out, "summary.md"), "w") as f:
        f.write(f"{a.scene} frames {a.frames}, {a.width} x {a.height}, worker --threads {a.threads}; references "
                f"{a.ref_spp} spp pt in {ref_folder}; load average {load[0]:.1f} at the start, {load[1]:.1f} at the end"
                + "\n\n" + "\n".join(text) + "\n")  # fmt: skip
    print(open(os.path.join(a.out, "summary.md")).read())
    if a.charts:
        charts(a, tag, [c[0] for c in configs])
    if a.strip:
        best = configs[-1][0]
        strip(a, tag, parse_frames(a.frames), best, a.spp[len(a.spp) // 2], ref_folder, a.strip)
    shutil.rmtree(a.tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
