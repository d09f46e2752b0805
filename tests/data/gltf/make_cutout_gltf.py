#!/usr/bin/env python3
"""Writes scenes/cutout-lattice/ (cutout-lattice.gltf, .bin and its textures): the example of cut-outs.

A room corner lit by a ceiling lamp: a checker-tiled floor (a colour texture), a back wall, a wooden
lattice screen whose diamond holes are an alpha mask (alphaMode MASK, alphaCutoff 0.5) and two leaf
cards (a leaf-shaped mask, alphaMode MASK with the default cut-off), so that the lamp casts the
lattice's and the leaves' shadows on the floor and the wall is seen through the holes. The textures
are drawn here (8-bit PNG, written with zlib); everything is the project's own work.

    python3 tests/data/gltf/make_cutout_gltf.py   (from the repository root)
"""
import json
import math
import os
import struct
import zlib

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
OUT = os.path.join(ROOT, "scenes", "cutout-lattice")


def write_png(path, width, height, channels, pixel):
    """pixel(x, y) -> tuple of `channels` values in [0, 255]; row 0 is the top."""
    raw = bytearray()
    for y in range(height):
        raw.append(0)
        for x in range(width):
            raw.extend(int(max(0, min(255, round(v)))) for v in pixel(x, y))
    colour_type = {3: 2, 4: 6}[channels]

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(bytes(raw), 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


def floor_texture(x, y):
    """64 x 64: 8 x 8 tiles, terracotta and cream, with a darker grout line."""
    if x % 8 == 0 or y % 8 == 0:
        return (90, 80, 70)
    return (190, 95, 60) if (x // 8 + y // 8) % 2 == 0 else (225, 210, 180)


def lattice_texture(x, y):
    """128 x 128: laths along both diagonals; between them diamond holes (alpha 0)."""
    u, v = (x + 0.5) / 128, (y + 0.5) / 128
    a, b = (u + v) * 4, (u - v) * 4  # 4 laths per diagonal direction across the texture
    da, db = abs(a - round(a)), abs(b - round(b))
    frame = min(u, v, 1 - u, 1 - v) < 0.04
    solid = frame or da < 0.12 or db < 0.12
    grain = 12 * math.sin(40 * u + 3 * math.sin(9 * v))
    return (150 + grain, 105 + grain, 60 + grain / 2, 255 if solid else 0)


def leaf_texture(x, y):
    """128 x 128: a leaf (pointed ellipse with a stem and a midrib), alpha 0 around it."""
    u, v = (x + 0.5) / 128 * 2 - 1, 1 - (y + 0.5) / 128 * 2  # [-1, 1], v up
    half_width = 0.55 * max(0.0, 1 - v * v) ** 0.8  # pointed at both ends
    inside = abs(u) < half_width and -0.95 < v < 0.95
    stem = abs(u) < 0.03 and -1 < v < -0.6
    vein = abs(u) < 0.015 and abs(v) < 0.9
    if vein or stem:
        return (120, 150, 60, 255)
    return (60, 130 + 40 * v, 40, 255) if inside else (0, 0, 0, 0)


class Writer:
    def __init__(self):
        self.bin = bytearray()
        self.doc = {"asset": {"version": "2.0", "generator": "make_cutout_gltf.py"}, "scene": 0,
                    "scenes": [{"nodes": []}], "nodes": [], "meshes": [], "accessors": [], "bufferViews": [],
                    "materials": [], "textures": [], "images": [], "samplers": [{"magFilter": 9728}],
                    "extensionsUsed": ["KHR_materials_emissive_strength"]}

    def accessor(self, values, fmt, ctype, count, type_, minmax=None):
        while len(self.bin) % 4:
            self.bin.append(0)
        data = struct.pack("<" + fmt * len(values), *values)
        self.doc["bufferViews"].append({"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)})
        self.bin.extend(data)
        acc = {"bufferView": len(self.doc["bufferViews"]) - 1, "componentType": ctype, "count": count, "type": type_}
        if minmax:
            acc["min"], acc["max"] = minmax
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def quad(self, corners, material, uv_scale=1.0):
        """corners a, b, c, d counter-clockwise seen from the front; uv (0,0) at a, (1,1) at c (v down)."""
        pos = [c for p in corners for c in p]
        lo = [min(p[k] for p in corners) for k in range(3)]
        hi = [max(p[k] for p in corners) for k in range(3)]
        s = uv_scale
        uv = [0, s, s, s, s, 0, 0, 0]  # glTF's v runs down the image: a is the image's bottom left
        prim = {"attributes": {"POSITION": self.accessor(pos, "f", 5126, 4, "VEC3", (lo, hi)),
                               "TEXCOORD_0": self.accessor(uv, "f", 5126, 4, "VEC2")},
                "indices": self.accessor([0, 1, 2, 0, 2, 3], "H", 5123, 6, "SCALAR"), "material": material}
        self.doc["meshes"].append({"primitives": [prim]})
        self.doc["nodes"].append({"mesh": len(self.doc["meshes"]) - 1})
        self.doc["scenes"][0]["nodes"].append(len(self.doc["nodes"]) - 1)

    def texture(self, uri):
        self.doc["images"].append({"uri": uri})
        self.doc["textures"].append({"source": len(self.doc["images"]) - 1, "sampler": 0})
        return len(self.doc["textures"]) - 1

    def material(self, name, **m):
        self.doc["materials"].append({"name": name, **m})
        return len(self.doc["materials"]) - 1


def camera_node(w, eye, look, yfov_deg, name=None):
    """A perspective camera at `eye` looking at `look` (up +y): a node turned by yaw, then pitch."""
    f = [l - e for l, e in zip(look, eye)]
    n = math.sqrt(sum(c * c for c in f))
    f = [c / n for c in f]
    yaw, pitch = math.atan2(-f[0], -f[2]), math.asin(f[1])
    qy = (0, math.sin(yaw / 2), 0, math.cos(yaw / 2))
    qx = (math.sin(pitch / 2), 0, 0, math.cos(pitch / 2))
    q = (qy[3] * qx[0], qy[1] * qx[3], -qy[1] * qx[0], qy[3] * qx[3])  # qy * qx
    w.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": math.radians(yfov_deg), "znear": 0.01}}]
    node = {"name": name} if name else {}
    node.update({"camera": 0, "translation": list(eye), "rotation": list(q)})
    w.doc["nodes"].append(node)
    w.doc["scenes"][0]["nodes"].append(len(w.doc["nodes"]) - 1)


def main():
    os.makedirs(OUT, exist_ok=True)
    write_png(os.path.join(OUT, "floor.png"), 64, 64, 3, floor_texture)
    write_png(os.path.join(OUT, "lattice.png"), 128, 128, 4, lattice_texture)
    write_png(os.path.join(OUT, "leaf.png"), 128, 128, 4, leaf_texture)

    w = Writer()
    diffuse = {"metallicFactor": 0, "roughnessFactor": 1}
    floor = w.material("floor", pbrMetallicRoughness={**diffuse, "baseColorTexture": {"index": w.texture("floor.png")}})
    wall = w.material("wall", pbrMetallicRoughness={**diffuse, "baseColorFactor": [0.75, 0.75, 0.7, 1]})
    lattice = w.material("lattice", alphaMode="MASK", alphaCutoff=0.5, doubleSided=True,
                         pbrMetallicRoughness={**diffuse, "baseColorTexture": {"index": w.texture("lattice.png")}})
    leaf = w.material("leaf", alphaMode="MASK", doubleSided=True,
                      pbrMetallicRoughness={**diffuse, "baseColorTexture": {"index": w.texture("leaf.png")}})
    lamp = w.material("lamp", emissiveFactor=[1, 0.95, 0.85],
                      extensions={"KHR_materials_emissive_strength": {"emissiveStrength": 12}},
                      pbrMetallicRoughness={**diffuse, "baseColorFactor": [0, 0, 0, 1]})

    w.quad([(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)], floor, 2.0)  # floor, tiles repeat twice
    w.quad([(-2, 0, -2), (2, 0, -2), (2, 2.6, -2), (-2, 2.6, -2)], wall)  # back wall
    w.quad([(-2, 0, 2), (-2, 0, -2), (-2, 2.6, -2), (-2, 2.6, 2)], wall)  # left wall
    w.quad([(-1.1, 0, -0.8), (0.9, 0, -0.8), (0.9, 1.7, -0.8), (-1.1, 1.7, -0.8)], lattice)  # the screen
    w.quad([(0.5, 0.1, 0.4), (1.2, 0.1, 0.1), (1.2, 0.9, 0.1), (0.5, 0.9, 0.4)], leaf)  # two leaf cards
    w.quad([(0.9, 0.3, 0.9), (1.5, 0.3, 0.5), (1.5, 1.0, 0.6), (0.9, 1.0, 1.0)], leaf)
    w.quad([(-0.5, 2.5, -1.8), (0.5, 2.5, -1.8), (0.5, 2.5, -1.0), (-0.5, 2.5, -1.0)], lamp)  # lamp behind the screen

    # The camera: eye (0.6, 1.3, 3.6) looking at (-0.1, 0.4, -0.8); yfov 40 degrees (the lamp is out of view).
    camera_node(w, (0.6, 1.3, 3.6), (-0.1, 0.4, -0.8), 40)

    w.doc["buffers"] = [{"uri": "cutout-lattice.bin", "byteLength": len(w.bin)}]
    with open(os.path.join(OUT, "cutout-lattice.bin"), "wb") as f_:
        f_.write(w.bin)
    with open(os.path.join(OUT, "cutout-lattice.gltf"), "w") as f_:
        json.dump(w.doc, f_, indent=1)
        f_.write("\n")


if __name__ == "__main__":
    main()
