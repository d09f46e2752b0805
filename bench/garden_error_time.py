#!/usr/bin/python3
"""Error against time on scenes/garden (a glTF with textures and cut-outs, lit by a sky image and a
sun): eprfarm pt, eprfarm skip and Blender Cycles at a sweep of sample counts, against a converged
eprfarm path-traced reference; and the agreement of that reference with a converged Cycles image
(docs/RESULTS.md, "A glTF under a sky and a sun").

    /usr/bin/python3 bench/garden_error_time.py --epr BUILD/client/epr --out OUT [--width 160 --height 120]
        [--spp 4,8,16,32,64,128,256 --ref-spp 2048 --charts docs/results]

Runs, one after the other (2 tracing threads each):
  * the reference: `epr render garden.json --single-process --mode pt` as two halves of --ref-spp / 2
    (seeds 1000001, 1000002); (a - b)^2 / 4 estimates its own variance per pixel, whose share (the
    floor) is subtracted from every error, as bench/speed_accuracy.cpp does;
  * eprfarm pt and skip at every --spp (seed 1), CPU seconds of the epr process (getrusage of the
    child: scene load, BVH and, for skip, the GL reprojection included);
  * Cycles: scripts/cycles_sweep.py --gltf at every --spp (its CPU seconds per render, the scene built
    once), and scripts/cycles_reference.py --gltf at --ref-spp / 2 with seeds 1 and 2 (Cycles' converged
    image and its noise).
Error: relative MSE, mean over pixels and channels of (x - r)^2 / (r^2 + 0.01), and trimmed (the 1 %
largest per-pixel terms left out). Writes OUT/csv/garden_WxH_{pt,skip,cycles}.csv (columns as
speed_accuracy's, for bench/charts/error_time.gp), OUT/summary.md (the tables and the agreement) and,
with --charts DIR, the charts.
"""

import argparse
import csv
import os
import resource
import subprocess
import sys

import numpy as np
import OpenImageIO as oiio

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE = os.path.join(ROOT, "scenes", "garden")
CAMERA = "--eye=0.9,1.5,4.2 --look=0.1,0.7,-0.6 --up=0,1,0 --fov=45"  # the glTF's camera node
SKY = ["--env", os.path.join(SCENE, "sky.exr"), "--sun=-0.6,0.9,-1.0,0.53,3"]  # as garden.json
TRIM = 0.01


def read(path):
    buf = oiio.ImageBuf(path)
    if buf.has_error:
        raise SystemExit(f"cannot read {path}: {buf.geterror()}")
    return buf.get_pixels(oiio.FLOAT)[:, :, :3].astype(np.float64)


def children_cpu():
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def run(argv, log):
    with open(log, "w") as f:
        r = subprocess.run(argv, stdout=f, stderr=subprocess.STDOUT)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed, see {log}")


def epr_render(a, mode, spp, seed, out):
    c0 = children_cpu()
    run([a.epr, "render", os.path.join(SCENE, "garden.json"), "--single-process", "--mode", mode, "--width",
         str(a.width), "--height", str(a.height), "--spp", str(spp), "--seed", str(seed), "--threads", "2",
         "--out", out], out + ".log")  # fmt: skip
    return children_cpu() - c0


def terms(x, ref):
    return ((x - ref) ** 2 / (ref**2 + 0.01)).mean(axis=2).ravel()


def errors(x, ref, floor):
    t = terms(x, ref) - floor
    keep = np.sort(t)[: int(len(t) * (1 - TRIM))]
    return float(t.mean()), float(keep.mean())


