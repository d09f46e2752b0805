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
per-pixel differences. OUT/runs.csv holds every run, written as each one ends (an interrupted sweep keeps
what it measured).

With --cycles ARGS (one scene only: scripts/cycles_reference.py's scene flags, e.g. "--gltf FILE
--env SKY --sun X,Y,Z,ANGLE,E") and --cycles-camera FILE (--eye= --look= --up= --fov=, the scene's
camera), Blender Cycles is a baseline too: scripts/cycles_sweep.py renders every P once per seed (its
CPU seconds per render call: scene sync and BVH included, Blender's start and the import not), scored
against Cycles' own converged image (cycles_reference.py at --ref-spp / 2, seeds 1000001 and 1000002, its noise
subtracted the same way), so each renderer is measured against itself and the two models' small
differences do not count as error. Its row gives the median error x CPU as a multiple of the best
pt's, and every mode's ratio to Cycles' is printed below the table.
"""

import argparse
import csv
import os
import shlex
import statistics
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import garden_error_time as garden  # noqa: E402  (read, run, children_cpu, errors, terms)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

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


def blender(a, script, args, log):
    garden.run([a.blender, "-b", "--factory-startup", "-noaudio", "-P", os.path.join(ROOT, "scripts", script), "--",
                "--width", str(a.width), "--height", str(a.height), "--threads", str(a.threads), *args], log)  # fmt: skip


def cycles_runs(a, spps, seeds):
    """{P: [(seed, cpu, full, trimmed), ...]} for Cycles against its own reference."""
    folder = os.path.join(a.out, "cycles")
    os.makedirs(folder, exist_ok=True)
    scene = shlex.split(a.cycles)
    with open(a.cycles_camera, encoding="utf-8") as f:
        camera = shlex.split(f.read())
    halves = []
    for s in (1000001, 1000002):  # not a sweep's seed: Cycles' samples of one seed are the same at every count
        out = os.path.join(folder, f"ref_{a.width}x{a.height}_{a.ref_spp}_{s}.exr")
        if not os.path.exists(out):
            blender(a, "cycles_reference.py", [*scene, *camera, "--spp", str(a.ref_spp // 2), "--seed", str(s),
                                               "--out", out], out + ".log")  # fmt: skip
        halves.append(garden.read(out))
    ref = (halves[0] + halves[1]) / 2
    floor = ((halves[0] - halves[1]) ** 2 / 4 / (ref**2 + 0.01)).mean(axis=2).ravel()
    runs = {}
    for seed in seeds:
        sweep = os.path.join(folder, f"sweep_{seed}")
        blender(a, "cycles_sweep.py", [*scene, "--camera", a.cycles_camera, "--spp", ",".join(map(str, spps)),
                                       "--seed", str(seed), "--outdir", sweep], sweep + ".log")  # fmt: skip
        with open(os.path.join(sweep, "times.csv"), newline="") as f:
            for row in csv.DictReader(f):
                full, trimmed = garden.errors(garden.read(os.path.join(sweep, row["file"])), ref, floor)
                runs.setdefault(int(row["spp"]), []).append((seed, float(row["cpu_s"]), full, trimmed))
    return runs


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
    ap.add_argument("--cycles", help="Cycles as a baseline too: cycles_reference.py's scene flags (one scene only)")
    ap.add_argument("--cycles-camera", help="with --cycles: a file of --eye= --look= --up= --fov=")
    ap.add_argument("--blender", default="blender")
    a = ap.parse_args()
    if a.cycles and (len(a.scene) != 1 or not a.cycles_camera):
        raise SystemExit("--cycles needs exactly one --scene and --cycles-camera")
    if not any(m.startswith("pt") for m in a.modes):
        raise SystemExit("--modes needs at least one pt mode: the best pt is the baseline")
    spps = [int(s) for s in a.spp.split(",")]
    seeds = [int(s) for s in a.seeds.split(",")]
    os.makedirs(os.path.join(a.out, "img"), exist_ok=True)
    cycles = cycles_runs(a, spps, seeds) if a.cycles else {}
    runs_csv = open(os.path.join(a.out, "runs.csv"), "w", newline="")
    table = csv.writer(runs_csv)

    def record(*new_rows):
        table.writerows(new_rows)
        runs_csv.flush()

    record(["scene", "spp", "mode", "seed", "cpu_s", "relmse", "trimmed", "offset_pct"])
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
                    record([scene, spp, mode, seed, f"{cpu:.3f}", f"{full:.6g}", f"{trimmed:.6g}", f"{off:.3f}"])
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
            shown = len(a.modes) + 5
            if spp in cycles:
                by_seed = {r[0]: r for r in cycles[spp]}
                pairs = lambda mode: [(r, by_seed[r[0]]) for r in runs[mode] if r[0] in by_seed]  # noqa: E731
                c = cycles[spp]
                lines.append(f"| Cycles | {statistics.median(r[1] for r in c):.2f} | "
                             f"{statistics.median(r[2] for r in c):.5f} | {statistics.median(r[3] for r in c):.5f} | "
                             + " / ".join(f"{statistics.median(y[1] * y[i] / (b[1] * b[i]) for b, y in pairs(best)):.2f}"
                                          for i in (2, 3)) + " | (against its own reference) |")  # fmt: skip
                lines.append("")
                lines.append("Each mode's error x CPU as a multiple of Cycles' (full / trimmed): " + "; ".join(
                    f"{mode} " + " / ".join(f"{statistics.median(r[1] * r[i] / (y[1] * y[i]) for r, y in pairs(mode)):.2f}"
                                            for i in (2, 3)) for mode in a.modes))  # fmt: skip
                shown += 3
                record(*[["cycles", spp, "cycles", r[0], f"{r[1]:.3f}", f"{r[2]:.6g}", f"{r[3]:.6g}", ""] for r in c])
            lines.append("")
            print("\n".join(lines[-shown:]), flush=True)
    runs_csv.close()
    with open(os.path.join(a.out, "summary.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
