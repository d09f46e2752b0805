#!/usr/bin/python3
"""Where a frame window's error and CPU go (issue 36, docs/RESULTS.md "Frame windows"): reads the images
bench/frame_window.py left in OUT and prints, per configuration and sample count P,

- the error split by pixel kind: edge pixels (M' = 0: they take no reprojected samples and trace all
  their paths), skipped pixels (M < P) and the others (M = P, M' > 0): each kind's share of the pixels
  and of the frames' summed relMSE terms (reference noise subtracted);
- M' of the non-edge pixels (median, 10th and 90th percentile) and M' / M;
- the reprojected samples a frame accepted per path it traced (`accepted` / `paths_traced` of its
  statistics): a window's over skip's at the same P is how much its neighbours add to its own;
- the bias: the image mean's luminance against the reference's, mean over frames, with its standard
  error over the frames;
- the master's seconds per frame from the statistics files (tracing is the worker's: `seconds_tracing`,
  reprojecting, building the deep framebuffer, loading the scene) against the farm's CPU seconds.

    /usr/bin/python3 bench/frame_window_parts.py --out OUT --refs REFS/STEM_WxH_FRAMES_REFSPP --frames 1-12
"""

import argparse
import glob
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.dont_write_bytecode = True
import frame_window as fw  # noqa: E402
import garden_error_time as garden  # noqa: E402

LUM = np.array([0.2126, 0.7152, 0.0722])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="bench/frame_window.py's --out")
    ap.add_argument("--refs", required=True, help="the reference folder of the scene and frames")
    ap.add_argument("--frames", required=True)
    ap.add_argument("--tag", help="the scene's tag (default: the only one in OUT/img)")
    a = ap.parse_args()
    frames = fw.parse_frames(a.frames)
    tag = a.tag or os.listdir(os.path.join(a.out, "img"))[0]
    refs = []
    for frame in frames:
        ha, hb = (garden.read(os.path.join(a.refs, f"h{s}.{frame:04d}.exr")) for s in (1000001, 1000002))
        ref = (ha + hb) / 2
        refs.append((ref, ((ha - hb) ** 2 / 4 / (ref**2 + 0.01)).mean(axis=2)))
    cpu = {}
    for path in glob.glob(os.path.join(a.out, "csv", f"{tag}_*.csv")):
        name = os.path.basename(path)[len(tag) + 1 : -4]
        for line in open(path).readlines()[1:]:
            r = line.split(",")
            cpu[(name, int(r[0]))] = float(r[1])
    rows, per_path = [], {}
    for folder in sorted(glob.glob(os.path.join(a.out, "img", tag, "*_*"))):
        name, _, spp = os.path.basename(folder).rpartition("_")
        spp = int(spp)
        err = {"edge": 0.0, "skipped": 0.0, "full": 0.0}
        npx = {"edge": 0, "skipped": 0, "full": 0}
        mp, ratio, bias, secs, acc, traced = [], [], [], np.zeros(4), 0, 0
        for frame, (ref, floor) in zip(frames, refs):
            x = garden.read(f"{folder}/f.{frame:04d}.exr")
            t = ((x - ref) ** 2 / (ref**2 + 0.01)).mean(axis=2) - floor
            c = garden.read(f"{folder}/f.{frame:04d}.counts.exr")
            m, m2 = c[:, :, 0], c[:, :, 1]
            kinds = {"edge": m2 == 0, "skipped": (m2 > 0) & (m < spp), "full": (m2 > 0) & (m >= spp)}
            for k, sel in kinds.items():
                err[k] += float(t[sel].sum())
                npx[k] += int(sel.sum())
            mp.append(m2[m2 > 0])
            ratio.append(m2[m2 > 0] / np.maximum(m[m2 > 0], 1))
            bias.append(float((x @ LUM).mean() / (ref @ LUM).mean() - 1))
            s = json.load(open(f"{folder}/f.{frame:04d}.json"))
            secs += [s.get(k, 0.0) for k in ("seconds_tracing", "seconds_reprojecting", "seconds_frame_build",
                                            "seconds_scene_load")]  # fmt: skip
            acc += s.get("accepted", 0)
            traced += s.get("paths_traced", 0)
        total, pixels = sum(err.values()), sum(npx.values())
        mp, ratio = np.concatenate(mp), np.concatenate(ratio)
        per_path[(name, spp)] = acc / max(traced, 1)
        rows.append((name, spp, npx, err, total, pixels, mp, ratio, bias, secs))
    print("| config | P | pixels edge / skipped / full % | error share edge / skipped / full % | M' p10 / p50 / p90 "
          "| M'/M p50 | accepted per path (x skip's) | image mean vs reference % (± s.e.) | tracing / reprojecting / "
          "frame build / scene load s | farm CPU-s |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, spp, npx, err, total, pixels, mp, ratio, bias, secs in sorted(rows, key=lambda r: (r[1], r[0])):
        pct = " / ".join(f"{100 * npx[k] / pixels:.0f}" for k in npx)
        share = " / ".join(f"{100 * err[k] / total:.0f}" for k in err)
        q = np.percentile(mp, [10, 50, 90]) if len(mp) else [0, 0, 0]
        base = per_path.get(("skip", spp))
        app = per_path[(name, spp)]
        rel = f" ({app / base:.1f})" if base else ""
        b = 100 * np.mean(bias)
        se = 100 * np.std(bias, ddof=1) / np.sqrt(len(bias)) if len(bias) > 1 else 0.0
        print(f"| {name} | {spp} | {pct} | {share} | {q[0]:.0f} / {q[1]:.0f} / {q[2]:.0f} | "
              f"{np.median(ratio) if len(ratio) else 0:.1f} | {app:.2f}{rel} | {b:+.2f} ± {se:.2f} | "
              + " / ".join(f"{v:.1f}" for v in secs) + f" | {cpu.get((name, spp), float('nan')):.1f} |")  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
