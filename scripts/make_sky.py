#!/usr/bin/python3
"""Writes a procedural equirectangular sky (OpenEXR, half float) for scenes/sky/.

A clear-sky look without a physical model: blue at the zenith fading to a pale horizon, a warm glow
around the sun's direction, and a dark warm-grey ground below the horizon. The mapping is eprfarm's
(common/lighting.h; Blender's Environment Texture for a Y-up scene): column u looks along
phi = 2 pi (u - 0.5) with phi = atan2(z, x), row t (from the top) at theta = pi t from +Y.

Usage: /usr/bin/python3 scripts/make_sky.py OUT.exr [--width 256] [--sun X,Y,Z]
(Debian's python3-openimageio and python3-numpy.) The image is the project's own work.
"""
import argparse

import numpy as np
import OpenImageIO as oiio


def sky(width: int, sun: np.ndarray) -> np.ndarray:
    height = width // 2
    t = (np.arange(height) + 0.5) / height
    u = (np.arange(width) + 0.5) / width
    theta = np.pi * t[:, None]
    phi = 2 * np.pi * (u[None, :] - 0.5)
    d = np.stack([np.sin(theta) * np.cos(phi), np.cos(theta) * np.ones_like(phi), np.sin(theta) * np.sin(phi)], -1)
    up = np.clip(d[..., 1], 0, 1)
    zenith = np.array([0.25, 0.45, 1.0])
    horizon = np.array([0.9, 0.95, 1.0])
    blend = (1 - up) ** 3
    rgb = zenith * (1 - blend[..., None]) + horizon * blend[..., None]
    cos_sun = np.clip(d @ (sun / np.linalg.norm(sun)), -1, 1)
    glow = np.exp((cos_sun - 1) * 12.0)[..., None] * np.array([1.6, 1.2, 0.7])
    rgb = rgb + glow
    ground = np.array([0.18, 0.15, 0.12]) * (0.6 + 0.4 * np.exp(d[..., 1] * 8))[..., None]
    below = d[..., 1] < 0
    rgb[below] = ground[below]
    return rgb.astype(np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--sun", default="-1,1,-0.4", help="direction of the glow, x,y,z (y is up)")
    a = ap.parse_args()
    img = sky(a.width, np.array([float(v) for v in a.sun.split(",")]))
    spec = oiio.ImageSpec(img.shape[1], img.shape[0], 3, "half")
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(a.out)
    if not out or not out.open(a.out, spec):
        raise SystemExit(f"cannot write {a.out}: {oiio.geterror()}")
    out.write_image(img)
    out.close()


if __name__ == "__main__":
    main()
