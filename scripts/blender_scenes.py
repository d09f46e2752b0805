"""Scenes built from Blender's primitives and lamps, rendered by Cycles and exported for the farm by
the Blender add-on (client/blender/eprfarm_blender/export.py, as its render engine exports a frame).
Run with Blender (scripts/addon_cycles_compare.py runs it and compares with the farm's renders):

    blender -b --factory-startup -noaudio -P scripts/blender_scenes.py -- --scene principled \
        --folder OUT --width 96 --height 64 --spp 128 --seeds 1,2

Writes OUT/SCENE.blend, OUT/cycles_SEED.exr per seed (Cycles as scripts/cycles_reference.py sets it
up: box filter, no denoising, no clamping, bounce caps of 1024; the scene's own World and lamps), the
add-on's export in OUT/farm/ and OUT/farm.json: the job's scene file, camera and the add-on's warnings.
--lambertian makes every material Lambertian in both (light transport without the materials).

Scenes (Blender's Z-up coordinates, metres):
  principled  a textured, normal-mapped floor (both images generated here), a copper sphere
              (metallic 1, roughness 0.25), a smooth glass sphere (transmission 1, IOR 1.45), a wall;
              a square area lamp, a point lamp and a spot lamp, a dim World colour.
  objects     Suzanne in gold, a chrome torus, a rough steel cube and a normal-mapped tiled slab on a
              floor whose metallic and roughness come from one generated image (glTF's
              metallicRoughnessTexture), under a sky colour and a sun.
  interior    a closed room (4 x 5 x 2.6 m) lit only through a window opening in one wall by a
              sun and a blue sky: a glossy floor, a table with a metal bowl on it.
  sponza      scenes/crytek-sponza/Sponza.gltf through Blender's glTF importer (its camera and
              Principled BSDFs), the courtyard HDRI as the World and sponza.json's sun.
"""

import argparse
import json
import math
import os
import sys
import time
from types import SimpleNamespace

import bpy
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
sys.dont_write_bytecode = True  # no __pycache__ in the source tree
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "client", "blender"))
import cycles_reference  # noqa: E402  (Cycles set up as eprfarm renders)


# ---------------------------------------------------------------------------------------------
# building blocks


def image(name, folder, size, texel, non_color=False):
    """A PNG written to FOLDER from texel(u, v) -> (r, g, b) in [0, 1] (stored values), loaded back as
    an image file (the way a user's texture is)."""
    img = bpy.data.images.new(name + "_gen", size, size, alpha=False)
    pixels = []
    for j in range(size):
        for i in range(size):
            pixels += [*texel((i + 0.5) / size, (j + 0.5) / size), 1.0]
    img.pixels = pixels
    path = os.path.join(folder, name + ".png")
    img.filepath_raw = path
    img.file_format = "PNG"
    img.save()
    bpy.data.images.remove(img)
    loaded = bpy.data.images.load(path)
    if non_color:
        loaded.colorspace_settings.name = "Non-Color"
    return loaded


def bump_normals(tiles, slope):
    """A tangent-space normal map of TILES x TILES round bumps (height sin(pi x) sin(pi y) per tile)."""

    def texel(u, v):
        x, y = (u * tiles) % 1.0, (v * tiles) % 1.0
        dx = slope * math.cos(math.pi * x) * math.sin(math.pi * y)
        dy = slope * math.sin(math.pi * x) * math.cos(math.pi * y)
        n = Vector((-dx, -dy, 1.0)).normalized()
        return [(c + 1.0) / 2.0 for c in n]

    return texel


