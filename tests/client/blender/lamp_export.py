"""Blender's lamps as the add-on exports them (client/blender/eprfarm_blender/export.py, farm_lighting),
run inside Blender:

    blender -b --factory-startup --python tests/client/blender/lamp_export.py

A scene built here with a point lamp (with a radius), a spot, a rectangular and a disk area lamp and
two Sun lamps must export every lamp (but a light portal, and a lamp that casts no shadow with a
warning): power times colour in W, positions and directions in glTF's Y-up frame, the spot's cone, the area lamps' corners facing the way they shine, the first sun as
"sun" and the second among "lights". Exits 1 on a failure (unittest's report on stderr)."""

import math
import os
import sys
import tempfile
import unittest

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "..", "client", "blender"))
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
from eprfarm_blender import export  # noqa: E402


def lamp(kind, name, location, rotation=(0.0, 0.0, 0.0), **props):
    data = bpy.data.lights.new(name, kind)
    for key, value in props.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    obj.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(obj)
    return obj


class LampExportTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
        scene.world = None
        lamp("POINT", "A point", (1, 2, 3), energy=100, color=(1, 0.5, 0.25), shadow_soft_size=0.1)
        # Pointing along Blender's +X (turned 90 degrees about Y: local -Z becomes +X... see below).
        lamp("SPOT", "B spot", (0, 0, 4), energy=50, spot_size=math.radians(40), spot_blend=0.25, shadow_soft_size=0)
        lamp("AREA", "C square", (0, 0, 2), energy=20, shape="SQUARE", size=0.5)
        lamp("AREA", "D disk", (0, 0, 2.5), energy=30, shape="DISK", size=1.0)
        lamp("SUN", "E sun", (0, 0, 10), rotation=(0.3, 0, 0), energy=3, angle=math.radians(1))
        lamp("SUN", "F sun", (0, 0, 10), energy=2)
        lamp("AREA", "G portal", (0, 0, 1), energy=10).data.cycles.is_portal = True
        lamp("POINT", "H shadowless", (0, 0, 1), energy=10).data.cycles.cast_shadow = False
        bpy.context.view_layer.update()
        cls.folder = tempfile.mkdtemp(prefix="epr-lamps-")
        cls.lighting, cls.warnings = export.farm_lighting(scene, bpy.context.evaluated_depsgraph_get(), cls.folder)
        cls.lights = {light["name"]: light for light in cls.lighting["lights"]}

    def test_every_lamp_is_exported(self):
        # A light portal emits nothing in Cycles: it is left out.
        self.assertEqual(sorted(self.lights), ["A point", "B spot", "C square", "D disk", "F sun", "H shadowless"])
        self.assertEqual(
            self.warnings, ["Point lamp 'H shadowless': Cast Shadow off is ignored (the farm's lamps cast shadows)"]
        )

    def test_point(self):
        p = self.lights["A point"]
        self.assertEqual(p["type"], "point")
        self.assertEqual(p["power"], [100, 50, 25])
        self.assertEqual(p["position"], [1, 3, -2])  # Blender (x, y, z) is (x, z, -y)
        self.assertAlmostEqual(p["radius"], 0.1, places=6)

    def test_spot(self):
        s = self.lights["B spot"]
        self.assertEqual(s["type"], "spot")
        self.assertAlmostEqual(s["spot_size_deg"], 40, places=4)
        self.assertAlmostEqual(s["spot_blend"], 0.25, places=6)
        for got, want in zip(s["direction"], [0, -1, 0]):  # an unrotated lamp shines down (-Z, our -Y)
            self.assertAlmostEqual(got, want, places=6)

    def test_area_lamps_face_the_way_they_shine(self):
        for name, corners, area in (("C square", 4, 0.25), ("D disk", 32, math.pi * 0.25)):
            a = self.lights[name]
            self.assertEqual(a["type"], "area")
            c = a["corners"]
            self.assertEqual(len(c), corners)
            # The polygon's normal by the right-hand rule (fan from corner 0) points down (-Y): the
            # side an unrotated area lamp lights.
            n = [0.0, 0.0, 0.0]
            for k in range(1, len(c) - 1):
                u = [c[k][i] - c[0][i] for i in range(3)]
                v = [c[k + 1][i] - c[0][i] for i in range(3)]
                cross = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]
                n = [n[i] + cross[i] / 2 for i in range(3)]
            self.assertLess(n[1], 0)
            self.assertAlmostEqual(-n[1], area, delta=0.01 * area)

    def test_suns(self):
        sun = self.lighting["sun"]  # the first by name
        self.assertAlmostEqual(sun["angle_deg"], 1, places=4)
        self.assertEqual(sun["irradiance"], [3, 3, 3])
        self.assertAlmostEqual(sun["direction"][1], math.cos(0.3), places=5)
        other = self.lights["F sun"]
        self.assertEqual(other["type"], "sun")
        self.assertEqual(other["direction"], [0, 1, 0])
        self.assertEqual(other["irradiance"], [2, 2, 2])


if __name__ == "__main__":
    result = unittest.main(argv=[sys.argv[0]], exit=False).result
    sys.exit(0 if result.wasSuccessful() else 1)
