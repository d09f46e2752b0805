"""Run inside Blender (blender -b --python make_blend.py -- ARGS): builds the test's .blend from a glTF
scene, set to render with the eprfarm engine, and checks the add-on's camera against the glTF
exporter's.

    blender -b --factory-startup --python make_blend.py -- --addon-dir client/blender
        --package-dir build/client/python --gltf scenes/cornell-box.gltf --master HOST:PORT
        --width 64 --height 64 --spp 64 --blend OUT.blend [--move-camera-at 2]

--move-camera-at F keys the camera at frame 1 where the glTF puts it and at frame F moved 0.3 m to
the side and turned by 4 degrees, so that frames differ.
"""

import argparse
import json
import math
import os
import sys
import tempfile

import addon_utils
import bpy

argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
p = argparse.ArgumentParser()
p.add_argument("--addon-dir", required=True)
p.add_argument("--package-dir", required=True)
p.add_argument("--gltf", required=True)
p.add_argument("--master", required=True)
p.add_argument("--width", type=int, required=True)
p.add_argument("--height", type=int, required=True)
p.add_argument("--spp", type=int, required=True)
p.add_argument("--mode", default="pt")
p.add_argument("--seed", type=int, default=3)
p.add_argument("--blend", required=True)
p.add_argument("--move-camera-at", type=int, default=0)
args = p.parse_args(argv)

import numpy

numpy.bool = bool  # Debian's numpy lacks it; Blender's glTF importer uses it

bpy.ops.wm.read_factory_settings(use_empty=True)
sys.path.insert(0, os.path.abspath(args.addon_dir))
addon_utils.enable("eprfarm_blender", default_set=True)
if "eprfarm_blender" not in bpy.context.preferences.addons:
    sys.exit("make_blend.py: the eprfarm_blender add-on did not enable")
bpy.context.preferences.addons["eprfarm_blender"].preferences.package_path = os.path.abspath(args.package_dir)

bpy.ops.import_scene.gltf(filepath=os.path.abspath(args.gltf))
scene = bpy.context.scene
cameras = [o for o in scene.objects if o.type == "CAMERA"]
if not cameras:
    sys.exit(f"make_blend.py: {args.gltf} has no camera")
camera = cameras[0]
scene.camera = camera
scene.render.engine = "EPRFARM"
scene.render.resolution_x = args.width
scene.render.resolution_y = args.height
scene.render.resolution_percentage = 100
scene.render.image_settings.file_format = "OPEN_EXR"
scene.render.image_settings.color_depth = "32"
scene.render.image_settings.color_mode = "RGB"
s = scene.eprfarm
s.master = args.master
s.samples = args.spp
s.mode = args.mode
s.seed = args.seed
s.show_rounds = True
scene.frame_start = scene.frame_end = scene.frame_current = 1

if args.move_camera_at:
    camera.rotation_mode = "XYZ"
    camera.keyframe_insert("location", frame=1)
    camera.keyframe_insert("rotation_euler", frame=1)
    camera.location.x += 0.3
    camera.rotation_euler.z += math.radians(4.0)
    camera.keyframe_insert("location", frame=args.move_camera_at)
    camera.keyframe_insert("rotation_euler", frame=args.move_camera_at)
    scene.frame_end = args.move_camera_at
    scene.frame_set(1)

# The add-on's camera (eye, look, up, fov) against the camera the glTF exporter writes for the same
# frame: a check of its axis conversion and field of view, here at a non-square size too.
from eprfarm_blender import export

imported_fit = camera.data.sensor_fit
W, H = args.width, args.height
for fit, w, h in ((imported_fit, W, H), ("AUTO", W * 2, H), ("AUTO", W, H * 2), ("HORIZONTAL", W, H * 2)):
    scene.render.resolution_x, scene.render.resolution_y = w, h
    camera.data.sensor_fit = fit
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mine, _ = export.farm_camera(scene, depsgraph)
    folder = tempfile.mkdtemp()
    path = os.path.join(folder, "cam.gltf")
    bpy.ops.export_scene.gltf(filepath=path, export_format="GLTF_SEPARATE", export_cameras=True, use_renderable=True)
    with open(path) as f:
        doc = json.load(f)
    node = next(n for n in doc["nodes"] if "camera" in n)
    yfov = math.degrees(doc["cameras"][node["camera"]]["perspective"]["yfov"])
    eye = node.get("translation", [0, 0, 0])
    if abs(yfov - mine.fov) > 1e-3 or max(abs(a - b) for a, b in zip(eye, mine.eye)) > 1e-4:
        sys.exit(f"make_blend.py: at {w}x{h} the add-on's camera {mine} differs from the exporter's: eye {eye}, "
                 f"yfov {yfov}")
    qx, qy, qz, qw = node.get("rotation", [0, 0, 0, 1])
    # The exporter's -z axis (view direction) and +y axis (up) from its quaternion.
    forward = (-(2 * (qx * qz + qw * qy)), -(2 * (qy * qz - qw * qx)), -(1 - 2 * (qx * qx + qy * qy)))
    up = (2 * (qx * qy - qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz + qw * qx))
    my_forward = [l - e for l, e in zip(mine.look, mine.eye)]
    def far(a, b):
        return max(abs(x - y) for x, y in zip(a, b)) > 1e-4

    if far(forward, my_forward) or far(up, mine.up):
        sys.exit(f"make_blend.py: the add-on's view {my_forward} / up {mine.up} differ from the exporter's "
                 f"{forward} / {up}")
    print(f"make_blend.py: camera at {w}x{h}, sensor fit {fit}, agrees with the exporter's: yfov {yfov:.4f} degrees",
          flush=True)
camera.data.sensor_fit = imported_fit
scene.render.resolution_x, scene.render.resolution_y = args.width, args.height

bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(args.blend))
print(f"make_blend.py: wrote {args.blend}", flush=True)
