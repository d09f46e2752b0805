"""Independent reference render of an OBJ+MTL or glTF 2.0 scene with Blender Cycles (CPU).

Run with Blender (tested with Debian's Blender 3.4.1):

    blender -b --factory-startup -noaudio -P scripts/cycles_reference.py -- \
        --obj scenes/cornell-box/CornellBox-Original.obj \
        --width 128 --height 128 --spp 4096 --seed 1 --out out.exr

It renders the same light transport model as eprfarm's path tracer:
  * every surface is Lambertian with albedo Kd (Diffuse BSDF, roughness 0);
  * a material with non-zero Ke is additionally a diffuse area emitter of radiance Ke
    (Emission shader, strength 1, added to the Diffuse BSDF). Cycles mesh lights emit from
    both sides of the surface, as ours do, unless the MTL says `emit front` (eprfarm's statement:
    Ke leaves the front side only): then the strength is 1 - Backfacing, as in eprfarm;
  * black background (world strength 0) unless --env gives a sky (a colour or an equirectangular
    image, mapped as eprfarm maps it: build_sky()), and --sun a sun lamp (angle, strength =
    irradiance), as `epr render --env/--sun` take them; no clamping, no denoising, no adaptive sampling,
    bounce caps of 1024 (Cycles' maximum; its Russian roulette is unbiased);
  * pinhole camera given by eye / look-at / up and a VERTICAL field of view;
  * box pixel filter one pixel wide (uniform sample positions inside the pixel);
  * emissive triangles cut into N x N (--emitter-subdiv, default 16): see subdivide_emitters().

The OBJ is parsed here (not with Blender's importer, which rotates axes) and the mesh is built in
the OBJ's own coordinate frame (y up); the camera is placed in that same frame, so nothing is
rotated. Polygons are fan-triangulated like eprfarm's loader does.

--gltf FILE instead imports a glTF 2.0 file with Blender's importer (which turns glTF's y-up frame
into Blender's z-up one: (x, y, z) becomes (x, -z, y)); --eye/--look/--up and --sun stay in glTF's
frame and are turned here, and the sky needs no extra rotation (scenes/README.md, "Orientation of
the image"). The imported cameras and lamps are removed, and each material's Principled BSDF is
replaced by eprfarm's model of it (lambertian_material()): a Lambertian Diffuse BSDF of the base
colour (texture x factor as imported, sRGB, the importer's texel filter), plus an Emission of the
emissive colour x strength, cut out (a Transparent BSDF) where the alpha is below the material's
alpha clip threshold (MASK; BLEND at 0.5, as eprfarm renders it). Normals are the importer's
(smooth where the glTF has NORMAL, flat elsewhere) and the Principled BSDF's normal input (the
imported normal map, with its strength = the glTF scale) feeds the Diffuse BSDF, as eprfarm shades
(scenes/README.md, "Shading normals"). With
--principled the imported materials are kept as they are (Cycles' Principled BSDF: a measure of how
far eprfarm's material model is from Blender's).

Output: a linear (scene-referred) 32-bit float RGB OpenEXR holding raw radiance, row 0 = top
of the image. The render time (seconds, measured around bpy.ops.render.render, so it includes
Cycles' scene sync and BVH build) is printed on one line as `cycles_seconds=<float>`.
"""

import argparse
import math
import os
import sys
import time

import bpy
from mathutils import Matrix, Vector


# ---------------------------------------------------------------------------------------------
# arguments


