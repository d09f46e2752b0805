"""The add-on's preferences (where the eprfarm package is) and the scene's farm settings."""

import os
import sys

import bpy

ADDON = __package__


class EprfarmPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON

    package_path: bpy.props.StringProperty(
        name="eprfarm package folder",
        description=(
            "Folder that holds the eprfarm Python package (the build tree's build/client/python, or a "
            "venv's site-packages); empty: the package installed in Blender's Python"
        ),
        subtype="DIR_PATH",
        default="",
    )

    def draw(self, context):
        self.layout.prop(self, "package_path")
        try:
            client = import_client()
            self.layout.label(text=f"eprfarm package: {os.path.dirname(client.__file__)}", icon="CHECKMARK")
        except ImportError as e:
            self.layout.label(text=str(e), icon="ERROR")


def import_client():
    """The eprfarm package: from the preference's folder when set, else from Blender's Python.
    ImportError with what to do when it cannot be imported."""
    prefs = bpy.context.preferences.addons.get(ADDON)
    folder = bpy.path.abspath(prefs.preferences.package_path) if prefs else ""
    if folder:
        folder = os.path.normpath(folder)
        if not os.path.isdir(os.path.join(folder, "eprfarm")):
            raise ImportError(f"the eprfarm package folder '{folder}' (add-on preferences) has no eprfarm package")
        if folder not in sys.path:
            sys.path.insert(0, folder)
    try:
        import eprfarm
    except ImportError as e:
        raise ImportError(
            f"cannot import the eprfarm Python client ({e}): install client/python into Blender's Python, "
            "or set its folder in the add-on's preferences (client/blender/README.md)"
        ) from None
    return eprfarm


def client_options(s):
    """The eprfarm.Client options of the scene's farm settings."""
    options = {}
    if s.token:
        options["token"] = s.token
    elif s.token_file:
        options["token_file"] = bpy.path.abspath(s.token_file)
    if s.ca_file:
        options["ca_file"] = bpy.path.abspath(s.ca_file)
    elif s.tls:
        options["tls"] = True
    return options


# What a master's refusal for want of the right token says to do: the panel's fields (EprfarmSettings).
TOKEN_HINT = "set the master's token in Render Properties > eprfarm: Token, or Token File"


def farm_client(eprfarm, s):
    """The eprfarm.Client of the scene's farm settings `s`; ValueError for a malformed address, token
    or CA file (the package's message, naming it)."""
    client = eprfarm.Client(s.master, **client_options(s))
    client.token_hint = TOKEN_HINT
    return client


class EprfarmSettings(bpy.types.PropertyGroup):
    master: bpy.props.StringProperty(
        name="Master",
        description="The farm's master, host:port (several: comma-separated, as epr --master)",
        default="localhost:50051",
    )
    token: bpy.props.StringProperty(
        name="Token",
        description="The master's bearer token (saved in the .blend file; prefer a token file)",
        subtype="PASSWORD",
        default="",
    )
    token_file: bpy.props.StringProperty(
        name="Token File", description="File holding the master's bearer token", subtype="FILE_PATH", default=""
    )
    tls: bpy.props.BoolProperty(name="TLS", description="Connect over TLS", default=False)
    ca_file: bpy.props.StringProperty(
        name="CA File", description="PEM file of CA roots for TLS (implies TLS)", subtype="FILE_PATH", default=""
    )
    samples: bpy.props.IntProperty(
        name="Samples", description="Target samples per pixel", default=16, min=1, max=1000000, soft_max=4096
    )
    mode: bpy.props.EnumProperty(
        name="Mode",
        description="How the farm renders",
        items=[
            ("skip", "Reprojection + skipping", "Eye path reprojection with pixel skipping (epr --mode skip)"),
            ("rp", "Reprojection", "Eye path reprojection without skipping (epr --mode rp)"),
            ("pt", "Path tracing", "Plain path tracing (epr --mode pt)"),
        ],
        default="skip",
    )
    seed: bpy.props.IntProperty(name="Seed", description="Random seed of the job", default=1, min=0)
    frame_window: bpy.props.IntProperty(
        name="Frame Window",
        description=(
            "Render Frames on Farm: reproject each frame's paths into the frames up to this many frames away "
            "(the camera may move; the scene must stand still). 0: every frame alone"
        ),
        default=0,
        min=0,
        max=16,
    )
    show_rounds: bpy.props.BoolProperty(
        name="Show Rounds",
        description="Load the job's latest round into the render result while it runs",
        default=True,
    )


classes = (EprfarmPreferences, EprfarmSettings)


def register():
    for c in classes:
        bpy.utils.register_class(c)
    bpy.types.Scene.eprfarm = bpy.props.PointerProperty(type=EprfarmSettings)


def unregister():
    del bpy.types.Scene.eprfarm
    for c in reversed(classes):
        bpy.utils.unregister_class(c)
