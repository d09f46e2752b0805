"""eprfarm for Blender: a render engine that renders the scene on an eprfarm render farm.

The engine ("eprfarm", in the render properties' engine menu) exports each frame to glTF 2.0,
submits it to the farm's master with the eprfarm Python client (client/python), shows the job's
progress and rounds in Blender and writes the finished image into the render result: F12, Render
Animation, `blender -b file.blend -f 1` and `-a` render on the farm, one frame after the other. The
operator "Render Frames on Farm" (eprfarm.render_frames) queues the whole frame range as one batch
instead, which the farm renders side by side. See client/blender/README.md.
"""

bl_info = {
    "name": "eprfarm",
    "author": "eprfarm",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "Render Properties > Render Engine > eprfarm",
    "description": "Renders the scene on an eprfarm render farm (exported as glTF 2.0)",
    "category": "Render",
}

import bpy

from . import batch, engine, settings


def register():
    settings.register()
    bpy.utils.register_class(engine.EprfarmRenderEngine)
    for c in batch.classes:
        bpy.utils.register_class(c)
    engine.register_panels()


def unregister():
    engine.unregister_panels()
    for c in reversed(batch.classes):
        bpy.utils.unregister_class(c)
    bpy.utils.unregister_class(engine.EprfarmRenderEngine)
    settings.unregister()