def parse_vec3(text):
    parts = [p for p in text.replace(" ", "").split(",") if p != ""]
    if len(parts) != 3:
        raise argparse.ArgumentTypeError("expected x,y,z but got %r" % text)
    return Vector([float(p) for p in parts])


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(
        prog="blender -b --factory-startup -noaudio -P scripts/cycles_reference.py --",
        description="Render an OBJ+MTL scene (Lambertian Kd, emissive Ke) with Cycles to a linear EXR.")
    ap.add_argument("--obj", help="OBJ file (its mtllib files are read too)")
    ap.add_argument("--gltf", help="instead of --obj: a glTF 2.0 file (.gltf or .glb), imported by Blender")
    ap.add_argument("--principled", action="store_true",
                    help="with --gltf: keep the imported Principled BSDFs (measures eprfarm's approximation of them)")
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--height", type=int, default=128)
    ap.add_argument("--spp", type=int, default=64, help="samples per pixel")
    ap.add_argument("--seed", type=int, default=0, help="Cycles sampling seed")
    ap.add_argument("--out", required=True, help="output .exr path")
    ap.add_argument("--eye", type=parse_vec3, default=parse_vec3("0,1,3.9"))
    ap.add_argument("--look", type=parse_vec3, default=parse_vec3("0,1,0"))
    ap.add_argument("--up", type=parse_vec3, default=parse_vec3("0,1,0"))
    ap.add_argument("--fov", type=float, default=39.3077, help="VERTICAL field of view, degrees")
    ap.add_argument("--threads", type=int, default=0, help="render threads, 0 = all cores")
    ap.add_argument("--env", default="",
                    help="a sky as `epr render --env`: R,G,B (or one grey) or an equirectangular image file")
    ap.add_argument("--env-strength", type=float, default=1.0)
    ap.add_argument("--env-rotation", type=float, default=0.0, help="degrees about +Y, as rotation_deg")
    ap.add_argument("--sun", default="",
                    help="a sun as `epr render --sun`: DX,DY,DZ[,ANGLE_DEG[,E]] (towards the sun; irradiance W/m^2)")
    ap.add_argument("--lamps", default="",
                    help="a scene JSON whose \"lights\" (point and spot lamps in Blender's units, scenes/README.md, "
                         "\"Lamps\") become Cycles lamps, in the OBJ's frame")
    ap.add_argument("--emitter-subdiv", type=int, default=16,
                    help="split each emissive triangle into N x N (1: as exported)")
    ap.add_argument("--max-bounces", type=int, default=1024,
                    help="Cycles bounce caps (max/diffuse/...); 1024 is Cycles' maximum")
    a = ap.parse_args(argv)
    if bool(a.obj) == bool(a.gltf):
        ap.error("give exactly one of --obj and --gltf")
    if a.width <= 0 or a.height <= 0 or a.spp <= 0:
        ap.error("width, height and spp must be positive")
    if not (0.0 < a.fov < 180.0):
        ap.error("fov must be in (0, 180) degrees")
    if a.threads < 0:
        ap.error("threads must be >= 0")
    return a


# ---------------------------------------------------------------------------------------------
# OBJ / MTL


def strip_comment(line):
    i = line.find("#")
    return line if i < 0 else line[:i]


def read_logical_lines(path):
    """Lines with comments removed and backslash continuations joined."""
    with open(path, "r", encoding="utf-8", errors="replace") as f:
        pending = ""
        for raw in f:
            line = raw.rstrip("\r\n")
            if line.endswith("\\"):
                pending += line[:-1] + " "
                continue
            line = pending + line
            pending = ""
            yield strip_comment(line).strip()
        if pending:
            yield strip_comment(pending).strip()


def parse_mtl(path, materials):
    """Adds {name: {'Kd': (r,g,b), 'Ke': (r,g,b), 'front_only': bool}} from an MTL file to `materials`."""
    current = None
    for line in read_logical_lines(path):
        if not line:
            continue
        tok = line.split()
        key = tok[0]
        if key == "newmtl":
            name = line[len("newmtl"):].strip()
            current = materials.setdefault(name, {"Kd": (0.0, 0.0, 0.0), "Ke": (0.0, 0.0, 0.0), "front_only": False})
        elif current is not None and key == "emit":
            if tok[1:] not in (["front"], ["both"]):
                raise SystemExit("%s: bad line %r (emit front or emit both)" % (path, line))
            current["front_only"] = tok[1] == "front"
        elif current is not None and key in ("Kd", "Ke"):
            vals = tok[1:]
            if vals and vals[0] in ("spectral", "xyz"):
                raise SystemExit("%s: %s %s is not supported (only RGB)" % (path, key, vals[0]))
            nums = [float(v) for v in vals[:3]]
            if len(nums) == 1:
                nums = nums * 3
            if len(nums) != 3:
                raise SystemExit("%s: bad line %r" % (path, line))
            current[key] = tuple(nums)


