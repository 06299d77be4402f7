"""Colours a material computes, as terms the bake can evaluate per point: a tint times at most one
image texture and at most one colour attribute (paint), each possibly transformed (ColourTerm), and
the algebra materials.py builds them with (sums, products, functions of a term or of two)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class MaterialTexture:
    """An albedo map: linear RGB pixels (h, w, 3) float32, row 0 at the bottom; the UV map it is
    sampled through ('' = the mesh's active render UV map); its image's name (for messages);
    encoded: for an 8-bit sRGB image, its pixels as stored (sRGB-encoded), which Cycles filters
    before it decodes them (None: the pixels are filtered as they are)."""

    pixels: np.ndarray
    uv_map: str
    image: str
    encoded: np.ndarray | None = field(default=None, repr=False)


@dataclass(frozen=True)
class MaterialPaint:
    """An albedo painted into a colour attribute: its name ('' = the mesh's render colour attribute),
    read as offset + scale x T(the attribute's colour) (scale, offset (3,): a Mix or Invert node on
    it; T: the transforms, functions of colours (..., 3), applied in order: a nonlinear node such as
    Hue/Saturation/Value, Gamma or RGB Curves on it).

    The transforms are applied to each corner's colour, which is then interpolated across the
    triangle; Cycles interpolates first and applies the node to the result. The two agree exactly
    where a triangle's corners have one colour (paint constant per face) and otherwise differ by
    the node's curvature across the triangle."""

    attribute: str
    scale: tuple = (1.0, 1.0, 1.0)
    offset: tuple = (0.0, 0.0, 0.0)
    transforms: tuple = ()

    def colours(self, rgb: np.ndarray) -> np.ndarray:
        for transform in self.transforms:
            rgb = transform(rgb)
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


def affine(term: ColourTerm, scale, offset) -> ColourTerm | None:
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
    new = MaterialPaint(
        p.attribute, tuple(s * np.asarray(p.scale)), tuple(offset + s * np.asarray(p.offset)), p.transforms
    )
    return ColourTerm(np.ones(3), paint=new)


def combine(a: float, A: ColourTerm, b: float, B: ColourTerm) -> ColourTerm | None:
    """a A + b B, when one side is a constant."""
    if A.constant:
        return affine(B, b, a * A.tint)
    if B.constant:
        return affine(A, a, b * B.tint)
    return None


def product(A: ColourTerm, B: ColourTerm) -> ColourTerm | None:
    """A x B, when they hold at most one texture and one paint between them."""
    if A.texture is not None and B.texture is not None or A.paint is not None and B.paint is not None:
        return None
    return ColourTerm(A.tint * B.tint, A.texture or B.texture, A.paint or B.paint)


def apply(term: ColourTerm, fn, label: str) -> ColourTerm | None:
    """fn (a function of colours (..., 3)) of a term, None where that is not a ColourTerm (fn of a
    texture times paint). A texture gets new pixels, fn of its texels: exact at texel centres,
    between them fn of the bilinear mean where Cycles takes fn of the texels' mean (a nonlinear node
    after an Image Texture). Paint gets fn per corner colour (see MaterialPaint)."""
    if term.constant:
        return ColourTerm(np.asarray(fn(term.tint), float))
    if term.texture is not None and term.paint is not None:
        return None
    tint = term.tint
    if term.texture is not None:
        tex = term.texture
        pixels = np.asarray(fn(tint * tex.pixels.astype(float)), np.float32)
        return ColourTerm(np.ones(3), MaterialTexture(pixels, tex.uv_map, f"{tex.image} > {label}"))
    paint = term.paint

    def transform(rgb):
        return fn(tint * paint.colours(rgb))

    return ColourTerm(np.ones(3), paint=MaterialPaint(paint.attribute, transforms=(transform,)))


def pointwise(A: ColourTerm, B: ColourTerm, fn, label: str) -> ColourTerm | None:
    """fn(A, B) (a function of two colours (..., 3)) where it is a ColourTerm: one side constant,
    two textures through one UV map at one size (texel by texel), or paint of one attribute."""
    if A.constant:
        return apply(B, lambda b: fn(A.tint, b), label)
    if B.constant:
        return apply(A, lambda a: fn(a, B.tint), label)
    ta, tb, pa, pb = A.texture, B.texture, A.paint, B.paint
    if pa is None and pb is None and ta.uv_map == tb.uv_map and ta.pixels.shape == tb.pixels.shape:
        pixels = fn(A.tint * ta.pixels.astype(float), B.tint * tb.pixels.astype(float))
        texture = MaterialTexture(
            np.asarray(pixels, np.float32), ta.uv_map, f"{ta.image}, {tb.image} > {label}"
        )
        return ColourTerm(np.ones(3), texture)
    if ta is None and tb is None and pa.attribute == pb.attribute:
        sa, sb = A.tint, B.tint

        def transform(rgb):
            return fn(sa * pa.colours(rgb), sb * pb.colours(rgb))

        return ColourTerm(np.ones(3), paint=MaterialPaint(pa.attribute, transforms=(transform,)))
    return None
