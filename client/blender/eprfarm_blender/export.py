"""The scene as the farm gets it: a glTF 2.0 export of the current frame (meshes and materials,
without cameras and lights) and the active camera as the job's camera."""

import math
import os
from typing import List, NamedTuple, Tuple

import bpy


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
    """What the export leaves out that the scene may rely on."""
    warnings = []
    lamps = [
        f"'{inst.object.name}' ({inst.object.data.type.lower()})"
        for inst in depsgraph.object_instances
        if inst.object.type == "LIGHT"
    ]
    if lamps:
        warnings.append(
            f"light objects are not exported: {', '.join(sorted(set(lamps)))}; the farm is lit by emissive "
            "materials (Principled BSDF Emission colour and strength) on meshes"
        )
    world = scene.world
    if world is not None and world.use_nodes and world.node_tree:
        background = world.node_tree.nodes.get("Background")
        if background is not None:
            colour = background.inputs["Color"].default_value
            strength = background.inputs["Strength"].default_value
            if strength > 0 and max(colour[:3]) > 0:
                warnings.append(f"the world '{world.name}' (background light) is not exported")
    for material in bpy.data.materials:
        if material.users == 0 or not material.use_nodes or material.node_tree is None:
            continue
        kinds = {n.type for n in material.node_tree.nodes}
        if "BSDF_PRINCIPLED" not in kinds and "EMISSION" not in kinds:
            warnings.append(
                f"material '{material.name}' has no Principled BSDF: the glTF exporter writes a default material"
            )
    return warnings


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
        result = _export(path)
    if "FINISHED" not in result or not os.path.exists(path):
        raise ExportError(f"the glTF export to {path} did not finish ({', '.join(result)})")
    return path


def _export(path: str):
    return bpy.ops.export_scene.gltf(
        filepath=path,
        check_existing=False,
        export_format="GLTF_SEPARATE",
        export_image_format="AUTO",
        export_materials="EXPORT",
        export_texcoords=True,
        export_normals=True,
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