def parse_obj(path):
    """Returns (vertices, triangles, tri_material_names, materials)."""
    base = os.path.dirname(os.path.abspath(path))
    verts = []
    tris = []
    tri_mat = []
    materials = {}
    current_mat = None
    for lineno, line in enumerate(read_logical_lines(path), 1):
        if not line:
            continue
        tok = line.split()
        key = tok[0]
        if key == "v":
            if len(tok) < 4:
                raise SystemExit("%s:%d: vertex needs 3 coordinates" % (path, lineno))
            verts.append((float(tok[1]), float(tok[2]), float(tok[3])))
        elif key == "f":
            idx = []
            for t in tok[1:]:
                s = t.split("/")[0]
                i = int(s)
                if i > 0:
                    i -= 1                 # 1-based
                elif i < 0:
                    i += len(verts)        # relative: -1 is the last vertex read so far
                else:
                    raise SystemExit("%s:%d: vertex index 0" % (path, lineno))
                if not (0 <= i < len(verts)):
                    raise SystemExit("%s:%d: vertex index %s out of range" % (path, lineno, s))
                idx.append(i)
            if len(idx) < 3:
                continue
            for k in range(1, len(idx) - 1):   # polygon fan around the first vertex
                tris.append((idx[0], idx[k], idx[k + 1]))
                tri_mat.append(current_mat)
        elif key == "usemtl":
            current_mat = line[len("usemtl"):].strip() or None
        elif key == "mtllib":
            # several file names may follow; names with spaces are tried as a whole first
            rest = line[len("mtllib"):].strip()
            candidates = [rest] if os.path.isfile(os.path.join(base, rest)) else rest.split()
            for name in candidates:
                p = name if os.path.isabs(name) else os.path.join(base, name)
                if os.path.isfile(p):
                    parse_mtl(p, materials)
                else:
                    print("cycles_reference: warning: mtllib %s not found" % p, flush=True)
        # vt, vn, g, o, s, l, p ... are ignored
    return verts, tris, tri_mat, materials


# ---------------------------------------------------------------------------------------------
# scene construction


DEFAULT_KD = (0.8, 0.8, 0.8)   # for faces without a (known) material


def make_material(name, kd, ke, front_only=False):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    out.target = "CYCLES"
    diff = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diff.inputs["Color"].default_value = (kd[0], kd[1], kd[2], 1.0)
    diff.inputs["Roughness"].default_value = 0.0       # Lambertian (not Oren-Nayar)
    if any(c != 0.0 for c in ke):
        emit = nt.nodes.new("ShaderNodeEmission")
        emit.inputs["Color"].default_value = (ke[0], ke[1], ke[2], 1.0)
        emit.inputs["Strength"].default_value = 1.0      # radiance = Ke
        if front_only:                                   # no emission seen from the back
            back = nt.nodes.new("ShaderNodeNewGeometry")
            front = nt.nodes.new("ShaderNodeMath")
            front.operation = "SUBTRACT"
            front.inputs[0].default_value = 1.0
            nt.links.new(back.outputs["Backfacing"], front.inputs[1])
            nt.links.new(front.outputs["Value"], emit.inputs["Strength"])
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(emit.outputs["Emission"], add.inputs[0])
        nt.links.new(diff.outputs["BSDF"], add.inputs[1])
        nt.links.new(add.outputs["Shader"], out.inputs["Surface"])
        if hasattr(mat.cycles, "sample_as_light"):       # Blender < 3.5: MIS on (default)
            mat.cycles.sample_as_light = True
    else:
        nt.links.new(diff.outputs["BSDF"], out.inputs["Surface"])
    return mat


