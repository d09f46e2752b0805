"""What of a material's node tree the farm renders: Blender's glTF exporter writes a Principled BSDF
(or an Emission shader) as glTF's metallic-roughness material, which the farm reads as its
microfacet material (scenes/README.md, "glTF 2.0"). Everything else in the tree that shapes the
surface is left out or approximated; material_warnings names it, one warning per material."""

from typing import List

# Principled BSDF inputs the farm does not model, with the value at which they do nothing.
IGNORED_INPUTS = (
    ("Subsurface", 0.0, "subsurface scattering"),
    ("Anisotropic", 0.0, "anisotropy"),
    ("Sheen", 0.0, "sheen"),
    ("Clearcoat", 0.0, "clearcoat"),
    ("Transmission Roughness", 0.0, "the refraction takes Roughness"),
    ("Specular", 0.5, "the dielectric reflects as Specular 0.5 (IOR 1.5)"),
    ("Specular Tint", 0.0, "specular tint"),
)
# Inputs the exporter writes only as numbers.
NUMBER_ONLY = ("IOR", "Emission Strength", "Transmission")
IMAGE_NODES = ("TEX_IMAGE",)
LEGACY_SEPARATE = ("SEPRGB", "SEPXYZ")  # Blender's exporter reads their every output as the red channel


def _source(socket):
    """The node feeding an input, or None."""
    return socket.links[0].from_node if socket.is_linked and socket.links else None


def _label(node) -> str:
    return f"node '{node.name}' ({node.bl_label})"


def _image(node, what: str, problems: List[str]) -> None:
    """An Image Texture as the exporter writes it: flat projection, its UV coordinates, repeated."""
    if node.image is None:
        problems.append(f"{_label(node)} feeding {what} has no image (the input's value is used)")
        return
    if node.projection != "FLAT":
        problems.append(f"{_label(node)}: {node.projection.lower()} projection is read as flat (UV)")
    if node.extension != "REPEAT":
        problems.append(f"{_label(node)}: extension {node.extension.lower()} is read as repeat")
    if node.interpolation not in ("Linear", "Closest"):
        problems.append(f"{_label(node)}: {node.interpolation.lower()} interpolation is read as linear")
    mapping = _source(node.inputs["Vector"])
    if mapping is not None and mapping.type not in ("UVMAP", "TEX_COORD"):
        problems.append(f"{_label(mapping)} in front of {_label(node)} is ignored (texture transforms are)")


def _constant(socket) -> bool:
    """Whether the exporter reads SOCKET as a constant: unlinked, or fed by a Value or RGB node."""
    node = _source(socket)
    return node is None or node.type in ("VALUE", "RGB")


def _past_factor(node):
    """The node behind a multiply by a constant, which Blender's glTF exporter writes as the factor
    (metallicFactor, baseColorFactor, ...) of the texture behind it, as its importer builds them: a
    Math node (multiply) for values, a Mix node (colour, multiply, factor 1) for colours. NODE itself
    when it is no such node."""
    if node.type == "MATH" and node.operation == "MULTIPLY":
        pair = node.inputs[0], node.inputs[1]
    elif node.type == "MIX" and node.data_type == "RGBA" and node.blend_type == "MULTIPLY":
        factor = node.inputs[0]
        if factor.is_linked or abs(factor.default_value - 1.0) > 1e-6:
            return node
        pair = node.inputs[6], node.inputs[7]
    else:
        return node
    linked = [s for s in pair if not _constant(s)]
    if len(linked) != 1:
        return node
    behind = _source(linked[0])
    return behind if behind is not None else node


def _texture_input(principled, name: str, problems: List[str], through_separate: bool = False) -> None:
    """An input the exporter writes as a value or an image (through a Separate Color node for metallic
    and roughness), times a constant factor."""
    node = _source(principled.inputs[name])
    if node is None:
        return
    node = _past_factor(node)
    if through_separate and node.type in LEGACY_SEPARATE:
        problems.append(
            f"{_label(node)} feeding {name} is exported as the image's red channel (use a Separate Color node)"
        )
        return
    if through_separate and node.type == "SEPARATE_COLOR":
        if node.mode != "RGB":
            problems.append(f"{_label(node)} feeding {name} separates {node.mode}; the export reads RGB channels")
        node = _source(node.inputs[0])
        if node is None:
            return
    if node.type in IMAGE_NODES:
        _image(node, name, problems)
    else:
        problems.append(f"{_label(node)} feeding {name} is not exported (the farm reads a value or an Image Texture)")


