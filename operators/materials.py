"""Reading materials as Cycles lights them: diffuse albedo (a constant or an image texture) and emission.

Read: Principled BSDF (Base Color; Emission Color x Strength), Diffuse BSDF (Color), Emission
(Color x Strength, no reflection), through Reroute nodes. A Base Color (or Color) driven by an
Image Texture, directly or through a UV Map or Texture Coordinate (UV) node, is read as a texture:
its pixels in linear RGB (an 8-bit sRGB image decoded as Cycles decodes it), sampled through that
UV map. A Base Color (or Color) driven by a Color Attribute node is read as paint: the mesh's
colour attribute of that name (or its render colour attribute), per face corner, interpolated
across each triangle as Cycles does. Mix (Mix, Multiply, Add, Subtract) and Invert nodes with
constant factors over those are followed where the result is still a tint x texture x paint
(ColourTerm): a texture multiplied by paint, paint mixed with a constant. Anything else that drives
a colour gives the material's viewport colour and one warning naming the material and the node.
"""

from __future__ import annotations

from dataclasses import dataclass, field

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
    """An albedo painted into a colour attribute: its name ('' = the mesh's render colour attribute),
    read as offset + scale x the attribute's colour (scale, offset (3,): a Mix or Invert node on it)."""

    attribute: str
    scale: tuple = (1.0, 1.0, 1.0)
    offset: tuple = (0.0, 0.0, 0.0)

    def colours(self, rgb: np.ndarray) -> np.ndarray:
        return np.asarray(self.offset) + np.asarray(self.scale) * rgb


@dataclass(frozen=True)
class ColourTerm:
    """What a colour socket gives, as tint (3,) x texture x paint (each optional): a constant is
    the tint alone. Mix (Mix, Multiply, Add, Subtract) and Invert nodes with constant factors over
    a constant, an Image Texture and a Color Attribute stay of this form, as long as one side of a
    sum is constant and a product holds at most one texture and one paint."""

    tint: np.ndarray
    texture: MaterialTexture | None = None
    paint: MaterialPaint | None = None

    @property
    def constant(self) -> bool:
        return self.texture is None and self.paint is None


def _affine(term: ColourTerm, scale, offset) -> ColourTerm | None:
    """offset + scale x term, None where that is not a ColourTerm (a texture times paint, shifted)."""
    scale, offset = np.asarray(scale, float) * np.ones(3), np.asarray(offset, float) * np.ones(3)
    if term.constant:
        return ColourTerm(offset + scale * term.tint)
    if term.texture is not None and term.paint is not None:
        return None
    s = scale * term.tint
    if term.texture is not None:
        tex = term.texture
        if np.allclose(s, 1.0) and np.allclose(offset, 0.0):
            return ColourTerm(np.ones(3), tex)
        pixels = np.asarray(offset + s * tex.pixels, np.float32)
        label = f"{tex.image} x{tuple(np.round(s, 6))} +{tuple(np.round(offset, 6))}"
        return ColourTerm(np.ones(3), MaterialTexture(pixels, tex.uv_map, label))
    p = term.paint
    new = MaterialPaint(p.attribute, tuple(s * np.asarray(p.scale)), tuple(offset + s * np.asarray(p.offset)))
    return ColourTerm(np.ones(3), paint=new)


def _combine(a: float, A: ColourTerm, b: float, B: ColourTerm) -> ColourTerm | None:
    """a A + b B, when one side is a constant."""
    if A.constant:
        return _affine(B, b, a * A.tint)
    if B.constant:
        return _affine(A, a, b * B.tint)
    return None


def _product(A: ColourTerm, B: ColourTerm) -> ColourTerm | None:
    """A x B, when they hold at most one texture and one paint between them."""
    if A.texture is not None and B.texture is not None or A.paint is not None and B.paint is not None:
        return None
    return ColourTerm(A.tint * B.tint, A.texture or B.texture, A.paint or B.paint)


def _mix_inputs(node):
    """(blend type, factor socket, A socket, B socket, clamp) of a Mix (colour) or legacy MixRGB node."""
    if node.bl_idname == "ShaderNodeMix":
        if node.data_type != "RGBA":
            return None
        by_id = {s.identifier: s for s in node.inputs}
        return node.blend_type, by_id["Factor_Float"], by_id["A_Color"], by_id["B_Color"], node.clamp_factor
    return node.blend_type, node.inputs["Fac"], node.inputs["Color1"], node.inputs["Color2"], True


@dataclass(frozen=True)
class MaterialLight:
    """reflectance (3,) (the texture's mean where there is one; for paint, what a mesh without the
    attribute gets), emission (3,) radiance, texture, paint."""

    reflectance: np.ndarray
    emission: np.ndarray
    texture: MaterialTexture | None = None
    paint: MaterialPaint | None = None
    tint: np.ndarray = field(default_factory=lambda: np.ones(3))  # a factor on texture x paint
    emitted: ColourTerm | None = None  # an emission colour from a texture or paint (x strength)


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


class _Unread(Exception):
    """A colour the reader cannot follow: the node that stops it, and why."""