def clear_scene():
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj, do_unlink=True)
    for coll in (bpy.data.meshes, bpy.data.materials, bpy.data.cameras, bpy.data.lights):
        for block in list(coll):
            coll.remove(block)


def subdivide_emitters(verts, tris, tri_mat, materials, n):
    """Splits every emissive triangle into n x n congruent triangles (the same surface).

    Cycles 3.4 picks a point on a large emitting triangle with a bias: the conference room's
    1.8 x 0.6 m panels as two triangles each render 0.3 % darker on average, and 1-1.5 % darker on
    the walls that see them at grazing angles, than the same panels cut into 4 x 4 quads (docs/RESULTS.md).
    Small triangles avoid it; the exported geometry and materials are unchanged. 4 x 4 is not enough
    for the hall's skylight (one 30 x 3 m strip, two triangles): cut 4 x 4 it renders 1.0 % darker than
    cut 16 x 16 or 32 x 32 (those two agree within 0.04 %), hence the default of 16 (conference: 16, 8
    and 4 x 4 agree within 0.07 %; Cornell: 16 x 16 and 4 x 4 within 0.07 %)."""
    if n <= 1:
        return verts, tris, tri_mat
    verts = [tuple(v) for v in verts]
    out_tris, out_mat = [], []
    for t, m in zip(tris, tri_mat):
        if not (m in materials and any(materials[m]["Ke"])):
            out_tris.append(t)
            out_mat.append(m)
            continue
        a, b, c = (verts[i] for i in t)
        index = {}

        def point(i, j):  # a + (b - a) i / n + (c - a) j / n, i + j <= n
            if (i, j) not in index:
                index[(i, j)] = len(verts)
                verts.append(tuple(a[k] + (b[k] - a[k]) * i / n + (c[k] - a[k]) * j / n for k in range(3)))
            return index[(i, j)]

        for i in range(n):
            for j in range(n - i):
                out_tris.append((point(i, j), point(i + 1, j), point(i, j + 1)))
                out_mat.append(m)
                if i + j < n - 1:
                    out_tris.append((point(i + 1, j), point(i + 1, j + 1), point(i, j + 1)))
                    out_mat.append(m)
    return verts, out_tris, out_mat


def build_mesh(scene, verts, tris, tri_mat, materials):
    names = []
    index_of = {}
    for m in tri_mat:
        key = m if m in materials else None
        if key not in index_of:
            index_of[key] = len(names)
            names.append(key)
    mesh = bpy.data.meshes.new("obj_mesh")
    mesh.from_pydata([tuple(v) for v in verts], [], [tuple(t) for t in tris])
    for key in names:
        if key is None:
            mesh.materials.append(make_material("__default__", DEFAULT_KD, (0.0, 0.0, 0.0)))
        else:
            m = materials[key]
            mesh.materials.append(make_material(key, m["Kd"], m["Ke"], m["front_only"]))
    mat_idx = [index_of[m if m in materials else None] for m in tri_mat]
    mesh.polygons.foreach_set("material_index", mat_idx)
    mesh.polygons.foreach_set("use_smooth", [False] * len(tris))   # geometric normals
    mesh.update()
    obj = bpy.data.objects.new("obj", mesh)
    scene.collection.objects.link(obj)
    missing = sorted({m for m in tri_mat if m not in materials}, key=str)
    if missing:
        print("cycles_reference: warning: faces without a known material (Kd %s): %s"
              % (DEFAULT_KD, missing), flush=True)
    return obj


