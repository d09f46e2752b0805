#!/usr/bin/python3
"""Equal-time image strip: pt | rp | skip | skip's M' heat map | reference, side by side, one PNG.

    /usr/bin/python3 bench/charts/strip.py OUT/strip/cornell_128x128 docs/results/strip_cornell_128x128.png [LABEL...]

Reads PREFIX_pt.exr, PREFIX_rp.exr, PREFIX_skip.exr, PREFIX_skip_mprime.png and PREFIX_reference.exr
(written by speed_accuracy: each run's image after the last round it finished within half of plain
path tracing's CPU time for P = 64), maps radiance to 8-bit sRGB (clamped to [0, 1], as the renderer's
PNGs), scales small images up 2x (nearest) and labels each panel when OpenImageIO can render text.
"""
import os
import sys

import numpy as np
import OpenImageIO as oiio


def read(path):
    buf = oiio.ImageBuf(path)
    if buf.has_error:
        raise SystemExit("%s: %s" % (path, buf.geterror()))
    px = buf.get_pixels(oiio.FLOAT)
    return np.asarray(px)[:, :, :3] if px.shape[2] >= 3 else np.repeat(np.asarray(px), 3, axis=2)


def srgb(x):
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def main():
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    prefix, out = sys.argv[1], sys.argv[2]
    labels = sys.argv[3:] or ["pt", "rp", "skip", "skip: M' (heat map)", "reference"]
    panels = []
    for name, kind in (("_pt.exr", "hdr"), ("_rp.exr", "hdr"), ("_skip.exr", "hdr"),
                       ("_skip_mprime.png", "ldr"), ("_reference.exr", "hdr")):
        path = prefix + name
        if not os.path.isfile(path):
            raise SystemExit("missing %s" % path)
        img = read(path)
        # The heat map PNG is read linearised by OpenImageIO; encode it back to sRGB.
        panels.append(srgb(img))
    h = max(p.shape[0] for p in panels)
    scale = 2 if h <= 160 else 1
    gap = np.ones((h * scale, 4, 3), dtype=np.float32)
    row = []
    for p in panels:
        if scale > 1:
            p = np.repeat(np.repeat(p, scale, axis=0), scale, axis=1)
        row += [p, gap]
    strip = np.concatenate(row[:-1], axis=1).astype(np.float32)
    buf = oiio.ImageBuf(oiio.ImageSpec(strip.shape[1], strip.shape[0], 3, oiio.FLOAT))
    buf.set_pixels(oiio.ROI(), strip)
    x = 0
    for p, label in zip(panels, labels):
        try:
            oiio.ImageBufAlgo.render_text(buf, x + 4, 14, label, 12, "", (1, 1, 0.3))
        except Exception:
            pass
        x += p.shape[1] * scale + 4
    out_buf = oiio.ImageBufAlgo.copy(buf, oiio.UINT8)
    if not out_buf.write(out):
        raise SystemExit("%s: %s" % (out, out_buf.geterror()))
    print("wrote", out)


if __name__ == "__main__":
    main()
