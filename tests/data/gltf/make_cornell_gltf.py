#!/usr/bin/env python3
"""Writes scenes/cornell-box.gltf (+ cornell-box.bin): the Cornell box of
scenes/cornell-box/CornellBox-Original.obj as glTF 2.0, the example of the glTF loader.

One mesh with a primitive per MTL material (indexed triangles; quads split 0-1-2 / 0-2-3), Kd as
baseColorFactor with metallic 0 and roughness 1 (diffuse), Ke as emissiveFactor scaled to [0, 1] with
KHR_materials_emissive_strength holding the rest, and the box's conventional camera as a camera node.

    python3 tests/data/gltf/make_cornell_gltf.py   (from the repository root)
"""
import json
import math
import os
import struct

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
OBJ = os.path.join(ROOT, "scenes", "cornell-box", "CornellBox-Original.obj")
MTL = os.path.join(ROOT, "scenes", "cornell-box", "CornellBox-Original.mtl")
OUT = os.path.join(ROOT, "scenes", "cornell-box")


def read_mtl(path):
    mats, cur = {}, None
    for line in open(path):
        t = line.split("#")[0].split()
        if not t:
            continue
        if t[0] == "newmtl":
            cur = mats.setdefault(t[1], {"Kd": [0.8] * 3, "Ke": [0.0] * 3})
        elif t[0] in ("Kd", "Ke") and cur is not None:
            cur[t[0]] = [float(x) for x in t[1:4]]
    return mats


def read_obj(path):
    verts, faces, mat = [], {}, None
    order = []
    for line in open(path):
        t = line.split("#")[0].split()
        if not t:
            continue
        if t[0] == "v":
            verts.append([float(x) for x in t[1:4]])
        elif t[0] == "usemtl":
            mat = t[1]
            if mat not in faces:
                faces[mat] = []
                order.append(mat)
        elif t[0] == "f":
            idx = [int(c.split("/")[0]) for c in t[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            for k in range(1, len(idx) - 1):
                faces[mat].append((idx[0], idx[k], idx[k + 1]))
    return verts, faces, order


def main():
    mats = read_mtl(MTL)
    verts, faces, order = read_obj(OBJ)
    binary = b""
    views, accessors, primitives, materials = [], [], [], []

    def add(data, target):
        nonlocal binary
        binary += b"\0" * ((4 - len(binary) % 4) % 4)
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(data), "target": target})
        binary += data
        return len(views) - 1

    for name in order:
        tris = faces[name]
        used = sorted({i for t in tris for i in t})
        local = {v: i for i, v in enumerate(used)}
        pos = [verts[v] for v in used]
        pview = add(b"".join(struct.pack("<3f", *p) for p in pos), 34962)
        accessors.append({"bufferView": pview, "componentType": 5126, "count": len(pos), "type": "VEC3",
                          "min": [min(p[k] for p in pos) for k in range(3)],
                          "max": [max(p[k] for p in pos) for k in range(3)]})
        iview = add(b"".join(struct.pack("<3H", *(local[i] for i in t)) for t in tris), 34963)
        accessors.append({"bufferView": iview, "componentType": 5123, "count": 3 * len(tris), "type": "SCALAR"})
        m = mats[name]
        mat = {"name": name, "pbrMetallicRoughness": {"baseColorFactor": m["Kd"] + [1.0], "metallicFactor": 0.0,
                                                     "roughnessFactor": 1.0}}
        strength = max(m["Ke"])
        if strength > 0:
            mat["emissiveFactor"] = [c / strength for c in m["Ke"]]
            mat["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
        materials.append(mat)
        primitives.append({"attributes": {"POSITION": len(accessors) - 2}, "indices": len(accessors) - 1,
                           "material": len(materials) - 1, "mode": 4})

    doc = {
        "asset": {"version": "2.0", "generator": "tests/data/gltf/make_cornell_gltf.py"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "scene": 0,
        "scenes": [{"name": "CornellBox", "nodes": [0, 1]}],
        "nodes": [{"name": "box", "mesh": 0},
                  {"name": "camera", "camera": 0, "translation": [0.0, 1.0, 3.9]}],
        "cameras": [{"type": "perspective",
                     "perspective": {"yfov": math.radians(39.3077), "aspectRatio": 1.0, "znear": 0.1}}],
        "meshes": [{"name": "CornellBox-Original", "primitives": primitives}],
        "materials": materials,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"uri": "cornell-box.bin", "byteLength": len(binary)}],
    }
    with open(OUT + ".bin", "wb") as f:
        f.write(binary)
    with open(OUT + ".gltf", "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")


if __name__ == "__main__":
    main()