def look_at_matrix(eye, look, up):
    """Camera-to-world matrix: Blender cameras look down their local -Z with +Y up."""
    fwd = (look - eye)
    if fwd.length == 0.0:
        raise SystemExit("eye and look-at coincide")
    fwd.normalize()
    right = fwd.cross(up)
    if right.length < 1e-12:
        raise SystemExit("up is parallel to the view direction")
    right.normalize()
    true_up = right.cross(fwd)
    m = Matrix.Identity(4)
    for r in range(3):
        m[r][0] = right[r]
        m[r][1] = true_up[r]
        m[r][2] = -fwd[r]
        m[r][3] = eye[r]
    return m


def build_camera(scene, a):
    cam_data = bpy.data.cameras.new("camera")
    cam_data.type = "PERSP"
    cam_data.sensor_fit = "VERTICAL"
    # With sensor_fit VERTICAL the sensor height spans the image height, so the vertical field of
    # view is 2*atan(sensor_height / (2*lens)). Set lens from it directly (no reliance on `angle`).
    cam_data.sensor_height = 24.0
    cam_data.sensor_width = 24.0 * a.width / a.height
    cam_data.lens = cam_data.sensor_height / (2.0 * math.tan(math.radians(a.fov) / 2.0))
    cam_data.shift_x = 0.0
    cam_data.shift_y = 0.0
    cam_data.clip_start = 1e-4
    cam_data.clip_end = 1e6
    cam_data.dof.use_dof = False
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    cam.matrix_world = look_at_matrix(a.eye, a.look, a.up)
    scene.camera = cam
    return cam


def configure_render(scene, a, keep_world=False):
    """Cycles as eprfarm renders (see the top) into a.out; keep_world keeps the scene's World."""
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.feature_set = "SUPPORTED"
    cy.samples = a.spp
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    if hasattr(cy, "use_preview_denoising"):
        cy.use_preview_denoising = False
    cy.seed = a.seed
    cy.use_animated_seed = False
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    nb = a.max_bounces
    cy.max_bounces = nb
    cy.diffuse_bounces = nb
    cy.glossy_bounces = nb
    cy.transmission_bounces = nb
    cy.volume_bounces = 0
    cy.transparent_max_bounces = nb
    cy.min_light_bounces = 0
    cy.min_transparent_bounces = 0
    cy.blur_glossy = 0.0
    cy.light_sampling_threshold = 0.0     # never skip (roulette) shadow rays of dim lights
    cy.caustics_reflective = True
    cy.caustics_refractive = True
    if hasattr(cy, "use_fast_gi"):
        cy.use_fast_gi = False
    if hasattr(cy, "use_light_tree"):
        cy.use_light_tree = False
    if hasattr(cy, "use_layer_samples"):
        cy.use_layer_samples = "IGNORE"
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    cy.film_exposure = 1.0
    cy.use_auto_tile = False    # one tile: the images are small
    scene.render.film_transparent = False

    scene.render.resolution_x = a.width
    scene.render.resolution_y = a.height
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = 1.0
    scene.render.pixel_aspect_y = 1.0
    scene.render.use_border = False
    scene.render.use_motion_blur = False
    scene.render.use_persistent_data = False
    if a.threads > 0:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = a.threads
    else:
        scene.render.threads_mode = "AUTO"

    # colour management: irrelevant for the float EXR (always written scene-linear), but keep
    # the display side neutral anyway
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.view_settings.use_curve_mapping = False
    scene.sequencer_colorspace_settings.name = "Linear"

    # black world, no light from the background at all, unless --env gives a sky
    world = None if keep_world else scene.world or bpy.data.worlds.new("world")
    if world is not None:
        scene.world = world
        world.use_nodes = True
        nt = world.node_tree
        for n in list(nt.nodes):
            nt.nodes.remove(n)
        bg = nt.nodes.new("ShaderNodeBackground")
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        bg.inputs["Strength"].default_value = 0.0
        wout = nt.nodes.new("ShaderNodeOutputWorld")
        nt.links.new(bg.outputs["Background"], wout.inputs["Surface"])
        build_sky(scene, nt, bg, a)

    # single-layer float EXR with the combined pass only
    vl = scene.view_layers[0]
    vl.use_pass_combined = True
    vl.use_pass_z = False
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    scene.render.dither_intensity = 0.0
    im = scene.render.image_settings
    im.file_format = "OPEN_EXR"
    im.color_mode = "RGB"
    im.color_depth = "32"
    im.exr_codec = "ZIP"
    im.use_preview = False
    if hasattr(im, "color_management"):
        im.color_management = "FOLLOW_SCENE"
    scene.render.use_file_extension = False
    scene.render.filepath = os.path.abspath(a.out)