def principled(name, base=(0.8, 0.8, 0.8), metallic=0.0, roughness=0.5, transmission=0.0, ior=1.45,
               base_image=None, normal_image=None, normal_strength=1.0, mr_image=None):
    """A material of one Principled BSDF; images feed its base colour, its normal (a Normal Map node
    in tangent space) and its metallic (B) and roughness (G) through a Separate Color node."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    p = nt.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (*base, 1.0)
    p.inputs["Metallic"].default_value = metallic
    p.inputs["Roughness"].default_value = roughness
    p.inputs["Transmission"].default_value = transmission
    p.inputs["IOR"].default_value = ior
    if base_image is not None:
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = base_image
        nt.links.new(tex.outputs["Color"], p.inputs["Base Color"])
    if normal_image is not None:
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = normal_image
        nmap = nt.nodes.new("ShaderNodeNormalMap")
        nmap.inputs["Strength"].default_value = normal_strength
        nt.links.new(tex.outputs["Color"], nmap.inputs["Color"])
        nt.links.new(nmap.outputs["Normal"], p.inputs["Normal"])
    if mr_image is not None:
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image = mr_image
        sep = nt.nodes.new("ShaderNodeSeparateColor")
        nt.links.new(tex.outputs["Color"], sep.inputs["Color"])
        nt.links.new(sep.outputs["Blue"], p.inputs["Metallic"])
        nt.links.new(sep.outputs["Green"], p.inputs["Roughness"])
    return mat


def add(obj_op, material, smooth=False, **kw):
    """A primitive made by bpy.ops.mesh.primitive_*_add with one material."""
    obj_op(**kw)
    obj = bpy.context.active_object
    obj.data.materials.append(material)
    if smooth:
        for poly in obj.data.polygons:
            poly.use_smooth = True
    return obj


def lamp(kind, name, location, target=None, **props):
    data = bpy.data.lights.new(name, kind)
    for key, value in props.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    if target is not None:  # the lamp shines along its local -Z
        obj.rotation_euler = (Vector(target) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.collection.objects.link(obj)
    return obj


def camera(location, target, fov_deg):
    data = bpy.data.cameras.new("Camera")
    data.sensor_fit = "VERTICAL"
    data.angle = math.radians(fov_deg)
    obj = bpy.data.objects.new("Camera", data)
    obj.location = location
    obj.rotation_euler = (Vector(target) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.collection.objects.link(obj)
    bpy.context.scene.camera = obj


def world(colour, strength=1.0):
    w = bpy.data.worlds.new("World")
    w.use_nodes = True
    bg = w.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*colour, 1.0)
    bg.inputs["Strength"].default_value = strength
    bpy.context.scene.world = w


# ---------------------------------------------------------------------------------------------
# scenes


def build_principled(folder):
    checker = image("checker", folder, 256, lambda u, v: (0.8, 0.35, 0.2) if (int(u * 8) + int(v * 8)) % 2 else (0.2, 0.45, 0.7))
    bumps = image("bumps", folder, 64, bump_normals(8, 0.8), non_color=True)
    floor = principled("Floor", roughness=0.6, base_image=checker, normal_image=bumps)
    add(bpy.ops.mesh.primitive_plane_add, floor, size=6, location=(0, 0, 0))
    wall = principled("Wall", base=(0.7, 0.7, 0.7), roughness=0.8)
    add(bpy.ops.mesh.primitive_plane_add, wall, size=6, location=(0, 2, 3), rotation=(math.pi / 2, 0, 0))
    copper = principled("Copper", base=(0.95, 0.64, 0.54), metallic=1.0, roughness=0.25)
    add(bpy.ops.mesh.primitive_uv_sphere_add, copper, smooth=True, radius=0.5, location=(-0.75, 0.3, 0.5))
    glass = principled("Glass", base=(1, 1, 1), roughness=0.0, transmission=1.0, ior=1.45)
    add(bpy.ops.mesh.primitive_uv_sphere_add, glass, smooth=True, radius=0.45, location=(0.7, -0.3, 0.45))
    lamp("AREA", "Area", (0, -0.5, 3.2), target=(0, -0.5, 0), energy=300, size=2.0)
    lamp("POINT", "Point", (-2.2, -1.5, 1.8), energy=150, color=(1.0, 0.85, 0.7), shadow_soft_size=0)
    lamp("SPOT", "Spot", (2.4, -1.8, 2.6), target=(0.4, 0.2, 0.2), energy=400, spot_size=math.radians(45),
         spot_blend=0.2, shadow_soft_size=0)
    world((0.05, 0.06, 0.08))
    camera((0, -4.6, 1.7), (0, 0, 0.55), 40)


def build_objects(folder):
    tiles = image("tiles", folder, 64, bump_normals(4, 1.2), non_color=True)
    # metallic (B) and roughness (G): a 4 x 4 checker of polished metal and rough stone
    mr = image("metal_rough", folder, 64, lambda u, v: (0, 0.2, 1) if (int(u * 4) + int(v * 4)) % 2 else (0, 0.7, 0),
               non_color=True)
    ground = principled("Ground", base=(0.6, 0.6, 0.55), mr_image=mr)
    add(bpy.ops.mesh.primitive_plane_add, ground, size=8, location=(0, 0, 0))
    gold = principled("Gold", base=(1.0, 0.77, 0.34), metallic=1.0, roughness=0.3)
    monkey = add(bpy.ops.mesh.primitive_monkey_add, gold, smooth=True, size=1.0, location=(-1.1, 0.4, 0.75))
    monkey.modifiers.new("subdivision", "SUBSURF").levels = 1
    chrome = principled("Chrome", base=(0.9, 0.9, 0.92), metallic=1.0, roughness=0.08)
    add(bpy.ops.mesh.primitive_torus_add, chrome, smooth=True, major_radius=0.5, minor_radius=0.18,
        location=(0.4, -0.4, 0.18))
    steel = principled("Steel", base=(0.56, 0.57, 0.58), metallic=1.0, roughness=0.5)
    add(bpy.ops.mesh.primitive_cube_add, steel, size=0.7, location=(1.4, 0.9, 0.35))
    slab = principled("Tiles", base=(0.75, 0.72, 0.65), roughness=0.4, normal_image=tiles)
    add(bpy.ops.mesh.primitive_cube_add, slab, size=1.0, location=(0.3, 1.8, 0.6), scale=(1.4, 0.1, 0.6))
    lamp("SUN", "Sun", (0, 0, 5), target=(1.0, 1.5, -2.0), energy=3.0, angle=math.radians(2))
    world((0.35, 0.45, 0.6), 1.0)
    camera((0.2, -4.8, 2.2), (0.1, 0.4, 0.5), 42)


def build_interior(folder):
    plaster = principled("Plaster", base=(0.75, 0.73, 0.7), roughness=0.9)
    w, d, h = 4.0, 5.0, 2.6
    # the room's six sides as boxes 0.1 m thick; the window wall (x = +w/2) in four pieces around a
    # 1.4 x 1.2 m opening
    def box(name, centre, size, material):
        obj = add(bpy.ops.mesh.primitive_cube_add, material, size=1.0, location=centre)
        obj.scale = size
        obj.name = name

    floor = principled("Floor", base=(0.45, 0.3, 0.2), roughness=0.3)
    box("floor", (0, 0, -0.05), (w + 0.2, d + 0.2, 0.1), floor)
    box("ceiling", (0, 0, h + 0.05), (w + 0.2, d + 0.2, 0.1), plaster)
    box("back", (0, d / 2 + 0.05, h / 2), (w, 0.1, h), plaster)
    box("front", (0, -d / 2 - 0.05, h / 2), (w, 0.1, h), plaster)
    box("left", (-w / 2 - 0.05, 0, h / 2), (0.1, d, h), plaster)
    y0, y1, z0, z1 = -0.2, 1.2, 0.9, 2.1  # the opening
    x = w / 2 + 0.05
    box("right_low", (x, 0, z0 / 2), (0.1, d, z0), plaster)
    box("right_high", (x, 0, (z1 + h) / 2), (0.1, d, h - z1), plaster)
    box("right_front", (x, (y0 - d / 2) / 2, (z0 + z1) / 2), (0.1, y0 + d / 2, z1 - z0), plaster)
    box("right_back", (x, (y1 + d / 2) / 2, (z0 + z1) / 2), (0.1, d / 2 - y1, z1 - z0), plaster)
    wood = principled("Wood", base=(0.35, 0.2, 0.1), roughness=0.5)
    box("table", (0.3, 0.8, 0.72), (1.2, 0.8, 0.06), wood)
    for sx in (-1, 1):
        for sy in (-1, 1):
            box("leg", (0.3 + sx * 0.52, 0.8 + sy * 0.32, 0.35), (0.06, 0.06, 0.7), wood)
    silver = principled("Silver", base=(0.97, 0.96, 0.91), metallic=1.0, roughness=0.15)
    add(bpy.ops.mesh.primitive_uv_sphere_add, silver, smooth=True, radius=0.2, location=(0.3, 0.8, 0.95))
    lamp("SUN", "Sun", (6, 0, 6), target=(0, 0.5, 0), energy=5.0, angle=math.radians(1))
    world((0.3, 0.45, 0.8), 1.0)
    camera((-1.7, -2.3, 1.5), (0.6, 0.6, 0.9), 60)


def build_sponza(folder):
    """The repository's Crytek Sponza as Blender imports its glTF (its camera, Principled BSDFs from the
    importer), lit as scenes/crytek-sponza/sponza.json lights it: the courtyard HDRI and a sun."""
    import numpy

    if "bool" not in vars(numpy):  # Debian's numpy lacks numpy.bool, which the importer uses
        numpy.bool = bool
    sponza = os.path.join(HERE, "..", "scenes", "crytek-sponza")
    bpy.ops.import_scene.gltf(filepath=os.path.join(sponza, "Sponza.gltf"))
    scene = bpy.context.scene
    scene.camera = next(o for o in scene.objects if o.type == "CAMERA")
    w = bpy.data.worlds.new("World")
    w.use_nodes = True
    env = w.node_tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(os.path.join(sponza, "courtyard.exr"))
    w.node_tree.links.new(env.outputs["Color"], w.node_tree.nodes["Background"].inputs["Color"])
    scene.world = w
    # sponza.json's sun: towards it (0.25, 1.0, 0.15) in glTF's y-up axes, (x, -z, y) in Blender's
    towards = Vector((0.25, -0.15, 1.0))
    lamp("SUN", "Sun", tuple(towards), target=(0, 0, 0), energy=5.0, angle=math.radians(0.53))


SCENES = {"principled": build_principled, "objects": build_objects, "interior": build_interior,
          "sponza": build_sponza}


# ---------------------------------------------------------------------------------------------


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(prog="blender -b --factory-startup -noaudio -P scripts/blender_scenes.py --")
    ap.add_argument("--scene", required=True, choices=sorted(SCENES))
    ap.add_argument("--folder", required=True)
    ap.add_argument("--width", type=int, default=96)
    ap.add_argument("--height", type=int, default=64)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--seeds", default="1,2", help="one Cycles render per seed")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--lambertian", action="store_true",
                    help="both renderers Lambertian: Cycles' materials as cycles_reference.py --gltf makes them, the "
                         "farm's by \"type\": \"diffuse\" overrides (separates light transport from the materials)")
    return ap.parse_args(argv)


def lambertian(job):
    """Every material Lambertian of its base colour, in Cycles and in the farm's scene JSON."""
    names = []
    for mat in bpy.data.materials:
        if mat.users and mat.use_nodes:
            cycles_reference.lambertian_material(mat)
            names.append(mat.name)
    with open(job, encoding="utf-8") as f:
        spec = json.load(f)
    spec["materials"] = {name: {"type": "diffuse"} for name in names}
    with open(job, "w", encoding="utf-8") as f:
        json.dump(spec, f, indent=1)


