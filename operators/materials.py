"""Reading materials as Cycles lights them: diffuse albedo (a constant or an image texture) and emission.

Read: Principled BSDF (Base Color; Emission Color x Strength), Diffuse BSDF (Color), Emission
(Color x Strength, no reflection), through Reroute nodes. A Base Color (or Color) driven by an
Image Texture, directly or through a UV Map or Texture Coordinate (UV) node, is read as a texture:
its pixels in linear RGB (an 8-bit sRGB image decoded as Cycles decodes it), sampled through that
UV map. A Base Color (or Color) driven by a Color Attribute node is read as paint: the mesh's
colour attribute of that name (or its render colour attribute), per face corner, interpolated
across each triangle as Cycles does. Mix (Mix, Multiply, Add, Subtract) and Invert nodes with
constant factors over those are followed where the result is still a tint x texture x paint
(ColourTerm): a texture multiplied by paint, paint mixed with a constant. Nonlinear nodes with
constant inputs besides their colours, as Cycles computes them: Hue/Saturation/Value, Gamma,
Brightness/Contrast, RGB Curves (tabulated as Cycles tabulates them) and every other Mix blend type
(Screen, Overlay, Divide, Difference, Exclusion, Darken, Lighten, Dodge, Burn, Soft Light, Linear
Light, Hue, Saturation, Color, Value) and a Mix node's clamped result, on a constant, on a texture
(its texels transformed: exact at texel centres, Cycles transforms the filtered colour) or on paint
(each corner's colour transformed, then interpolated: exact where a face has one colour, Cycles
transforms the interpolated colour); a Mix of two textures through one UV map at one size texel by
texel, of paint with the same paint corner by corner. Anything else that drives a colour (a node
on a texture times paint, a linked factor or node input, other nodes) gives the material's
viewport colour and one warning naming the material and the node. An Image Texture whose image has
no pixels (a missing file) is magenta, as Cycles renders it, with a warning naming the image; an
emission colour from one is ignored, with a warning. A Principled BSDF's layers scale its diffuse
light as principled.py says (float_input reads a Separate Color of a constant colour for them).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np

from . import compat, principled
from .colour_math import MIX_BLENDS, CurvesTable, bright_contrast, gamma, hue_saturation_value, mix_colours
from .colour_terms import (
    ColourTerm,
    MaterialPaint,
    MaterialTexture,
    affine,
    apply,
    combine,
    pointwise,
    product,
)
from .images import alpha_pixels, image_pixels

# What a surface gets when its material cannot be read (and what Blender renders without a material).
DEFAULT_REFLECTANCE = (0.8, 0.8, 0.8)


def _mix_inputs(node):
    """(blend type, factor socket, A socket, B socket, clamp) of a Mix (colour) or legacy MixRGB node."""
    if node.bl_idname == "ShaderNodeMix":
        if node.data_type != "RGBA":
            return None
        by_id = {s.identifier: s for s in node.inputs}
        return node.blend_type, by_id["Factor_Float"], by_id["A_Color"], by_id["B_Color"], node.clamp_factor
    return node.blend_type, node.inputs["Fac"], node.inputs["Color1"], node.inputs["Color2"], True


def _clamps_result(node) -> bool:
    """Whether a Mix (colour) node clamps its result to [0, 1] (the legacy MixRGB node's Clamp)."""
    return bool(node.clamp_result if node.bl_idname == "ShaderNodeMix" else node.use_clamp)


def _constants(node, *names) -> list[float] | None:
    """The values of a node's float inputs (by identifier), None if any is linked."""
    by_id = {s.identifier: s for s in node.inputs}
    if any(by_id[n].is_linked for n in names):
        return None
    return [float(by_id[n].default_value) for n in names]


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
    alpha: MaterialAlpha = field(default_factory=lambda: MaterialAlpha())  # the share that is there
    bake_weight: float = 1.0  # the share of its diffuse light a bake reports (principled.bake_weight)


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


# What Cycles renders an image without pixels (a missing file) as: magenta, alpha 1.
MISSING_RGB = (1.0, 0.0, 1.0)


def _term(socket, material, depth: int = 0, missing: list[str] | None = None) -> ColourTerm:
    """The ColourTerm a colour socket gives; raises _Unread naming the node it cannot follow. An
    Image Texture without pixels gives MISSING_RGB, as Cycles renders it, its name added to missing."""
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
                if missing is not None:
                    missing.append(node.image.name)
                return ColourTerm(np.array(MISSING_RGB))
            return ColourTerm(np.ones(3), MaterialTexture(px[0], uv, node.image.name, px[1]))
    label = f"{material.name}: {node.name}"  # names a texture's pixels after a nonlinear node
    if kind in ("ShaderNodeMix", "ShaderNodeMixRGB") and (mix := _mix_inputs(node)) is not None:
        blend, fac, a_in, b_in, clamp = mix
        if not fac.is_linked and blend in MIX_BLENDS:
            f = float(fac.default_value)
            f = min(max(f, 0.0), 1.0) if clamp else f
            A, B = _term(a_in, material, depth + 1, missing), _term(b_in, material, depth + 1, missing)
            got = None
            if blend == "MIX":
                got = combine(1.0 - f, A, f, B)
            elif blend == "ADD":
                got = combine(1.0, A, f, B)
            elif blend == "SUBTRACT":
                got = combine(1.0, A, -f, B)
            elif blend == "MULTIPLY":  # A x ((1 - f) + f B)
                scaled = affine(B, f, 1.0 - f)
                got = None if scaled is None else product(A, scaled)
            if got is None:  # the other blend types, and two textures or paints, texel by texel
                got = pointwise(A, B, lambda a, b: mix_colours(blend, f, a, b), label)
            if got is not None and _clamps_result(node):
                got = apply(got, lambda c: np.clip(c, 0.0, 1.0), label)
            if got is not None:
                return got
    if kind == "ShaderNodeInvert" and not node.inputs["Fac"].is_linked:
        f = float(node.inputs["Fac"].default_value)  # c + f (1 - 2c)
        got = affine(_term(node.inputs["Color"], material, depth + 1, missing), 1.0 - 2.0 * f, f)
        if got is not None:
            return got
    fn = None
    if kind == "ShaderNodeHueSaturation" and (v := _constants(node, "Hue", "Saturation", "Value", "Fac")):
        fn = partial(hue_saturation_value, hue=v[0], saturation=v[1], value=v[2], fac=v[3])
    elif kind == "ShaderNodeGamma" and (v := _constants(node, "Gamma")):
        fn = partial(gamma, g=v[0])
    elif kind == "ShaderNodeBrightContrast" and (v := _constants(node, "Bright", "Contrast")):
        fn = partial(bright_contrast, bright=v[0], contrast=v[1])
    elif kind == "ShaderNodeRGBCurve" and (v := _constants(node, "Fac")):
        fn = partial(CurvesTable.of(node.mapping), fac=v[0])
    if fn is not None:
        got = apply(_term(node.inputs["Color"], material, depth + 1, missing), fn, label)
        if got is not None:
            return got
    raise _Unread(f"a {node.bl_label} node")


def _colour(socket, what: str, material, warnings: list[str]) -> ColourTerm | None:
    """The ColourTerm of a colour socket; None with a warning if it cannot be read."""
    missing: list[str] = []
    try:
        term = _term(socket, material, missing=missing)
        _warn_missing(material, what, missing, warnings)
        return term
    except _Unread as e:
        warnings.append(
            f"material '{material.name}': {what} is driven by {e}; using the material's viewport colour "
            "(read: a constant, an Image Texture through a UV map, a Color Attribute, and over them Mix, "
            "Invert, Hue/Saturation/Value, Gamma, Brightness/Contrast and RGB Curves nodes with constant "
            "factors and settings)"
        )
        return None


def float_input(socket, material) -> float | None:
    """A float input driven by a Separate Color node (RGB) of a constant colour (an Image Texture
    whose file is missing included: a glTF import's metallic and roughness): that channel; None
    for anything else."""
    node, out = upstream(socket)
    if node is None or node.bl_idname != "ShaderNodeSeparateColor" or node.mode != "RGB":
        return None
    channel = {"Red": 0, "Green": 1, "Blue": 2}.get(out.name)
    if channel is None:
        return None
    try:
        term = _term(node.inputs["Color"], material)
    except _Unread:
        return None
    return float(term.tint[channel]) if term.constant else None


def _warn_missing(material, what: str, missing: list[str], warnings: list[str]) -> None:
    for name in dict.fromkeys(missing):
        warnings.append(
            f"material '{material.name}': image '{name}' has no pixels (missing file?); its {what} is "
            "read as Cycles renders it: magenta"
        )


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
    node, cut = _past_transparent(_surface_shader(material), material, warnings)
    kind = node.bl_idname if node is not None else None
    rho, em, tex, paint, tint, em_term = np.array(DEFAULT_REFLECTANCE), black, None, None, np.ones(3), None
    weight = 1.0
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
            # the metallic and transmission lobes' shares are no diffuse light
            linked = partial(float_input, material=material)
            kept = principled.transport_factor(node, linked)
            rho, tint = rho * kept, tint * kept
            weight = principled.bake_weight(node, linked)
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
    alpha = cut
    if kind == "ShaderNodeBsdfPrincipled":
        alpha = _both(cut, _alpha(node.inputs["Alpha"], material, warnings), material, warnings)
    return MaterialLight(rho, np.maximum(em, 0.0), tex, paint, tint, em_term, alpha, weight)


def _emission(colour, strength, material, warnings: list[str]) -> tuple[np.ndarray, ColourTerm | None]:
    """(radiance (3,), varying emission or None): a constant colour x strength, or a colour from a
    texture or paint (read as a base colour is) x strength, which each triangle emits as its mean
    (the radiance is then the texture's mean, for meshes without its UV map or attribute)."""
    if strength.is_linked:
        warnings.append(f"material '{material.name}': an emission strength driven by nodes is ignored")
        return np.zeros(3), None
    s = float(strength.default_value)
    missing: list[str] = []
    try:
        term = _term(colour, material, missing=missing)
    except _Unread as e:
        warnings.append(f"material '{material.name}': emission colour driven by {e} is ignored")
        return np.zeros(3), None
    if missing:
        # Cycles renders it magenta over the whole mesh: a large emitter next to its own receivers,
        # whose exact near field (light.tree) a bake cannot afford
        names = ", ".join(f"'{n}'" for n in dict.fromkeys(missing))
        warnings.append(
            f"material '{material.name}': emission colour from image {names} without pixels (missing "
            "file?) is ignored (Cycles renders it magenta)"
        )
        return np.zeros(3), None
    if term.constant:
        return term.tint * s, None
    term = ColourTerm(term.tint * s, term.texture, term.paint)
    mean = (
        np.zeros(3) if term.texture is None else term.tint * term.texture.pixels.reshape(-1, 3).mean(axis=0)
    )
    return mean, term


# --------------------------------------------------------------------------- alpha


@dataclass(frozen=True)
class MaterialAlpha:
    """A material's alpha (Cycles: alpha x the shader + (1 - alpha) x transparent): a constant in
    [0, 1], times an alpha map where there is one (pixels (h, w) float32 in [0, 1], row 0 at the
    bottom, sampled through uv_map as an albedo map is; image: its name, for messages)."""

    constant: float = 1.0
    pixels: np.ndarray | None = field(default=None, repr=False)
    uv_map: str = ""
    image: str = ""


def _alpha(socket, material, warnings: list[str], what: str = "Alpha") -> MaterialAlpha:
    """The alpha a float socket gives: a constant, or an Image Texture's Alpha output through a UV
    map; anything else is read as opaque, with a warning naming the node."""
    if not socket.is_linked:
        return MaterialAlpha(float(np.clip(socket.default_value, 0.0, 1.0)))
    node, out = upstream(socket)
    if node is not None and node.bl_idname == "ShaderNodeTexImage" and node.image is not None:
        uv = _uv_of(node)
        if out.name == "Alpha" and uv is not None and node.projection == "FLAT":
            px = alpha_pixels(node.image)
            return MaterialAlpha() if px is None else MaterialAlpha(1.0, px, uv, node.image.name)
    label = "nodes" if node is None else f"a {node.bl_label} node"
    warnings.append(
        f"material '{material.name}': {what} driven by {label} is ignored; the surface is read as opaque "
        "(read: a constant, or an Image Texture's Alpha through a UV map)"
    )
    return MaterialAlpha()


def _both(a: MaterialAlpha, b: MaterialAlpha, material, warnings: list[str]) -> MaterialAlpha:
    """The product of two alphas (a Mix Shader's over a Principled BSDF's), where at most one has a map."""
    if a.pixels is not None and b.pixels is not None:
        warnings.append(
            f"material '{material.name}': two alpha maps ('{a.image}', '{b.image}'); only '{a.image}' is read"
        )
        b = MaterialAlpha(b.constant)
    m = a if a.pixels is not None else b
    return MaterialAlpha(a.constant * b.constant, m.pixels, m.uv_map, m.image)


def _past_transparent(node, material, warnings: list[str]):
    """(the shader under a Mix Shader of a Transparent BSDF and another shader, its alpha): the
    older way to cut foliage out (Mix Shader's factor from an image's alpha); (node, opaque) for
    any other node."""
    if node is None or node.bl_idname != "ShaderNodeMixShader":
        return node, MaterialAlpha()
    fac, first, second = node.inputs[0], upstream(node.inputs[1])[0], upstream(node.inputs[2])[0]

    def transparent(n) -> bool:
        return n is not None and n.bl_idname == "ShaderNodeBsdfTransparent"

    if transparent(first) == transparent(second):
        return node, MaterialAlpha()
    alpha = _alpha(fac, material, warnings, "a Mix Shader's factor")
    if transparent(second):  # (1 - fac) x the shader: alpha is 1 - fac
        alpha = MaterialAlpha(
            1.0 - alpha.constant if alpha.pixels is None else 1.0,
            None if alpha.pixels is None else np.float32(1.0) - alpha.pixels,
            alpha.uv_map,
            alpha.image,
        )
    return (second if transparent(first) else first), alpha