def blender_frame(v):
    """A direction or point of glTF's y-up frame in the frame Blender's glTF importer builds."""
    return Vector((v[0], -v[2], v[1]))


def build_sky(scene, nt, bg, a):
    """eprfarm's sky and sun (common/lighting.h) in this script's y-up frame. Blender's Environment
    Texture reads a Z-up direction; ours (x, y, z) is (x, -z, y) there, a rotation of +90 degrees
    about X, followed by the sky's rotation about the up axis: a Mapping node (Point) with rotation
    (90, 0, rotation_deg). Nearest-texel lookup ("Closest"), as eprfarm does."""
    if a.env:
        parts = a.env.split(",")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            values = None
        if values is not None:
            rgb = values * 3 if len(values) == 1 else values
            bg.inputs["Color"].default_value = (rgb[0], rgb[1], rgb[2], 1.0)
        else:
            tex = nt.nodes.new("ShaderNodeTexEnvironment")
            tex.image = bpy.data.images.load(os.path.abspath(a.env))
            tex.image.colorspace_settings.name = "Linear"
            tex.interpolation = "Closest"
            coord = nt.nodes.new("ShaderNodeTexCoord")
            mapping = nt.nodes.new("ShaderNodeMapping")
            mapping.vector_type = "POINT"
            turn = 0.0 if getattr(a, "gltf", None) else math.pi / 2  # an imported glTF is z-up already
            mapping.inputs["Rotation"].default_value = (turn, 0.0, math.radians(a.env_rotation))
            nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
            nt.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
            nt.links.new(tex.outputs["Color"], bg.inputs["Color"])
        bg.inputs["Strength"].default_value = a.env_strength
    if a.sun:
        v = [float(p) for p in a.sun.split(",")]
        d = Vector(v[:3]).normalized()
        if getattr(a, "gltf", None):
            d = blender_frame(d)
        light = bpy.data.lights.new("sun", type="SUN")
        light.angle = math.radians(v[3] if len(v) > 3 else 0.53)
        light.energy = v[4] if len(v) > 4 else 1.0
        obj = bpy.data.objects.new("sun", light)
        scene.collection.objects.link(obj)
        obj.rotation_euler = d.to_track_quat("Z", "Y").to_euler()  # the lamp shines along its -Z


