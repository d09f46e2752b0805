"""The add-on's warnings about materials the farm cannot render as Blender does
(client/blender/eprfarm_blender/materials.py, through export.scene_warnings), run inside Blender:

    blender -b --factory-startup --python tests/client/blender/material_warnings.py

Objects with a plain Principled BSDF, one with an image texture, a normal map and metallic-roughness
through Separate Color, one with the factor nodes Blender's glTF importer adds (all exported: no
warning), and materials whose nodes the farm does not render
(subsurface, clearcoat and an alpha in blend mode Opaque, a Bump node, a procedural base colour, a
legacy Separate RGB node, a Glossy BSDF on the output, a world-space normal map, a sum feeding Metallic; and a material no
object uses) must give one warning for each rendered material at fault, naming the material and each
node or input, and none for the rest. Exits 1 on a failure."""

import os
import sys
import tempfile
import unittest

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "..", "client", "blender"))
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
from eprfarm_blender import export  # noqa: E402


def material(name):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    return mat, mat.node_tree, mat.node_tree.nodes["Principled BSDF"]


def image_node(tree, name, folder):
    img = bpy.data.images.new(name, 4, 4)
    img.filepath_raw = os.path.join(folder, name + ".png")
    img.file_format = "PNG"
    img.save()
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.name = name
    tex.image = img
    return tex


def cube(name, mat, x):
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(x, 0, 0))
    obj = bpy.context.active_object
    obj.name = name
    obj.data.materials.append(mat)


class MaterialWarningsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        folder = tempfile.mkdtemp(prefix="epr-materials-")
        plain, _, p = material("Plain")
        p.inputs["Metallic"].default_value = 1.0
        textured, tree, p = material("Textured")
        tree.links.new(image_node(tree, "colour", folder).outputs["Color"], p.inputs["Base Color"])
        nmap = tree.nodes.new("ShaderNodeNormalMap")
        tree.links.new(image_node(tree, "normals", folder).outputs["Color"], nmap.inputs["Color"])
        tree.links.new(nmap.outputs["Normal"], p.inputs["Normal"])
        sep = tree.nodes.new("ShaderNodeSeparateColor")
        tree.links.new(image_node(tree, "mr", folder).outputs["Color"], sep.inputs["Color"])
        tree.links.new(sep.outputs["Blue"], p.inputs["Metallic"])
        tree.links.new(sep.outputs["Green"], p.inputs["Roughness"])
        skin, _, p = material("Skin")
        p.inputs["Subsurface"].default_value = 0.3
        p.inputs["Clearcoat"].default_value = 1.0
        p.inputs["Alpha"].default_value = 0.5  # blend mode opaque: Cycles renders it, the farm cannot
        bumpy, tree, p = material("Bumpy")
        bump = tree.nodes.new("ShaderNodeBump")
        bump.name = "MyBump"
        tree.links.new(bump.outputs["Normal"], p.inputs["Normal"])
        noise = tree.nodes.new("ShaderNodeTexNoise")
        noise.name = "MyNoise"
        tree.links.new(noise.outputs["Color"], p.inputs["Base Color"])
        # Blender's exporter reads a legacy Separate RGB node's outputs as the red channel.
        legacy, tree, p = material("Legacy")
        sep = tree.nodes.new("ShaderNodeSeparateRGB")
        sep.name = "MySeparate"
        tree.links.new(image_node(tree, "mr2", folder).outputs["Color"], sep.inputs["Image"])
        tree.links.new(sep.outputs["B"], p.inputs["Metallic"])
        glossy, tree, p = material("Shiny")
        out = tree.nodes["Material Output"]
        g = tree.nodes.new("ShaderNodeBsdfGlossy")
        g.name = "MyGlossy"
        tree.links.new(g.outputs["BSDF"], out.inputs["Surface"])
        world_normals, tree, p = material("WorldNormals")
        nmap = tree.nodes.new("ShaderNodeNormalMap")
        nmap.name = "MyNormalMap"
        nmap.space = "WORLD"
        tree.links.new(image_node(tree, "wn", folder).outputs["Color"], nmap.inputs["Color"])
        tree.links.new(nmap.outputs["Normal"], p.inputs["Normal"])
        # As Blender's glTF importer builds a material with factors: baseColorFactor x the image through
        # a Mix node (multiply), metallicFactor and roughnessFactor x the channels through Math nodes.
        imported, tree, p = material("Imported")
        mix = tree.nodes.new("ShaderNodeMix")
        mix.data_type, mix.blend_type = "RGBA", "MULTIPLY"
        mix.inputs["Factor"].default_value = 1.0
        mix.inputs[7].default_value = (0.8, 0.5, 0.2, 1.0)
        tree.links.new(image_node(tree, "colour2", folder).outputs["Color"], mix.inputs[6])
        tree.links.new(mix.outputs[2], p.inputs["Base Color"])
        sep = tree.nodes.new("ShaderNodeSeparateColor")
        tree.links.new(image_node(tree, "mr3", folder).outputs["Color"], sep.inputs["Color"])
        for channel, name, factor in (("Blue", "Metallic", 0.5), ("Green", "Roughness", 0.9)):
            times = tree.nodes.new("ShaderNodeMath")
            times.operation = "MULTIPLY"
            times.inputs[1].default_value = factor
            tree.links.new(sep.outputs[channel], times.inputs[0])
            tree.links.new(times.outputs[0], p.inputs[name])
        # A sum is no factor: the exporter leaves the texture out.
        offset, tree, p = material("Offset")
        plus = tree.nodes.new("ShaderNodeMath")
        plus.name, plus.operation = "MyAdd", "ADD"
        sep = tree.nodes.new("ShaderNodeSeparateColor")
        tree.links.new(image_node(tree, "mr4", folder).outputs["Color"], sep.inputs["Color"])
        tree.links.new(sep.outputs["Blue"], plus.inputs[0])
        tree.links.new(plus.outputs[0], p.inputs["Metallic"])
        unused, _, p = material("Unused")
        p.inputs["Sheen"].default_value = 1.0
        for i, mat in enumerate((plain, textured, skin, bumpy, legacy, glossy, world_normals, imported, offset)):
            cube(mat.name + "Cube", mat, i)
        bpy.context.view_layer.update()
        cls.warnings = export.scene_warnings(bpy.context.scene, bpy.context.evaluated_depsgraph_get())
        cls.by_material = {}
        for w in cls.warnings:
            name = w.split("'")[1]
            cls.by_material.setdefault(name, []).append(w)

    def test_one_warning_per_material_at_fault(self):
        self.assertEqual(sorted(self.by_material), ["Bumpy", "Legacy", "Offset", "Shiny", "Skin", "WorldNormals"], self.warnings)
        for name, warnings in self.by_material.items():
            self.assertEqual(len(warnings), 1, warnings)
            self.assertTrue(warnings[0].startswith(f"material '{name}': "), warnings[0])

    def test_ignored_inputs_are_named(self):
        w = self.by_material["Skin"][0]
        self.assertIn("Subsurface 0.3 ignored", w)
        self.assertIn("Clearcoat 1 ignored", w)
        self.assertIn("Alpha is ignored in blend mode opaque", w)

    def test_nodes_are_named(self):
        self.assertIn("node 'MyBump' (Bump) feeding Normal is ignored", self.by_material["Bumpy"][0])
        self.assertIn("node 'MyNoise' (Noise Texture) feeding Base Color is not exported", self.by_material["Bumpy"][0])
        self.assertIn("node 'MyGlossy' (Glossy BSDF) feeds the surface", self.by_material["Shiny"][0])
        self.assertIn(
            "node 'MySeparate' (Separate RGB (Legacy)) feeding Metallic is exported as the image's red channel",
            self.by_material["Legacy"][0],
        )
        self.assertIn("node 'MyNormalMap' (Normal Map): world space is ignored", self.by_material["WorldNormals"][0])
        self.assertIn("node 'MyAdd' (Math) feeding Metallic is not exported", self.by_material["Offset"][0])


if __name__ == "__main__":
    result = unittest.main(argv=[sys.argv[0]], exit=False).result
    sys.exit(0 if result.wasSuccessful() else 1)