def _term(socket, material, depth: int = 0) -> ColourTerm:
    """The ColourTerm a colour socket gives; raises _Unread naming the node it cannot follow."""
    if not socket.is_linked:
        return ColourTerm(np.array(socket.default_value[:3], float))
    node, out = upstream(socket)
    if node is None or depth > 16:
        raise _Unread("nodes")
    kind = node.bl_idname
    if kind == "ShaderNodeVertexColor" and out.name == "Color":
        return ColourTerm(np.ones(3), paint=MaterialPaint(node.layer_name))
    if kind == "ShaderNodeTexImage" and node.image is not None and out.name == "Color":
        uv = _uv_of(node)
        if uv is not None and node.projection == "FLAT":
            px = image_pixels(node.image)
            if px is None:
                raise _Unread(f"image '{node.image.name}' without pixels (missing file?)")
            return ColourTerm(np.ones(3), MaterialTexture(px, uv, node.image.name))
    if kind in ("ShaderNodeMix", "ShaderNodeMixRGB") and (mix := _mix_inputs(node)) is not None:
        blend, fac, a_in, b_in, clamp = mix
        if not fac.is_linked and blend in ("MIX", "MULTIPLY", "ADD", "SUBTRACT"):
            f = float(fac.default_value)
            f = min(max(f, 0.0), 1.0) if clamp else f
            A, B = _term(a_in, material, depth + 1), _term(b_in, material, depth + 1)
            if blend == "MIX":
                got = _combine(1.0 - f, A, f, B)
            elif blend == "ADD":
                got = _combine(1.0, A, f, B)
            elif blend == "SUBTRACT":
                got = _combine(1.0, A, -f, B)
            else:  # MULTIPLY: A x ((1 - f) + f B)
                scaled = _affine(B, f, 1.0 - f)
                got = None if scaled is None else _product(A, scaled)
            if got is not None:
                return got
    if kind == "ShaderNodeInvert" and not node.inputs["Fac"].is_linked:
        f = float(node.inputs["Fac"].default_value)  # c + f (1 - 2c)
        got = _affine(_term(node.inputs["Color"], material, depth + 1), 1.0 - 2.0 * f, f)
        if got is not None:
            return got
    raise _Unread(f"a {node.bl_label} node")


def _colour(socket, what: str, material, warnings: list[str]) -> ColourTerm | None:
    """The ColourTerm of a colour socket; None with a warning if it cannot be read."""
    try:
        return _term(socket, material)
    except _Unread as e:
        warnings.append(
            f"material '{material.name}': {what} is driven by {e}; using the material's viewport colour "
            "(read: a constant, an Image Texture through a UV map, a Color Attribute, and Mix or Invert "
            "nodes over them with constant factors)"
        )
        return None


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
    rho, em, tex, paint, tint, em_term = np.array(DEFAULT_REFLECTANCE), black, None, None, np.ones(3), None
    if kind in ("ShaderNodeBsdfPrincipled", "ShaderNodeBsdfDiffuse"):
        socket = node.inputs["Base Color" if kind == "ShaderNodeBsdfPrincipled" else "Color"]
        term = _colour(socket, socket.name, material, warnings)
        if term is None:
            rho = _viewport(material)
        elif term.constant:
            rho = term.tint
        else:
            tex, paint, tint = term.texture, term.paint, term.tint
            # a mesh without the attribute reads black there, as Cycles renders a missing attribute
            rho = np.zeros(3) if tex is None else tint * tex.pixels.reshape(-1, 3).mean(axis=0)
        if kind == "ShaderNodeBsdfPrincipled":
            em, em_term = _emission(
                node.inputs["Emission Color"], node.inputs["Emission Strength"], material, warnings
            )
    elif kind == "ShaderNodeEmission":
        rho = np.zeros(3)
        em, em_term = _emission(node.inputs["Color"], node.inputs["Strength"], material, warnings)
    else:
        what = "no surface shader" if node is None else f"a {node.bl_label} shader"
        warnings.append(
            f"material '{material.name}' has {what}; using its viewport colour (read: Principled, Diffuse, "
            "Emission)"
        )
        rho = _viewport(material)
    if rho.min() < 0.0 or rho.max() > 1.0:
        warnings.append(
            f"material '{material.name}': reflectance {tuple(np.round(rho, 3))} clamped to [0, 1]"
        )
        rho = np.clip(rho, 0.0, 1.0)
    return MaterialLight(rho, np.maximum(em, 0.0), tex, paint, tint, em_term)


def _emission(colour, strength, material, warnings: list[str]) -> tuple[np.ndarray, ColourTerm | None]:
    """(radiance (3,), varying emission or None): a constant colour x strength, or a colour from a
    texture or paint (read as a base colour is) x strength, which each triangle emits as its mean
    (the radiance is then the texture's mean, for meshes without its UV map or attribute)."""
    if strength.is_linked:
        warnings.append(f"material '{material.name}': an emission strength driven by nodes is ignored")
        return np.zeros(3), None
    s = float(strength.default_value)
    try:
        term = _term(colour, material)
    except _Unread as e:
        warnings.append(f"material '{material.name}': emission colour driven by {e} is ignored")
        return np.zeros(3), None
    if term.constant:
        return term.tint * s, None
    term = ColourTerm(term.tint * s, term.texture, term.paint)
    mean = (
        np.zeros(3) if term.texture is None else term.tint * term.texture.pixels.reshape(-1, 3).mean(axis=0)
    )
    return mean, term