def build_lamps(scene, path):
    """The point and spot lamps of a scene JSON's "lights" (power in W, Blender's spot size and blend;
    positions and directions in the OBJ's frame, which this script does not rotate) as Cycles lamps
    with radius 0, as the add-on exports Blender's (client/blender/eprfarm_blender/export.py)."""
    import json

    with open(path, encoding="utf-8") as f:
        lights = json.load(f).get("lights", [])
    for i, light in enumerate(lights):
        rectangle = light["type"] == "area" and len(light.get("corners", [])) == 4
        if light["type"] not in ("point", "spot") and not rectangle or "power" not in light or light.get("radius", 0):
            raise SystemExit("%s: lights[%d]: only point and spot lamps with a power and no radius, and "
                             "rectangular area lamps" % (path, i))
        power = light["power"] if isinstance(light["power"], list) else [light["power"]] * 3
        data = bpy.data.lights.new(light.get("name", "lamp%d" % i), type=light["type"].upper())
        data.energy = max(power)
        data.color = [c / data.energy for c in power] if data.energy > 0 else (1.0, 1.0, 1.0)
        data.shadow_soft_size = 0.0
        obj = bpy.data.objects.new(data.name, data)
        if rectangle:  # corners counter-clockwise seen from the lit side: local X along the first edge, -Z lit
            c = [Vector(p) for p in light["corners"]]
            u, v = c[1] - c[0], c[3] - c[0]
            data.shape = "RECTANGLE"
            data.size, data.size_y = u.length, v.length
            obj.matrix_world = Matrix((
                (*u.normalized(), 0), (*(-v.normalized()), 0), (*u.cross(v).normalized() * -1, 0), (0, 0, 0, 1)
            )).transposed()
            obj.location = (c[0] + c[2]) / 2
            scene.collection.objects.link(obj)
            continue
        obj.location = Vector(light["position"])
        if light["type"] == "spot":
            data.spot_size = math.radians(light["spot_size_deg"])
            data.spot_blend = light.get("spot_blend", 0.0)
            # The lamp shines along its local -Z.
            obj.rotation_euler = Vector(light["direction"]).normalized().to_track_quat("-Z", "Y").to_euler()
        scene.collection.objects.link(obj)


def lambertian_material(mat):
    """Replaces an imported material's Principled BSDF by eprfarm's model of it (see the top)."""
    nt = mat.node_tree if mat.use_nodes else None
    principled = next((n for n in nt.nodes if n.type == "BSDF_PRINCIPLED"), None) if nt else None
    output = next((n for n in nt.nodes if n.type == "OUTPUT_MATERIAL"), None) if nt else None
    if principled is None or output is None:
        raise SystemExit("material %r has no Principled BSDF and output" % mat.name)

    def source(socket):  # what feeds a socket: its link, or its value
        return socket.links[0].from_socket if socket.is_linked else None

    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Roughness"].default_value = 0.0
    if source(principled.inputs["Normal"]):  # the normal map
        nt.links.new(source(principled.inputs["Normal"]), diffuse.inputs["Normal"])
    base = principled.inputs["Base Color"]
    if source(base):
        nt.links.new(source(base), diffuse.inputs["Color"])
    else:
        diffuse.inputs["Color"].default_value = base.default_value
    shader = diffuse.outputs["BSDF"]
    emission, strength = principled.inputs["Emission"], principled.inputs["Emission Strength"].default_value
    if strength > 0 and (source(emission) or any(emission.default_value[:3])):
        emit = nt.nodes.new("ShaderNodeEmission")
        emit.inputs["Strength"].default_value = strength
        if source(emission):
            nt.links.new(source(emission), emit.inputs["Color"])
        else:
            emit.inputs["Color"].default_value = emission.default_value
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(emit.outputs["Emission"], add.inputs[0])
        nt.links.new(shader, add.inputs[1])
        shader = add.outputs["Shader"]
    alpha = principled.inputs["Alpha"]
    if mat.blend_method in ("CLIP", "BLEND", "HASHED") and (source(alpha) or alpha.default_value < 1.0):
        hole = nt.nodes.new("ShaderNodeMath")  # 1 where alpha < cut-off
        hole.operation = "LESS_THAN"
        if source(alpha):
            nt.links.new(source(alpha), hole.inputs[0])
        else:
            hole.inputs[0].default_value = alpha.default_value
        hole.inputs[1].default_value = mat.alpha_threshold if mat.blend_method == "CLIP" else 0.5
        mix = nt.nodes.new("ShaderNodeMixShader")
        nt.links.new(hole.outputs[0], mix.inputs["Fac"])
        nt.links.new(shader, mix.inputs[1])
        nt.links.new(nt.nodes.new("ShaderNodeBsdfTransparent").outputs["BSDF"], mix.inputs[2])
        shader = mix.outputs["Shader"]
    nt.links.new(shader, output.inputs["Surface"])
    nt.nodes.remove(principled)


