#!/usr/bin/python3
"""F12 in Cycles against F12 on the farm for scenes built from Blender's primitives and lamps
(scripts/blender_scenes.py): Blender builds each scene, renders it with Cycles (two seeds) and
exports it with the add-on; `epr render` renders the export (two seeds, the add-on's camera and
settings); the two are compared by image mean and by 8 x 8 blocks, each within a tolerance derived
from the noise the two seeds show. Run with Debian's /usr/bin/python3 (numpy, OpenImageIO):

    /usr/bin/python3 scripts/addon_cycles_compare.py --blender blender --epr build/client/epr \
        --scenes objects,interior --spp 256 --out /tmp/compare

Prints, per scene, the mean luminance ratio farm / Cycles with its standard error, per-channel
ratios, and the blocks beyond 5 standard errors (and where). docs/RESULTS.md, "Blender scenes
against Cycles", gives the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
BLOCK = 8
LUMINANCE = (0.2126, 0.7152, 0.0722)


def read_exr(path: str):
    import numpy as np
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise RuntimeError(f"cannot read {path}: {oiio.geterror()}")
    spec = inp.spec()
    pixels = inp.read_image(format="float")
    inp.close()
    return np.asarray(pixels, dtype=np.float64).reshape(spec.height, spec.width, spec.nchannels)[:, :, :3]


def run(cmd, what: str) -> str:
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"{what} failed (status {p.returncode}):\n{p.stdout[-4000:]}")
    return p.stdout


def blender_scene(blender: str, scene: str, folder: str, width: int, height: int, spp: int, seeds,
                  lambertian: bool = False) -> dict:
    """Builds SCENE in Blender, renders it with Cycles per seed and exports it with the add-on; the
    add-on's farm.json (scene file, camera, warnings)."""
    run(
        [blender, "-b", "--factory-startup", "-noaudio", "-P", os.path.join(HERE, "blender_scenes.py"), "--",
         "--scene", scene, "--folder", folder, "--width", str(width), "--height", str(height), "--spp", str(spp),
         "--seeds", ",".join(str(s) for s in seeds)] + (["--lambertian"] if lambertian else []),
        f"Blender building and rendering '{scene}'",
    )
    with open(os.path.join(folder, "farm.json"), encoding="utf-8") as f:
        return json.load(f)


def farm_render(epr: str, farm: dict, folder: str, width: int, height: int, spp: int, seed: int, mode: str) -> str:
    """`epr render` of the add-on's export with its camera, as one process; the EXR's path."""
    cam = farm["camera"]
    out = os.path.join(folder, f"farm_{seed}")
    vec = lambda v: ",".join(repr(float(x)) for x in v)  # noqa: E731
    run(
        [epr, "render", farm["scene"], "--single-process", "--width", str(width), "--height", str(height),
         "--spp", str(spp), "--seed", str(seed), "--mode", mode, "--eye", vec(cam["eye"]), "--look",
         vec(cam["look"]), "--up", vec(cam["up"]), "--fov", repr(cam["fov"]), "--out", out],
        f"epr render of {farm['scene']}",
    )
    return out + ".exr"


