#!/usr/bin/python3
"""Skip against the best plain path tracer, medians over seeds (issue 32's measured goals).

    /usr/bin/python3 bench/best_pt.py --epr BUILD/client/epr --out OUT \
        --scene builtin:conference --width 64 --height 64 --spp 256,1024 --seeds 1,2,3 \
        --modes pt:rr=reuse pt:rr=albedo skip skip:combine=variance [--ref-spp 4096] [--threads 2]

For every scene, P (--spp) and seed, each mode is one `epr render --single-process` (2 tracing
threads), its CPU seconds those of the epr process (getrusage of the child: scene load, BVH,
reprojection included). A mode is a name with `:key=value` options, each passed as `--key value`
(`pt:rr=albedo` is `--mode pt --rr albedo`). The reference is `epr render --mode pt` at --ref-spp / 2
with seeds 1000001 and 1000002, kept in OUT/ref and reused; its own variance, (a - b)^2 / 4 per pixel,
is subtracted from every error (garden_error_time.py's metric: relMSE, mean over pixels and channels
of (x - r)^2 / (r^2 + 0.01), full and trimmed of the 1 % largest per-pixel terms).

Printed and written to OUT/summary.md, per scene and P: each mode's median CPU seconds, median full
and trimmed error, and error x CPU (the efficiency: lower is better) as a multiple of the best pt's,
where the best pt is the pt mode with the lowest median error x CPU; the ratio is the median over
seeds of the per-seed ratios against that pt's run of the same seed (side by side, so load drifts
cancel). The image mean's offset from the reference (luminance, %) with the standard error of the
per-pixel differences. OUT/runs.csv holds every run.
"""

import argparse
import csv
import os
import statistics
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import garden_error_time as garden  # noqa: E402  (read, run, children_cpu, errors, terms)

LUMA = np.array([0.2126, 0.7152, 0.0722])


def parse_mode(text):
    name, *opts = text.split(":")
    args = ["--mode", name]
    for o in opts:
        key, _, value = o.partition("=")
        args += [f"--{key}", value]
    return args


def render(a, scene, mode_args, spp, seed, out):
    c0 = garden.children_cpu()
    garden.run([a.epr, "render", scene, "--single-process", "--width", str(a.width), "--height", str(a.height),
                "--spp", str(spp), "--seed", str(seed), "--threads", str(a.threads), "--out", out, *mode_args],
               out + ".log")  # fmt: skip
    return garden.children_cpu() - c0


def tag_of(scene):
    return os.path.splitext(os.path.basename(scene.replace("builtin:", "")))[0]


def reference(a, scene):
    folder = os.path.join(a.out, "ref")
    os.makedirs(folder, exist_ok=True)
    halves = []
    for s in (1000001, 1000002):
        prefix = os.path.join(folder, f"{tag_of(scene)}_{a.width}x{a.height}_{a.ref_spp}_{s}")
        if not os.path.exists(prefix + ".exr"):
            render(a, scene, ["--mode", "pt"], a.ref_spp // 2, s, prefix)
        halves.append(garden.read(prefix + ".exr"))
    ref = (halves[0] + halves[1]) / 2
    floor = ((halves[0] - halves[1]) ** 2 / 4 / (ref**2 + 0.01)).mean(axis=2).ravel()
    return ref, floor


def mean_offset(x, ref):
    d = (x - ref) @ LUMA
    r = (ref @ LUMA).mean()
    return 100 * d.mean() / r, 100 * d.std(ddof=1) / np.sqrt(d.size) / r


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epr", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--scene", nargs="+", required=True, help="builtin:NAME or a scene file")
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--height", type=int, default=64)
    ap.add_argument("--spp", default="256,1024")
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--modes", nargs="+", default=["pt:rr=reuse", "pt:rr=albedo", "skip"])
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    if not any(m.startswith("pt") for m in a.modes):
        raise SystemExit("--modes needs at least one pt mode: the best pt is the baseline")
    spps = [int(s) for s in a.spp.split(",")]
    seeds = [int(s) for s in a.seeds.split(",")]
    os.makedirs(os.path.join(a.out, "img"), exist_ok=True)
    rows = []
    lines = [f"load average at start {os.getloadavg()[0]:.1f}; {a.width} x {a.height}, seeds {a.seeds}, "
             f"reference {a.ref_spp} spp", ""]  # fmt: skip
    for scene in a.scene:
        ref, floor = reference(a, scene)
        for spp in spps:
            runs = {}  # mode -> list of (seed, cpu, full, trimmed, offset, sigma)
            for seed in seeds:
                for mode in a.modes:  # modes interleaved per seed: side by side under one load
                    prefix = os.path.join(a.out, "img", f"{tag_of(scene)}_{spp}_{mode.replace(':', '_')}_{seed}")
                    cpu = render(a, scene, parse_mode(mode), spp, seed, prefix)
                    x = garden.read(prefix + ".exr")
                    full, trimmed = garden.errors(x, ref, floor)
                    off, sigma = mean_offset(x, ref)
                    runs.setdefault(mode, []).append((seed, cpu, full, trimmed, off, sigma))
                    rows.append([scene, spp, mode, seed, f"{cpu:.3f}", f"{full:.6g}", f"{trimmed:.6g}", f"{off:.3f}"])
            med = lambda mode, i: statistics.median(r[i] for r in runs[mode])  # noqa: E731
            pts = [m for m in a.modes if m.startswith("pt")]
            best = min(pts, key=lambda m: med(m, 1) * med(m, 2))
            lines += [f"### {scene}, P = {spp} (best pt: {best})", "",
                      "| mode | CPU-s | relMSE full | trimmed | error x CPU / best pt's (full / trimmed) | mean offset |",
                      "|---|---|---|---|---|---|"]  # fmt: skip
            for mode in a.modes:
                ratio = [statistics.median(r[1] * r[i] / (b[1] * b[i]) for r, b in zip(runs[mode], runs[best]))
                         for i in (2, 3)]  # fmt: skip
                lines.append(f"| {mode} | {med(mode, 1):.2f} | {med(mode, 2):.5f} | {med(mode, 3):.5f} | "
                             f"{ratio[0]:.2f} / {ratio[1]:.2f} | {med(mode, 4):+.2f} % (sigma "
                             f"{med(mode, 5):.2f} %) |")  # fmt: skip
            lines.append("")
            print("\n".join(lines[-len(a.modes) - 5 :]), flush=True)
    with open(os.path.join(a.out, "runs.csv"), "w", newline="") as f:
        csv.writer(f).writerows([["scene", "spp", "mode", "seed", "cpu_s", "relmse", "trimmed", "offset_pct"], *rows])
    with open(os.path.join(a.out, "summary.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
