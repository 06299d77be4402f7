"""Reading materials as Cycles lights them: diffuse albedo (a constant or an image texture) and emission.

Read: Principled BSDF (Base Color; Emission Color x Strength), Diffuse BSDF (Color), Emission
(Color x Strength, no reflection), through Reroute nodes. A Base Color (or Color) driven by an
Image Texture, directly or through a UV Map or Texture Coordinate (UV) node, is read as a texture:
its pixels in linear RGB (an 8-bit sRGB image decoded as Cycles decodes it), sampled through that
UV map. A Base Color (or Color) driven by a Color Attribute node is read as paint: the mesh's
colour attribute of that name (or its render colour attribute), per face corner, interpolated
across each triangle as Cycles does. Anything else that drives a colour gives the material's
viewport colour and one warning naming the material.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import compat

# What a surface gets when its material cannot be read (and what Blender renders without a material).
DEFAULT_REFLECTANCE = (0.8, 0.8, 0.8)
MAX_TEXTURE_SIDE = 2048  # larger images are read at a reduced size (the bake samples them bilinearly)
_LINEAR_SPACES = {
    "Linear",
    "Linear Rec.709",
    "Linear CIE-XYZ E",
    "Linear FilmLight E-Gamut",
    "Non-Color",
    "Raw",
}


@dataclass(frozen=True)
class MaterialTexture:
    """An albedo map: linear RGB pixels (h, w, 3) float32, row 0 at the bottom; the UV map it is
    sampled through ('' = the mesh's active render UV map); its image's name (for messages)."""

    pixels: np.ndarray
    uv_map: str
    image: str


@dataclass(frozen=True)
class MaterialPaint:
    """An albedo painted into a colour attribute: its name ('' = the mesh's render colour attribute)."""

    attribute: str


@dataclass(frozen=True)
class MaterialLight:
    """reflectance (3,) (the texture's mean where there is one; for paint, what a mesh without the
    attribute gets), emission (3,) radiance, texture, paint."""

    reflectance: np.ndarray
    emission: np.ndarray
    texture: MaterialTexture | None = None
    paint: MaterialPaint | None = None


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function, inverted (what Cycles applies to an 8-bit sRGB texture)."""
    c = np.asarray(c, np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_pixels(image) -> np.ndarray | None:
    """All pixels of an image as linear RGB (h, w, 3) float32, row 0 at the bottom (an 8-bit
    sRGB image decoded as Cycles decodes it); None if it has no pixels (a missing file)."""
    w, h = image.size[:]
    if w == 0 or h == 0 or not image.has_data and not _load(image):
        return None
    w, h = image.size[:]
    channels = image.channels
    buf = np.empty(w * h * channels, np.float32)
    image.pixels.foreach_get(buf)
    px = buf.reshape(h, w, channels)
    rgb = px[..., :3] if channels >= 3 else np.repeat(px[..., :1], 3, axis=2)
    if not image.is_float and image.colorspace_settings.name not in _LINEAR_SPACES:
        rgb = srgb_to_linear(rgb)
    return rgb


def image_pixels(image) -> np.ndarray | None:
    """An albedo map's linear RGB pixels (h, w, 3) float32, None if it has no pixels; an image
    larger than MAX_TEXTURE_SIDE is read at every k-th pixel."""
    rgb = linear_pixels(image)
    if rgb is None:
        return None
    step = max(1, -(-max(rgb.shape[:2]) // MAX_TEXTURE_SIDE))
    return np.ascontiguousarray(np.clip(rgb[::step, ::step], 0.0, None), np.float32)


def _load(image) -> bool:
    try:
        image.pixels[0]  # touching the pixels loads the image
    except (IndexError, RuntimeError):
        return False
    return bool(image.has_data)


def upstream(socket):
    """(node, output socket) feeding `socket` through Reroutes; (None, None) if nothing is linked."""
    if not socket.is_linked:
        return None, None
    link = socket.links[0]
    node, out = link.from_node, link.from_socket
    while node.bl_idname == "NodeReroute":
        if not node.inputs[0].is_linked:
            return None, None
        link = node.inputs[0].links[0]
        node, out = link.from_node, link.from_socket
    return node, out


def surface_node(tree):
    """The node feeding the Surface of a node tree's (Cycles) output, None if there is none."""
    out = tree.get_output_node("CYCLES") or tree.get_output_node("ALL")
    return None if out is None else upstream(out.inputs["Surface"])[0]


def _surface_shader(material):
    return None if material.node_tree is None else surface_node(material.node_tree)


def _uv_of(tex_node) -> str | None:
    """The UV map an Image Texture node samples through: '' for the active render map, a name, or
    None when its Vector input is something else (a Mapping node, generated coordinates)."""
    src, src_out = upstream(tex_node.inputs["Vector"])
    if src is None:
        return ""
    if src.bl_idname == "ShaderNodeUVMap":
        return src.uv_map
    if src.bl_idname == "ShaderNodeTexCoord" and src_out.name == "UV":
        return ""
    return None


def _colour(socket, what: str, material, warnings: list[str]):
    """(constant (3,), texture or paint) of a colour socket; (None, None) with a warning if neither
    can be read."""
    if not socket.is_linked:
        return np.array(socket.default_value[:3], float), None
    node, out = upstream(socket)
    if node is not None and node.bl_idname == "ShaderNodeVertexColor" and out.name == "Color":
        return None, MaterialPaint(node.layer_name)
    if node is not None and node.bl_idname == "ShaderNodeTexImage" and node.image is not None:
        uv = _uv_of(node)
        if uv is not None and node.projection == "FLAT":
            px = image_pixels(node.image)
            if px is not None:
                return None, MaterialTexture(px, uv, node.image.name)
            warnings.append(
                f"material '{material.name}': image '{node.image.name}' has no pixels (missing file?); "
                "using the viewport colour"
            )
            return None, None
    kind = node.bl_label if node is not None else "nodes"
    warnings.append(
        f"material '{material.name}': {what} is driven by a {kind} node; using the material's viewport "
        "colour (read: a constant, an Image Texture through a UV map, or a Color Attribute)"
    )
    return None, None


def _viewport(material) -> np.ndarray:
    return np.array(material.diffuse_color[:3], float)


def read_material(material, warnings: list[str]) -> MaterialLight:
    """A material's diffuse albedo and emission as Cycles sees them (see the module docstring)."""
    black = np.zeros(3)
    if material is None:
        return MaterialLight(np.array(DEFAULT_REFLECTANCE), black)
    if not compat.renders_with_nodes(material):
        # A material without nodes renders as a diffuse surface of its viewport colour.
        return MaterialLight(_viewport(material), black)
    node = _surface_shader(material)
    kind = node.bl_idname if node is not None else None
    rho, em, tex, paint = np.array(DEFAULT_REFLECTANCE), black, None, None
    if kind in ("ShaderNodeBsdfPrincipled", "ShaderNodeBsdfDiffuse"):
        socket = node.inputs["Base Color" if kind == "ShaderNodeBsdfPrincipled" else "Color"]
        const, tex = _colour(socket, socket.name, material, warnings)
        if isinstance(tex, MaterialPaint):
            # a mesh without the attribute reads black there, as Cycles renders a missing attribute
            tex, paint, const = None, tex, np.zeros(3)
        rho = const if const is not None else _viewport(material)
        if kind == "ShaderNodeBsdfPrincipled":
            em = _emission(
                node.inputs["Emission Color"], node.inputs["Emission Strength"], material, warnings
            )
    elif kind == "ShaderNodeEmission":
        rho = np.zeros(3)
        em = _emission(node.inputs["Color"], node.inputs["Strength"], material, warnings)
    else:
        what = "no surface shader" if node is None else f"a {node.bl_label} shader"
        warnings.append(
            f"material '{material.name}' has {what}; using its viewport colour (read: Principled, Diffuse, "
            "Emission)"
        )
        rho = _viewport(material)
    if tex is not None:
        rho = tex.pixels.reshape(-1, 3).mean(axis=0).astype(float)
    if rho.min() < 0.0 or rho.max() > 1.0:
        warnings.append(
            f"material '{material.name}': reflectance {tuple(np.round(rho, 3))} clamped to [0, 1]"
        )
        rho = np.clip(rho, 0.0, 1.0)
    return MaterialLight(rho, np.maximum(em, 0.0), tex, paint)


def _emission(colour, strength, material, warnings: list[str]) -> np.ndarray:
    if strength.is_linked or colour.is_linked:
        warnings.append(f"material '{material.name}': emission driven by nodes is ignored")
        return np.zeros(3)
    return np.array(colour.default_value[:3], float) * float(strength.default_value)