def _normal(principled, problems: List[str]) -> None:
    node = _source(principled.inputs["Normal"])
    if node is None:
        return
    if node.type != "NORMAL_MAP":
        problems.append(f"{_label(node)} feeding Normal is ignored (the farm reads a Normal Map node)")
        return
    if node.space != "TANGENT":
        problems.append(f"{_label(node)}: {node.space.lower()} space is ignored (the farm reads tangent space)")
    if node.inputs["Strength"].is_linked:
        problems.append(f"{_label(node)}: a linked Strength is ignored (the farm reads a number)")
    image = _source(node.inputs["Color"])
    if image is None or image.type not in IMAGE_NODES:
        what = _label(image) if image is not None else "no image"
        problems.append(f"{_label(node)} reads {what}; the farm reads an Image Texture (the map is ignored)")
    else:
        _image(image, "Normal Map", problems)


def _principled(material, principled, problems: List[str]) -> None:
    for name, neutral, what in IGNORED_INPUTS:
        socket = principled.inputs[name]
        if socket.is_linked:
            problems.append(f"{_label(principled)}: {name} is linked and ignored ({what})")
        elif abs(socket.default_value - neutral) > 1e-6:
            problems.append(f"{_label(principled)}: {name} {socket.default_value:.3g} ignored ({what})")
    for name in NUMBER_ONLY:
        node = _source(principled.inputs[name])
        if node is not None:
            problems.append(f"{_label(node)} feeding {name} is ignored (the farm reads a number)")
    for name in ("Clearcoat Normal", "Tangent"):
        if principled.inputs[name].is_linked:
            problems.append(f"{_label(principled)}: {name} is linked and ignored")
    if principled.distribution != "GGX":
        problems.append(f"{_label(principled)}: distribution {principled.distribution} is rendered as GGX")
    _texture_input(principled, "Base Color", problems)
    _texture_input(principled, "Emission", problems)
    _texture_input(principled, "Metallic", problems, through_separate=True)
    _texture_input(principled, "Roughness", problems, through_separate=True)
    _normal(principled, problems)
    alpha = principled.inputs["Alpha"]
    if alpha.is_linked or alpha.default_value < 1.0:
        if material.blend_method in ("BLEND", "HASHED"):
            problems.append(f"blend mode {material.blend_method.lower()} is rendered as a cut-out at alpha 0.5")
        elif material.blend_method == "OPAQUE":
            problems.append("Alpha is ignored in blend mode opaque (Cycles renders it; the farm an opaque surface)")


def material_warnings(material) -> List[str]:
    """One warning naming what MATERIAL's nodes do that the farm does not render (none: [])."""
    if not material.use_nodes or material.node_tree is None:
        return []  # the exporter writes the material's viewport colour
    tree = material.node_tree
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL"]
    output = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    if output is None:
        return [f"material '{material.name}' has no Material Output: the glTF exporter writes a default material"]
    problems = []
    surface = _source(output.inputs["Surface"])
    if surface is None:
        problems.append("its Material Output has no surface (a default material is written)")
    elif surface.type == "BSDF_PRINCIPLED":
        _principled(material, surface, problems)
    elif surface.type == "EMISSION":
        if surface.inputs["Strength"].is_linked:
            problems.append(f"{_label(surface)}: a linked Strength is ignored")
        _texture_input(surface, "Color", problems)
    else:
        problems.append(
            f"{_label(surface)} feeds the surface; the farm reads a Principled BSDF or an Emission shader "
            "(the glTF exporter writes a default material)"
        )
    for name in ("Volume", "Displacement"):
        node = _source(output.inputs[name])
        if node is not None:
            problems.append(f"{_label(node)} on the output's {name} is ignored")
    if not problems:
        return []
    return [f"material '{material.name}': " + "; ".join(problems)]