def compare(farm_a, farm_b, cycles_a, cycles_b, relative: float = 0.0) -> dict:
    """The mean of each renderer's two seeds compared: the luminance ratio farm / Cycles with its
    standard error, per-channel ratios, and the 8 x 8 blocks (per channel) whose difference exceeds
    5 standard errors + RELATIVE x the larger block mean + 1e-4. A block mean's standard error comes from the
    per-pixel difference of the two seeds d (the mean of two seeds has variance var(d) / 4 per pixel),
    summed over both renderers."""
    import numpy as np

    farm, cycles = (farm_a + farm_b) / 2, (cycles_a + cycles_b) / 2
    h, w, c = farm.shape
    hb, wb = h // BLOCK, w // BLOCK

    def blocks(x):
        return x[: hb * BLOCK, : wb * BLOCK].reshape(hb, BLOCK, wb, BLOCK, c)

    def block_se(d):
        return blocks(d).std(axis=(1, 3)) / (2 * BLOCK)

    se = np.sqrt(block_se(farm_a - farm_b) ** 2 + block_se(cycles_a - cycles_b) ** 2)
    ours, ref = blocks(farm).mean(axis=(1, 3)), blocks(cycles).mean(axis=(1, 3))
    tolerance = 5 * se + relative * np.maximum(ours, ref) + 1e-4  # (blocks of the sky have no noise)
    z = np.abs(ours - ref) / (se + 2e-5)  # (the floor: 1e-4 is 5 of these)
    over = np.argwhere(np.abs(ours - ref) > tolerance)
    lum = np.asarray(LUMINANCE)
    lum_farm, lum_cycles = (farm * lum).sum(axis=2), (cycles * lum).sum(axis=2)
    # the image means' standard errors, from the seeds' per-pixel differences
    se_farm = float(((farm_a - farm_b) * lum).sum(axis=2).std()) / 2 / np.sqrt(h * w)
    se_cycles = float(((cycles_a - cycles_b) * lum).sum(axis=2).std()) / 2 / np.sqrt(h * w)
    ratio = float(lum_farm.mean() / lum_cycles.mean())
    ratio_se = ratio * float(np.hypot(se_farm / lum_farm.mean(), se_cycles / lum_cycles.mean()))
    return {
        "ratio": ratio,
        "ratio_se": ratio_se,
        "channel_ratios": [float(farm[:, :, k].mean() / cycles[:, :, k].mean()) for k in range(3)],
        "blocks": int(ours.size),
        "over": [(int(b[0]), int(b[1]), int(b[2]), float(ours[tuple(b)]), float(ref[tuple(b)]),
                  float(tolerance[tuple(b)])) for b in over],
        "worst_z": float(z.max()),
        "median_z": float(np.median(z)),
    }


def compare_scene(args, scene: str) -> dict:
    folder = os.path.join(os.path.abspath(args.out), scene)
    os.makedirs(folder, exist_ok=True)
    seeds = (1, 2)
    farm = blender_scene(args.blender, scene, folder, args.width, args.height, args.cycles_spp or args.spp, seeds,
                         args.lambertian)
    images = [farm_render(args.epr, farm, folder, args.width, args.height, args.spp, s, args.mode) for s in seeds]
    result = compare(*[read_exr(p) for p in images],
                     *[read_exr(os.path.join(folder, f"cycles_{s}.exr")) for s in seeds], args.relative)
    result["warnings"] = farm["warnings"]
    return result


def report(scene: str, r: dict) -> str:
    lines = [
        f"{scene}: mean luminance farm / Cycles {r['ratio']:.4f} +- {r['ratio_se']:.4f} (channels "
        + ", ".join(f"{x:.4f}" for x in r["channel_ratios"])
        + f"); blocks beyond tolerance {len(r['over'])} of {r['blocks']}; |diff| / se worst {r['worst_z']:.1f},"
        f" median {r['median_z']:.2f}"
    ]
    for by, bx, k, ours, ref, tol in r["over"][:12]:
        lines.append(f"  block ({bx}, {by}) channel {k}: farm {ours:.4f}, Cycles {ref:.4f}, tolerance {tol:.4f}")
    lines += [f"  add-on warning: {w}" for w in r.get("warnings", [])]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--blender", default="blender")
    ap.add_argument("--epr", default=os.path.join(HERE, "..", "build", "client", "epr"))
    ap.add_argument("--scenes", default="objects,interior", help="of scripts/blender_scenes.py")
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=64)
    ap.add_argument("--spp", type=int, default=256, help="the farm's samples per pixel")
    ap.add_argument("--cycles-spp", type=int, default=0, help="Cycles' (default: --spp)")
    ap.add_argument("--mode", default="skip", help="the farm's mode (the add-on's default: skip)")
    ap.add_argument("--relative", type=float, default=0.0, help="block tolerance beyond 5 se, a share of the mean")
    ap.add_argument("--lambertian", action="store_true", help="every material Lambertian in both renderers")
    ap.add_argument("--out", required=True, help="a folder for the scenes and renders")
    args = ap.parse_args()
    for scene in args.scenes.split(","):
        print(report(scene, compare_scene(args, scene)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