def blender(a, script, *args, log):
    run([a.blender, "-b", "--factory-startup", "-noaudio", "-P", os.path.join(ROOT, "scripts", script), "--",
         "--gltf", os.path.join(SCENE, "garden.gltf"), "--width", str(a.width), "--height", str(a.height),
         "--threads", "2", *SKY, *args], log)  # fmt: skip


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epr", required=True)
    ap.add_argument("--blender", default="blender")
    ap.add_argument("--out", required=True)
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--spp", default="4,8,16,32,64,128")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--charts", help="folder for the charts (bench/charts/error_time.gp; gnuplot): "
                    "error_cpu_TAG and error_cpu_full_TAG, .png and .svg")
    a = ap.parse_args()
    spps = [int(s) for s in a.spp.split(",")]
    os.makedirs(os.path.join(a.out, "csv"), exist_ok=True)
    os.makedirs(os.path.join(a.out, "img"), exist_ok=True)
    img = lambda name: os.path.join(a.out, "img", name)  # noqa: E731
    tag = f"garden_{a.width}x{a.height}"
    load = [os.getloadavg()[0]]

    half = a.ref_spp // 2
    ref_cpu = sum(epr_render(a, "pt", half, s, img(f"ref_{s}")) for s in (1000001, 1000002))
    ha, hb = read(img("ref_1000001.exr")), read(img("ref_1000002.exr"))
    ref = (ha + hb) / 2
    floor = ((ha - hb) ** 2 / 4 / (ref**2 + 0.01)).mean(axis=2).ravel()
    rows = {}
    for mode in ("pt", "skip"):
        rows[mode] = []
        for spp in spps:
            cpu = epr_render(a, mode, spp, 1, img(f"{mode}_{spp}"))
            rows[mode].append((spp, cpu, *errors(read(img(f"{mode}_{spp}.exr")), ref, floor)))
    sweep = img("cycles")
    with open(os.path.join(a.out, "cycles.camera"), "w") as f:
        f.write(CAMERA + "\n")
    blender(a, "cycles_sweep.py", "--camera", os.path.join(a.out, "cycles.camera"), "--spp", a.spp, "--seed", "1",
            "--outdir", sweep, log=sweep + ".log")  # fmt: skip
    rows["cycles"] = []
    with open(os.path.join(sweep, "times.csv")) as f:
        for r in csv.DictReader(f):
            x = read(os.path.join(sweep, r["file"]))
            rows["cycles"].append((int(r["spp"]), float(r["cpu_s"]), *errors(x, ref, floor)))
    c0 = children_cpu()
    for s in (1, 2):
        blender(a, "cycles_reference.py", "--spp", str(half), "--seed", str(s), "--out", img(f"cycles_ref_{s}.exr"),
                *CAMERA.split(), log=img(f"cycles_ref_{s}.log"))  # fmt: skip
    cycles_ref_cpu = children_cpu() - c0
    load.append(os.getloadavg()[0])
    for mode, rs in rows.items():
        with open(os.path.join(a.out, "csv", f"{tag}_{mode}.csv"), "w") as f:
            f.write("spp,cpu_s,rel_mse,rel_mse_trim\n")
            for r in rs:
                f.write("%d,%.4f,%.6g,%.6g\n" % r)
    ca, cb = read(img("cycles_ref_1.exr")), read(img("cycles_ref_2.exr"))
    with open(os.path.join(a.out, "summary.md"), "w") as f:
        f.write(f"garden {a.width} x {a.height}; load average {load[0]:.1f} at the start, {load[1]:.1f} at the end; "
                f"references: eprfarm pt {a.ref_spp} spp ({ref_cpu:.0f} CPU-s), Cycles {a.ref_spp} spp "
                f"({cycles_ref_cpu:.0f} CPU-s of Blender, start-up included)\n\n")
        f.write("| spp | pt CPU-s | pt relMSE | pt trimmed | skip CPU-s | skip relMSE | skip trimmed | Cycles CPU-s "
                "| Cycles relMSE | Cycles trimmed |\n|---|---|---|---|---|---|---|---|---|---|\n")
        for i, spp in enumerate(spps):
            cells = [f"{rows[m][i][1]:.2f} | {rows[m][i][2]:.4g} | {rows[m][i][3]:.4g}" for m in ("pt", "skip", "cycles")]
            f.write(f"| {spp} | " + " | ".join(cells) + " |\n")
        f.write("\n" + agreement(ha, hb, ca, cb, a) + "\n")
    print(open(os.path.join(a.out, "summary.md")).read())
    if a.charts:
        charts(a, tag)


def charts(a, tag):
    os.makedirs(a.charts, exist_ok=True)
    for name, ycol, what in (("error_cpu", "rel_mse_trim", "trimmed 1 %"), ("error_cpu_full", "rel_mse", "full")):
        title = f"{tag}: glTF, textures, cut-outs, sky image and sun ({what})"
        run(["gnuplot", "-e", f"csv='{os.path.join(a.out, 'csv')}'; tag='{tag}'; ycol='{ycol}'; "
             f"out='{os.path.join(a.charts, name + '_' + tag)}'; title='{title}'",
             os.path.join(ROOT, "bench", "charts", "error_time.gp")], os.path.join(a.out, name + ".log"))


def agreement(ha, hb, ca, cb, a, block=8):
    """Cycles' converged image against eprfarm's: image mean and blocks of luminance, each difference
    in standard errors of the difference (from the two halves of each)."""
    lum = lambda x: x @ np.array([0.2126, 0.7152, 0.0722])  # noqa: E731
    e, c = lum((ha + hb) / 2), lum((ca + cb) / 2)
    var = (lum(ha) - lum(hb)) ** 2 / 4 + (lum(ca) - lum(cb)) ** 2 / 4  # per pixel, of the difference
    h, w = e.shape
    n = (h // block) * (w // block)

    def blocks(x):
        return x[: h // block * block, : w // block * block].reshape(h // block, block, w // block, block).sum(axis=(1, 3))

    diff, se = blocks(e - c), np.sqrt(blocks(var))
    z = diff / se
    mean_z = float((e - c).sum() / np.sqrt(var.sum()))
    rel = float(e.mean() / c.mean() - 1)
    sky_rows = slice(0, h // 8)
    return (
        f"Agreement (luminance): eprfarm/Cycles image mean {100 * rel:+.3f} % (z {mean_z:+.2f}); "
        f"{int((diff > 0).sum())} of {n} {block} x {block} blocks brighter in eprfarm; worst block z {z.flat[np.argmax(abs(z))]:+.2f} "
        f"({100 * float(diff.flat[np.argmax(abs(z))] / blocks(c).flat[np.argmax(abs(z))]):+.2f} %); "
        f"|z| > 3 in {int((abs(z) > 3).sum())} blocks (expected {n * 0.0027:.1f}); top eighth of rows (sky) "
        f"{100 * float(e[sky_rows].mean() / c[sky_rows].mean() - 1):+.4f} %"
    )


if __name__ == "__main__":
    sys.exit(main())
