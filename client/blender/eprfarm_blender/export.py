"""The scene as the farm gets it: a glTF 2.0 export of the current frame (meshes and materials,
without cameras and lights), the World, the Sun lamps and the point, spot and area lamps as the sky,
sun and "lights" of a scene JSON beside it, and the active camera as the job's camera."""

import json
import math
import os
import shutil
from typing import Dict, List, NamedTuple, Optional, Tuple

import bpy

from . import materials


class ExportError(Exception):
    """A scene the farm cannot render as it is (the message says why and what to change)."""


class FarmCamera(NamedTuple):
    """The job's camera in glTF's Y-up frame: eye, look-at point, up, vertical field of view (degrees)."""

    eye: Tuple[float, float, float]
    look: Tuple[float, float, float]
    up: Tuple[float, float, float]
    fov: float


def _y_up(v) -> Tuple[float, float, float]:
    """Blender's Z-up coordinates as the glTF exporter writes them (+Y up, -Z forward)."""
    return (v[0], v[2], -v[1])


def resolution(scene) -> Tuple[int, int]:
    """The render size in pixels (resolution times its percentage)."""
    r = scene.render
    percent = r.resolution_percentage
    return (max(1, r.resolution_x * percent // 100), max(1, r.resolution_y * percent // 100))


def farm_camera(scene, depsgraph) -> Tuple[FarmCamera, List[str]]:
    """The scene's active camera at the current frame, and warnings about what the farm ignores."""
    if scene.camera is None:
        raise ExportError("the scene has no active camera (Scene properties > Camera)")
    cam = scene.camera.evaluated_get(depsgraph)
    data = cam.data
    if cam.type != "CAMERA":
        raise ExportError(f"the active camera '{cam.name}' is a {cam.type.lower()}, not a camera")
    if data.type != "PERSP":
        raise ExportError(f"camera '{cam.name}' is {data.type.lower()}: the farm renders perspective cameras only")
    warnings = []
    if data.shift_x or data.shift_y:
        warnings.append(f"camera '{cam.name}': lens shift is ignored")
    if data.dof.use_dof:
        warnings.append(f"camera '{cam.name}': depth of field is ignored (a pinhole camera)")
    if scene.render.pixel_aspect_x != scene.render.pixel_aspect_y:
        warnings.append("non-square pixel aspect is ignored")
    # The frame's corners in camera space, for this render's aspect and sensor fit.
    corners = data.view_frame(scene=scene)
    half_height = max(abs(c.y) for c in corners)
    depth = abs(corners[0].z)
    fov = math.degrees(2.0 * math.atan2(half_height, depth))
    m = cam.matrix_world
    rot = m.to_3x3().normalized()
    eye = m.translation
    forward = rot.col[2] * -1.0
    up = rot.col[1]
    look = eye + forward
    return FarmCamera(_y_up(eye), _y_up(look), _y_up(up), fov), warnings


def scene_warnings(scene, depsgraph) -> List[str]:
    """What the export leaves out of the materials the scene renders, one warning per material
    (materials.material_warnings; lamps and worlds: farm_lighting)."""
    used = {}
    for inst in depsgraph.object_instances:  # (an instance lives only during its iteration step)
        for slot in getattr(inst.object, "material_slots", ()):
            if slot.material is not None:
                used[slot.material.name] = slot.material.original
    warnings = []
    for name in sorted(used):
        warnings += materials.material_warnings(used[name])
    return warnings


def farm_lighting(scene, depsgraph, folder: str) -> Tuple[Dict, List[str]]:
    """The scene JSON's "environment", "sun" and "lights" (scenes/README.md, "Sky and sun", "Lamps")
    for the World and the visible lamps, an Environment Texture's image copied into FOLDER; and
    warnings about the lamp and world setups the farm approximates or cannot model. The first Sun lamp
    by name is the "sun" (the one a job's --sun replaces); the other suns and the point, spot and area
    lamps are "lights", in Blender's units (power in W, as Cycles reads it)."""
    lighting, warnings = {}, []
    lamps = []
    for inst in depsgraph.object_instances:  # (an instance lives only during its iteration step)
        if inst.object.type == "LIGHT":
            lamps.append((inst.object.name, inst.object.data, inst.matrix_world.copy()))
    lamps.sort(key=lambda lamp: lamp[0])  # by name: the same order on every frame and machine
    lights = []
    for name, data, matrix in lamps:
        cycles = getattr(data, "cycles", None)  # (Cycles' lamp settings; absent when Cycles is disabled)
        if data.type == "AREA" and getattr(cycles, "is_portal", False):
            continue  # a light portal emits nothing: it only guides Cycles' sampling of the sky
        if not getattr(cycles, "cast_shadow", True):
            warnings.append(f"{data.type.title()} lamp '{name}': Cast Shadow off is ignored (the farm's lamps cast shadows)")
        if data.use_nodes:
            unit = "strength" if data.type == "SUN" else "power"
            warnings.append(f"{data.type.title()} lamp '{name}': its shader nodes are ignored (colour x {unit})")
        if data.type == "SUN":
            if "sun" not in lighting:
                lighting["sun"] = _sun(data, matrix)
            else:
                lights.append({"type": "sun", "name": name, **_sun(data, matrix)})
            continue
        light, problem = _lamp(name, data, matrix)
        if problem:
            warnings.append(problem)
        if light:
            lights.append(light)
    if lights:
        lighting["lights"] = lights
    world = scene.world
    if world is not None:
        environment, problem = _environment(world, folder)
        if problem:
            warnings.append(f"the world '{world.name}' is not exported: {problem}")
        elif environment:
            lighting["environment"] = environment
    return lighting, warnings


def _lamp(name: str, lamp, matrix) -> Tuple[Optional[Dict], str]:
    """A point, spot or area lamp as a scene JSON light (Blender's power in W times its colour; the
    farm converts as Cycles does: intensity P / (4 pi) W/sr for point and spot lamps and point lamps
    with a radius, radiance P / (4 A) for area lamps), and a warning about what it approximates."""
    power = [round(lamp.energy * c, 7) for c in lamp.color]
    rot = matrix.to_3x3()
    position = [round(v, 7) for v in _y_up(matrix.translation)]
    shines = [round(v, 7) for v in _y_up((rot.col[2] * -1.0).normalized())]  # lamps shine along local -Z
    problem = ""
    if lamp.type == "POINT":
        light = {"type": "point", "name": name, "position": position, "power": power}
        if lamp.shadow_soft_size > 0:
            light["radius"] = round(lamp.shadow_soft_size, 7)
        return light, ""
    if lamp.type == "SPOT":
        if lamp.shadow_soft_size > 0:
            problem = f"Spot lamp '{name}': its radius is ignored (a point: hard shadows)"
        return {
            "type": "spot",
            "name": name,
            "position": position,
            "direction": shines,
            "power": power,
            "spot_size_deg": round(math.degrees(lamp.spot_size), 6),
            "spot_blend": round(lamp.spot_blend, 6),
        }, problem
    if lamp.type == "AREA":
        sx = lamp.size
        sy = lamp.size_y if lamp.shape in ("RECTANGLE", "ELLIPSE") else lamp.size
        if getattr(lamp, "spread", math.pi) < math.pi - 1e-6:
            problem = f"Area lamp '{name}': its spread is ignored (it emits as a Lambertian surface, spread 180)"
        if lamp.shape in ("SQUARE", "RECTANGLE"):
            local = [(-sx / 2, -sy / 2), (sx / 2, -sy / 2), (sx / 2, sy / 2), (-sx / 2, sy / 2)]
        else:  # DISK, ELLIPSE: a 32-gon (the farm divides the power by the polygon's area)
            local = [
                (sx / 2 * math.cos(2 * math.pi * k / 32), sy / 2 * math.sin(2 * math.pi * k / 32)) for k in range(32)
            ]
        # Counter-clockwise seen from local -Z, the side the lamp lights: the farm's front.
        corners = [[round(v, 7) for v in _y_up(matrix @ _vector((x, y, 0.0)))] for x, y in reversed(local)]
        return {"type": "area", "name": name, "corners": corners, "power": power}, problem
    return None, f"lamp '{name}' ({lamp.type.lower()}) is not exported"


def _vector(v):
    from mathutils import Vector

    return Vector(v)


def _sun(lamp, matrix) -> Dict:
    """A Sun lamp as the farm's sun: towards the lamp (its local +Z; it shines along -Z), its angle,
    its strength (W/m², as the farm's irradiance) times its colour."""
    towards = _y_up(matrix.to_3x3().normalized().col[2])
    # The farm's disc needs an angle above 0; Blender's 0 (a point-like sun) becomes 0.001 degrees.
    angle = min(90.0, max(1e-3, math.degrees(lamp.angle)))
    irradiance = [lamp.energy * c for c in lamp.color]
    return {"direction": [round(v, 7) for v in towards], "angle_deg": round(angle, 6), "irradiance": irradiance}


def _environment(world, folder: str) -> Tuple[Optional[Dict], str]:
    """The World as the farm's environment (None: it gives no light), or why it cannot be."""
    if not world.use_nodes or world.node_tree is None:
        colour = list(world.color)
        return ({"color": colour} if max(colour) > 0 else None), ""
    tree = world.node_tree
    output = next((n for n in tree.nodes if n.type == "OUTPUT_WORLD" and n.is_active_output), None)
    output = output or next((n for n in tree.nodes if n.type == "OUTPUT_WORLD"), None)
    surface = output.inputs["Surface"] if output else None
    if surface is None or not surface.is_linked:
        return None, ""
    background = surface.links[0].from_node
    if background.type != "BACKGROUND":
        return None, f"its surface is a {background.bl_label} node; the farm reads a Background node"
    if background.inputs["Strength"].is_linked:
        return None, "the Background node's Strength is linked; the farm reads a number"
    strength = background.inputs["Strength"].default_value
    colour = background.inputs["Color"]
    if not colour.is_linked:
        rgb = list(colour.default_value)[:3]
        if strength <= 0 or max(rgb) <= 0:
            return None, ""
        return {"color": rgb, "strength": strength}, ""
    texture = colour.links[0].from_node
    if texture.type != "TEX_ENVIRONMENT" or texture.image is None:
        return None, (
            f"the Background colour comes from a {texture.bl_label} node; the farm reads a colour or an "
            "Environment Texture (equirectangular) image"
        )
    if texture.projection != "EQUIRECTANGULAR":
        return None, f"Environment Texture '{texture.name}' is {texture.projection.lower()}, not equirectangular"
    rotation, problem = _mapping_rotation(texture)
    if problem:
        return None, problem
    image, problem = _copy_image(texture.image, folder)
    if problem:
        return None, problem
    return {"image": image, "strength": strength, "rotation_deg": rotation}, ""


def _mapping_rotation(texture) -> Tuple[float, str]:
    """The rotation about the up axis (degrees) of a Mapping node in front of the texture: the
    farm's rotation_deg (scenes/README.md, "Orientation of the image"); no Mapping node: 0."""
    vector = texture.inputs["Vector"]
    if not vector.is_linked:
        return 0.0, ""
    mapping = vector.links[0].from_node
    if mapping.type != "MAPPING" or mapping.vector_type != "POINT":
        return 0.0, f"Environment Texture '{texture.name}' is mapped by a {mapping.bl_label} node; the farm reads a Mapping node (type Point) that turns it about Z"
    source = mapping.inputs["Vector"]
    if source.is_linked and not (
        source.links[0].from_node.type == "TEX_COORD" and source.links[0].from_socket.name == "Generated"
    ):
        return 0.0, f"Mapping '{mapping.name}' reads other coordinates than Texture Coordinate Generated"
    values = {k: mapping.inputs[k] for k in ("Location", "Rotation", "Scale")}
    if any(s.is_linked for s in values.values()):
        return 0.0, f"Mapping '{mapping.name}' has linked inputs; the farm reads its numbers"
    rx, ry, rz = values["Rotation"].default_value
    if max(abs(v) for v in values["Location"].default_value) > 1e-6 or abs(rx) > 1e-6 or abs(ry) > 1e-6 or max(
        abs(v - 1) for v in values["Scale"].default_value
    ) > 1e-6:
        return 0.0, f"Mapping '{mapping.name}' does more than turn about Z (location 0, rotation X and Y 0, scale 1)"
    return math.degrees(rz), ""


def _copy_image(image, folder: str) -> Tuple[str, str]:
    """The sky image as a file in FOLDER (copied, or written when packed); its name or a problem."""
    path = bpy.path.abspath(image.filepath, library=image.library) if image.filepath else ""
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".hdr", ".exr"):
        return "", f"its sky image '{image.name}' is not an .hdr or .exr file (the farm reads linear HDR images)"
    name = "world" + ext
    if image.packed_file is not None:
        with open(os.path.join(folder, name), "wb") as f:
            f.write(image.packed_file.data)
    elif os.path.isfile(path):
        shutil.copyfile(path, os.path.join(folder, name))
    else:
        return "", f"its sky image '{image.name}' ({path}) does not exist"
    return name, ""


def export_gltf(scene, view_layer, folder: str, name: str = "scene") -> str:
    """Writes the scene's renderable meshes at the current frame with their materials and textures
    as FOLDER/NAME.gltf (with its .bin and images) and returns the path. Runs the glTF exporter in a
    context of the scene and view layer (a render engine's context has neither)."""
    # Debian's numpy has no numpy.bool, which Blender's glTF exporter uses (numpy.bool was bool).
    import numpy

    if "bool" not in vars(numpy):  # (hasattr would warn: numpy 1.24 deprecates the name)
        numpy.bool = bool
    path = os.path.join(folder, name + ".gltf")
    override = {"scene": scene, "view_layer": view_layer}
    windows = [w for wm in bpy.data.window_managers for w in wm.windows]
    if windows:  # the exporter reads the context's active object, a member of a window's context
        override["window"] = windows[0]
    with bpy.context.temp_override(**override):
        result = _export(path, _normal_mapped(scene))
    if "FINISHED" not in result or not os.path.exists(path):
        raise ExportError(f"the glTF export to {path} did not finish ({', '.join(result)})")
    return path


def scene_file(gltf: str, lighting: Dict) -> str:
    """What the job renders: the glTF itself, or with a sky, a sun or lamps a scene JSON beside it
    naming the glTF, the environment, the sun and the lights (the client bundles the JSON, the glTF
    and the sky image)."""
    if not lighting:
        return gltf
    path = os.path.splitext(gltf)[0] + ".json"
    with open(path, "w", encoding="utf-8") as f:
        json.dump({"obj": os.path.basename(gltf), **lighting}, f, indent=1)
    return path


def _normal_mapped(scene) -> bool:
    """Whether a material of the scene's objects has a Normal Map node: then the export carries
    Blender's own (MikkTSpace) tangents, which the farm uses instead of generating its own."""
    for obj in scene.objects:
        for slot in getattr(obj, "material_slots", ()):
            tree = slot.material.node_tree if slot.material is not None and slot.material.use_nodes else None
            if tree is not None and any(n.type == "NORMAL_MAP" for n in tree.nodes):
                return True
    return False


def _export(path: str, tangents: bool):
    return bpy.ops.export_scene.gltf(
        filepath=path,
        check_existing=False,
        export_format="GLTF_SEPARATE",
        export_image_format="AUTO",
        export_materials="EXPORT",
        export_texcoords=True,
        export_normals=True,
        export_tangents=tangents,
        export_colors=False,
        export_cameras=False,
        export_lights=False,
        export_extras=False,
        export_yup=True,
        export_apply=True,
        export_animations=False,
        export_skins=False,
        export_morph=False,
        export_current_frame=True,
        use_renderable=True,
        use_active_scene=True,
        will_save_settings=False,
    )