def import_gltf(scene, a):
    """The glTF's meshes and materials (eprfarm's model of them, the importer's normals); the camera in
    Blender's frame. Returns the triangle count."""
    import numpy

    if "bool" not in vars(numpy):  # Debian's numpy lacks numpy.bool, which the importer uses
        numpy.bool = bool
    result = bpy.ops.import_scene.gltf(filepath=os.path.abspath(a.gltf))
    if "FINISHED" not in result:
        raise SystemExit("%s: the glTF import did not finish" % a.gltf)
    for obj in list(scene.objects):
        if obj.type in ("CAMERA", "LIGHT"):
            bpy.data.objects.remove(obj, do_unlink=True)
    for mat in bpy.data.materials:
        if not getattr(a, "principled", False):
            lambertian_material(mat)
    triangles = 0
    for mesh in bpy.data.meshes:
        mesh.calc_loop_triangles()
        triangles += len(mesh.loop_triangles)
    a.eye, a.look, a.up = blender_frame(a.eye), blender_frame(a.look), blender_frame(a.up)
    return triangles


def main():
    a = parse_args()
    t0 = time.perf_counter()
    if a.gltf:
        clear_scene()
        scene = bpy.context.scene
        triangles = import_gltf(scene, a)
        build_camera(scene, a)
        configure_render(scene, a)
        print("cycles_reference: %s: %d triangles, %d materials; %dx%d, %d spp, seed %d, threads %s, setup %.3f s"
              % (a.gltf, triangles, len(bpy.data.materials), a.width, a.height, a.spp, a.seed,
                 a.threads or "auto", time.perf_counter() - t0), flush=True)
        os.makedirs(os.path.dirname(os.path.abspath(a.out)) or ".", exist_ok=True)
        return render(scene)
    verts, tris, tri_mat, materials = parse_obj(a.obj)
    if not tris:
        raise SystemExit("%s: no faces" % a.obj)
    verts, tris, tri_mat = subdivide_emitters(verts, tris, tri_mat, materials, a.emitter_subdiv)
    clear_scene()
    scene = bpy.context.scene
    build_mesh(scene, verts, tris, tri_mat, materials)
    if a.lamps:
        build_lamps(scene, a.lamps)
    build_camera(scene, a)
    configure_render(scene, a)
    os.makedirs(os.path.dirname(os.path.abspath(a.out)) or ".", exist_ok=True)
    n_emit = sum(1 for m in tri_mat if m in materials and any(materials[m]["Ke"]))
    print("cycles_reference: %s: %d vertices, %d triangles (%d emissive), %d materials; "
          "%dx%d, %d spp, seed %d, threads %s, setup %.3f s"
          % (a.obj, len(verts), len(tris), n_emit, len(materials), a.width, a.height, a.spp,
             a.seed, a.threads or "auto", time.perf_counter() - t0), flush=True)
    render(scene)


def render(scene):
    t = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    seconds = time.perf_counter() - t
    if not os.path.isfile(scene.render.filepath):
        raise SystemExit("render did not write %s" % scene.render.filepath)
    print("cycles_reference: wrote %s" % scene.render.filepath, flush=True)
    print("cycles_seconds=%.6f" % seconds, flush=True)


def run_as_script(entry, name):
    """Runs entry() as Blender's -P script: on an error, prints it (tagged with name) and ends the
    process with status 1 -- Blender ignores a script's exit status in -P mode unless we exit the
    process ourselves."""
    try:
        entry()
    except SystemExit as e:
        if e.code not in (None, 0):
            print("%s: error: %s" % (name, e.code), file=sys.stderr, flush=True)
            sys.stdout.flush()
            os._exit(1)
        raise
    except Exception:
        import traceback
        traceback.print_exc()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(1)


if __name__ == "__main__":
    run_as_script(main, "cycles_reference")