def export_for_farm(folder):
    """The add-on's export of the current frame, as its render engine makes it (engine.py _render)."""
    from eprfarm_blender import export

    scene = bpy.context.scene
    depsgraph = bpy.context.evaluated_depsgraph_get()
    farm = os.path.join(folder, "farm")
    os.makedirs(farm, exist_ok=True)
    cam, warnings = export.farm_camera(scene, depsgraph)
    warnings += export.scene_warnings(scene, depsgraph)
    lighting, more = export.farm_lighting(scene, depsgraph, farm)
    warnings += more
    job = export.scene_file(export.export_gltf(scene, bpy.context.view_layer, farm), lighting)
    with open(os.path.join(folder, "farm.json"), "w", encoding="utf-8") as f:
        json.dump({"scene": job, "camera": cam._asdict(), "warnings": warnings}, f, indent=1)
    for w in warnings:
        print("blender_scenes: add-on warning: " + w, flush=True)
    return job


def main():
    a = parse_args()
    folder = os.path.abspath(a.folder)
    os.makedirs(folder, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    SCENES[a.scene](folder)
    scene = bpy.context.scene
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(folder, a.scene + ".blend"))
    job = export_for_farm(folder)
    if a.lambertian:
        lambertian(job)
    for seed in [int(s) for s in a.seeds.split(",")]:
        out = os.path.join(folder, "cycles_%d.exr" % seed)
        settings = SimpleNamespace(width=a.width, height=a.height, spp=a.spp, seed=seed, threads=a.threads,
                                   max_bounces=1024, out=out)
        cycles_reference.configure_render(scene, settings, keep_world=True)
        t = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        if not os.path.isfile(out):
            raise SystemExit("Cycles did not write " + out)
        print("blender_scenes: %s: Cycles seed %d: %.2f s" % (a.scene, seed, time.perf_counter() - t), flush=True)


if __name__ == "__main__":
    cycles_reference.run_as_script(main, "blender_scenes")
