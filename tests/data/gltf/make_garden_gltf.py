#!/usr/bin/python3
"""Writes scenes/garden/ (garden.gltf, .bin, its textures, sky.exr and garden.json): a glTF scene lit
only from outside, with textures and cut-outs.

A paved yard under a sky and a sun, no emitters: a paving texture on the ground, a brick wall, a
wooden crate (a plank texture), a lattice fence whose diamond holes are an alpha mask (alphaMode MASK,
alphaCutoff 0.5) and two leaf cards (MASK, the default cut-off). The sun stands behind the fence, so
the lattice's shadow, holes and all, falls on the paving in front of it, and the sky shows above the
wall and through the fence's holes. garden.json names the glTF, the sky image (written by
scripts/make_sky.py's sky(), its glow towards the sun) and the sun. Textures are 8-bit sRGB PNGs with
alpha 0 or 255 only, read at the nearest texel. Everything is the project's own work.

    /usr/bin/python3 tests/data/gltf/make_garden_gltf.py   (from the repository root; numpy, OpenImageIO)
"""
import json
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(ROOT, "scripts"))
sys.dont_write_bytecode = True
from make_cutout_gltf import Writer, camera_node, lattice_texture, leaf_texture, write_png  # noqa: E402

OUT = os.path.join(ROOT, "scenes", "garden")
SUN = (-0.6, 0.9, -1.0)  # towards the sun: behind the fence, to the left, 35 degrees up
EYE, LOOK, YFOV = (0.9, 1.5, 4.2), (0.1, 0.7, -0.6), 45.0


def paving_texture(x, y):
    """64 x 64: 4 x 4 grey-beige slabs of slightly different shades with dark joints."""
    if x % 16 in (0, 15) or y % 16 in (0, 15):
        return (70, 66, 60)
    shade = ((x // 16) * 7 + (y // 16) * 13) % 5 * 8
    return (150 + shade, 140 + shade, 120 + shade)


def brick_texture(x, y):
    """64 x 64: red-brown bricks in running bond, 4 courses, light mortar."""
    row = y // 16
    shift = 8 if row % 2 else 0
    if y % 16 in (0, 15) or (x + shift) % 32 in (0, 31):
        return (200, 195, 185)
    tone = ((x + shift) // 32 * 5 + row * 3) % 4 * 10
    return (150 + tone, 60 + tone // 2, 45)


def plank_texture(x, y):
    """32 x 32: four horizontal planks, light wood, dark gaps."""
    if y % 8 == 0:
        return (60, 40, 25)
    grain = 10 * math.sin(x * 0.7 + (y // 8) * 2.0)
    return (185 + grain, 140 + grain, 90 + grain / 2)


def box(w, lo, hi, material):
    """An axis-aligned box's five visible faces (no bottom), each a textured quad facing out."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    w.quad([(x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)], material)  # +z
    w.quad([(x1, y0, z0), (x0, y0, z0), (x0, y1, z0), (x1, y1, z0)], material)  # -z
    w.quad([(x1, y0, z1), (x1, y0, z0), (x1, y1, z0), (x1, y1, z1)], material)  # +x
    w.quad([(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)], material)  # -x
    w.quad([(x0, y1, z1), (x1, y1, z1), (x1, y1, z0), (x0, y1, z0)], material)  # top


def write_sky(path):
    import numpy as np
    import OpenImageIO as oiio
    from make_sky import sky

    img = sky(128, np.array(SUN))
    spec = oiio.ImageSpec(img.shape[1], img.shape[0], 3, "half")
    spec.attribute("compression", "zip")
    out = oiio.ImageOutput.create(path)
    if not out or not out.open(path, spec):
        raise SystemExit(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(img)
    out.close()


def main():
    os.makedirs(OUT, exist_ok=True)
    write_png(os.path.join(OUT, "paving.png"), 64, 64, 3, paving_texture)
    write_png(os.path.join(OUT, "brick.png"), 64, 64, 3, brick_texture)
    write_png(os.path.join(OUT, "plank.png"), 32, 32, 3, plank_texture)
    write_png(os.path.join(OUT, "lattice.png"), 128, 128, 4, lattice_texture)
    write_png(os.path.join(OUT, "leaf.png"), 128, 128, 4, leaf_texture)
    write_sky(os.path.join(OUT, "sky.exr"))

    w = Writer()
    w.doc["asset"]["generator"] = "make_garden_gltf.py"
    del w.doc["extensionsUsed"]
    diffuse = {"metallicFactor": 0, "roughnessFactor": 1}

    def textured(name, uri, **extra):
        return w.material(name, **extra,
                          pbrMetallicRoughness={**diffuse, "baseColorTexture": {"index": w.texture(uri)}})

    paving, brick, plank = textured("paving", "paving.png"), textured("brick", "brick.png"), textured("plank", "plank.png")
    lattice = textured("lattice", "lattice.png", alphaMode="MASK", alphaCutoff=0.5, doubleSided=True)
    leaf = textured("leaf", "leaf.png", alphaMode="MASK", doubleSided=True)

    w.quad([(-6, 0, 6), (6, 0, 6), (6, 0, -6), (-6, 0, -6)], paving, 6.0)  # the yard, 2 m per texture
    w.quad([(-4, 0, -2.5), (1.0, 0, -2.5), (1.0, 1.4, -2.5), (-4, 1.4, -2.5)], brick, 2.5)  # wall, left part
    w.quad([(-1.3, 0, -0.6), (1.7, 0, -0.6), (1.7, 1.9, -0.6), (-1.3, 1.9, -0.6)], lattice)  # the fence
    box(w, (1.4, 0, 0.6), (2.1, 0.6, 1.3), plank)  # the crate
    w.quad([(-1.0, 0.05, 0.6), (-0.3, 0.05, 0.3), (-0.3, 0.9, 0.3), (-1.0, 0.9, 0.6)], leaf)  # two leaf cards
    w.quad([(-1.6, 0.2, 1.2), (-0.9, 0.2, 0.9), (-0.9, 1.0, 1.0), (-1.6, 1.0, 1.3)], leaf)
    camera_node(w, EYE, LOOK, YFOV, name="camera")

    w.doc["buffers"] = [{"uri": "garden.bin", "byteLength": len(w.bin)}]
    with open(os.path.join(OUT, "garden.bin"), "wb") as f:
        f.write(w.bin)
    with open(os.path.join(OUT, "garden.gltf"), "w") as f:
        json.dump(w.doc, f, indent=1)
        f.write("\n")
    with open(os.path.join(OUT, "garden.json"), "w") as f:
        f.write(
            "{\n"
            "  // A yard lit only from outside (tests/data/gltf/make_garden_gltf.py writes this folder): the glTF's\n"
            "  // camera, textures and cut-outs, an equirectangular sky and a sun behind the fence.\n"
            '  "obj": "garden.gltf",\n'
            '  "environment": {"image": "sky.exr", "strength": 1, "rotation_deg": 0},\n'
            f'  "sun": {{"direction": [{SUN[0]}, {SUN[1]}, {SUN[2]}], "angle_deg": 0.53, "irradiance": 3}}\n'
            "}\n"
        )


if __name__ == "__main__":
    main()
