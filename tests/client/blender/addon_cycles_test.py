#!/usr/bin/python3
"""F12 in Cycles against F12 on the farm for a scene built in the test from Blender's primitives
(scripts/blender_scenes.py, scene "principled"): a floor with a generated checker texture and a
generated normal map (a Normal Map node), a copper sphere (metallic 1, roughness 0.25), a smooth glass
sphere (transmission 1, IOR 1.45), a wall; a square area lamp, a point lamp and a spot lamp; a World
colour. Blender renders it with Cycles (two seeds, 64 spp, 96 x 64) and exports it with the add-on
as its render engine does; `epr render --single-process` renders the export with the add-on's camera
(two seeds, 64 spp, the add-on's default mode, skip).

    addon_cycles_test.py --blender BLENDER --epr EPR

Checked (scripts/addon_cycles_compare.py, compare()):
  - the add-on warns about nothing (every node of the scene is mapped), and its glTF carries the
    floor's base colour texture, normal map and tangents, the copper's metallic 1 and the glass's
    transmission 1 and IOR 1.45;
  - the image mean's luminance, farm / Cycles, within 5 standard errors (from each renderer's two
    seeds) + 2 % for the Principled approximations scenes/README.md names (a Lambertian base where
    Cycles' is Disney's); measured 0.986 +- 0.002;
  - each 8 x 8 block's mean per channel within 5 standard errors (from the per-pixel difference of
    the two seeds, both renderers) + 3 % of the block mean + 1e-4 (blocks of the plain sky have no
    noise); at most 1 % of the 288 block and channel comparisons beyond, but for the row of blocks
    where the floor meets the wall: there the farm is 9-13 % darker from the material models (with
    every material Lambertian they agree: docs/RESULTS.md, "Blender scenes against Cycles"), and the
    test asks only that it is darker, in at most half of the row's comparisons. Measured: 9 beyond, all
    in that row (skip; pt 4).
A lamp left out of the export (the point lamp) moves the mean to 0.84 with 189 blocks beyond.
Run with Debian's /usr/bin/python3 (numpy, OpenImageIO).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, os.path.join(HERE, "..", "..", "..", "scripts"))
import addon_cycles_compare as compare  # noqa: E402

ARGS = argparse.Namespace()
WIDTH, HEIGHT, SPP, SEEDS = 96, 64, 64, (1, 2)
JUNCTION = 4  # the row of 8 x 8 blocks where the floor meets the wall


class AddonAgainstCyclesTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.folder = tempfile.mkdtemp(prefix="epr-addon-cycles-")
        cls.farm = compare.blender_scene(ARGS.blender, "principled", cls.folder, WIDTH, HEIGHT, SPP, SEEDS)
        farm = [
            compare.read_exr(compare.farm_render(ARGS.epr, cls.farm, cls.folder, WIDTH, HEIGHT, SPP, s, "skip"))
            for s in SEEDS
        ]
        cycles = [compare.read_exr(os.path.join(cls.folder, f"cycles_{s}.exr")) for s in SEEDS]
        cls.result = compare.compare(*farm, *cycles, relative=0.03)
        cls.result["warnings"] = cls.farm["warnings"]
        print(compare.report("principled", cls.result), flush=True)
        with open(os.path.join(os.path.dirname(cls.farm["scene"]), "scene.gltf"), encoding="utf-8") as f:
            cls.gltf = json.load(f)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.folder, ignore_errors=True)

    def material(self, name):
        return next(m for m in self.gltf["materials"] if m["name"] == name)

    def test_everything_is_exported(self):
        self.assertEqual(self.farm["warnings"], [])
        floor = self.material("Floor")
        self.assertIn("baseColorTexture", floor["pbrMetallicRoughness"])
        self.assertIn("normalTexture", floor)
        floor_index = self.gltf["materials"].index(floor)
        floor_primitives = [p for m in self.gltf["meshes"] for p in m["primitives"] if p.get("material") == floor_index]
        self.assertEqual(len(floor_primitives), 1)
        self.assertIn("TANGENT", floor_primitives[0]["attributes"])  # Blender's own tangents
        self.assertEqual(self.material("Copper")["pbrMetallicRoughness"].get("metallicFactor", 1.0), 1.0)
        glass = self.material("Glass")["extensions"]
        self.assertEqual(glass["KHR_materials_transmission"]["transmissionFactor"], 1.0)
        self.assertAlmostEqual(glass["KHR_materials_ior"]["ior"], 1.45, places=5)
        with open(self.farm["scene"], encoding="utf-8") as f:
            lights = json.load(f)["lights"]
        self.assertEqual(sorted(light["type"] for light in lights), ["area", "point", "spot"])

    def test_image_mean_within_noise(self):
        r = self.result
        self.assertLessEqual(abs(r["ratio"] - 1.0), 5 * r["ratio_se"] + 0.02, compare.report("principled", r))

    def test_blocks_within_noise(self):
        r = self.result
        report = compare.report("principled", r)
        # Row JUNCTION of blocks is where the floor (roughness 0.6, normal-mapped) meets the wall, seen
        # at grazing angles: there the farm's material model (a Lambertian base where Cycles' is
        # Disney's) is darker, a named approximation. Elsewhere the blocks agree within noise.
        junction = [o for o in r["over"] if o[0] == JUNCTION]
        self.assertLessEqual(len(r["over"]) - len(junction), 0.01 * r["blocks"], report)
        for by, bx, k, ours, ref, tol in junction:
            self.assertLess(ours, ref, f"block ({bx}, {by}) channel {k} brighter than Cycles':\n{report}")
        self.assertLessEqual(len(junction), 0.5 * r["blocks"] / (HEIGHT // 8), report)  # of its 36


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--blender", required=True)
    p.add_argument("--epr", required=True)
    args, rest = p.parse_known_args()
    vars(ARGS).update(vars(args))
    result = unittest.main(argv=[sys.argv[0]] + rest, exit=False).result
    return 0 if result.wasSuccessful() else 1


if __name__ == "__main__":
    sys.exit(main())
