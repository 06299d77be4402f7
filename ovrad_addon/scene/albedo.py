"""Varying albedo: image textures and painted colours on triangles, sampled where light is reflected.

A surface whose colour comes from an image or from a colour attribute (vertex paint) has no single
reflectance: the bake needs the albedo
at each vertex or texel, and the transport the mean albedo over each patch's support (taken at
the patch's receiver points). Images are linear RGB (the reader converts sRGB as Cycles does),
sampled bilinearly between texel centres with wrap-around, which is what Cycles' Image Texture
does with its default Linear interpolation and Repeat extension. An 8-bit sRGB image is kept as
stored and decoded after the interpolation, as Cycles does (TextureAlbedo.srgb). Painted colours are given per
triangle corner (linear RGB) and interpolated linearly across the triangle, as Cycles interpolates
a Color Attribute.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..digest import add_array, hasher
from ..errors import OvradError
from ..geometry import subtriangle_centroids


@dataclass(frozen=True, eq=False)
class TextureAlbedo:
    """images: linear RGB albedo maps, each (h, w, 3), row 0 at the bottom (Blender's order);
    image_of: (T,) int64, the map of each triangle (-1: none); uv: (T, 3, 2) texture coordinates of
    each triangle's corners; tint: (T, 3) factor applied to the map (1 for a plain texture);
    corners: None, or (T, 3, 3) linear RGB painted at each triangle corner where finite (NaN: the
    triangle is not painted), interpolated linearly: the albedo where the triangle has no map, a
    factor on the map where it has one (a texture multiplied by a colour attribute). A triangle with
    neither has its constant reflectance. srgb: per image, whether it holds sRGB-encoded values
    (an 8-bit sRGB texture) that are decoded to linear after the bilinear interpolation (empty:
    every image is linear)."""

    images: tuple = field(repr=False)
    image_of: np.ndarray = field(repr=False)
    uv: np.ndarray = field(repr=False)
    tint: np.ndarray = field(repr=False)
    corners: np.ndarray | None = field(default=None, repr=False)
    srgb: tuple = field(default=(), repr=False)

    def __post_init__(self) -> None:
        n = len(self.image_of)
        if self.uv.shape != (n, 3, 2) or self.tint.shape != (n, 3):
            raise OvradError("texture albedo: uv must be (T, 3, 2) and tint (T, 3)")
        if self.corners is not None and self.corners.shape != (n, 3, 3):
            raise OvradError("painted albedo: corner colours must be (T, 3, 3)")
        if n and self.image_of.max(initial=-1) >= len(self.images):
            raise OvradError("texture albedo: a triangle refers to a missing image")
        for img in self.images:
            if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 1:
                raise OvradError(f"texture albedo: images must be (h, w, 3), got {img.shape}")

    @property
    def has_paint(self) -> np.ndarray:
        """(T,) bool: the triangles with painted corner colours."""
        if self.corners is None:
            return np.zeros(len(self.image_of), bool)
        return np.all(np.isfinite(self.corners), axis=(1, 2))

    @property
    def painted(self) -> np.ndarray:
        """(T,) bool: the triangles whose albedo is their corners' painted colours (no map)."""
        return (self.image_of < 0) & self.has_paint

    @property
    def varies(self) -> np.ndarray:
        """(T,) bool: the triangles whose albedo varies over them (a texture or paint)."""
        return (self.image_of >= 0) | self.has_paint

    def key(self) -> bytes:
        """Bytes that change when any map, assignment, UV or paint changes (for cache keys)."""
        h = hasher(16)
        for a in (*self.images, self.image_of, self.uv, self.tint):
            add_array(h, a, dtype=False)
        if self.corners is not None:  # a key without paint stays what it was
            h.update(b"painted")
            add_array(h, self.corners, dtype=False)
        if any(self.srgb):
            h.update(b"srgb" + bytes(bool(f) for f in self.srgb))
        return h.digest()

    def encoded(self, k: int) -> bool:
        """Whether image k holds sRGB-encoded values, decoded after interpolation."""
        return k < len(self.srgb) and bool(self.srgb[k])


def srgb_decode(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function inverted (encoded values in [0, 1] to linear)."""
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Colours (m, 3) of an (h, w, 3) image at texture coordinates (m, 2), texel centres at
    (i + 0.5) / w, wrapping around (Repeat)."""
    h, w = image.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    c0, c1 = x0 % w, (x0 + 1) % w
    r0, r1 = y0 % h, (y0 + 1) % h
    top = image[r1, c0] * (1 - fx) + image[r1, c1] * fx
    bottom = image[r0, c0] * (1 - fx) + image[r0, c1] * fx
    return bottom * (1 - fy) + top * fy


def barycentric(corners: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric weights (m, 3) of points (m, 3) projected on triangles (m, 3, 3); degenerate
    triangles give their first corner."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2, p = b - a, c - a, points - a
    d11 = np.einsum("ij,ij->i", e1, e1)
    d12 = np.einsum("ij,ij->i", e1, e2)
    d22 = np.einsum("ij,ij->i", e2, e2)
    p1 = np.einsum("ij,ij->i", p, e1)
    p2 = np.einsum("ij,ij->i", p, e2)
    det = d11 * d22 - d12 * d12
    ok = det > 1e-30 * np.maximum(d11 * d22, 1e-300)
    safe = np.where(ok, det, 1.0)
    v = np.where(ok, (d22 * p1 - d12 * p2) / safe, 0.0)
    w = np.where(ok, (d11 * p2 - d12 * p1) / safe, 0.0)
    return np.column_stack([1.0 - v - w, v, w])


def albedo_at(
    textures: TextureAlbedo | None,
    reflectance: np.ndarray,
    corners: np.ndarray,
    triangles: np.ndarray,
    points: np.ndarray,
    clip: bool = True,
) -> np.ndarray:
    """Albedo (m, 3) at surface points on `triangles` (m,): the texture or the paint where the
    triangle has one, else the triangle's constant reflectance (T, 3). corners: (T, 3, 3) of all
    triangles' positions. clip: an albedo is clipped to [0, 1]; an emitted colour is not."""
    lo, hi = (0.0, 1.0) if clip else (0.0, np.inf)
    tri = np.asarray(triangles, np.int64)
    out = np.asarray(reflectance, np.float64)[tri].copy()
    if textures is None or len(tri) == 0:
        return out
    painted = np.flatnonzero(textures.painted[tri])
    if len(painted):
        t = tri[painted]
        bary = barycentric(corners[t], np.asarray(points, np.float64).reshape(-1, 3)[painted])
        colour = np.einsum("mk,mkj->mj", bary, textures.corners[t]) * textures.tint[t]
        out[painted] = np.clip(colour, lo, hi)
    which = textures.image_of[tri]
    for k in np.unique(which[which >= 0]):
        sel = np.flatnonzero(which == k)
        t = tri[sel]
        bary = barycentric(corners[t], np.asarray(points, np.float64).reshape(-1, 3)[sel])
        uv = np.einsum("mk,mkj->mj", bary, textures.uv[t])
        colour = bilinear(np.asarray(textures.images[k], np.float64), uv)
        if textures.encoded(k):
            colour = srgb_decode(colour)
        colour = colour * textures.tint[t]
        both = textures.has_paint[t]
        if np.any(both):  # the map multiplied by the paint
            colour[both] *= np.einsum("mk,mkj->mj", bary[both], textures.corners[t[both]])
        out[sel] = np.clip(colour, lo, hi)
    return out


def triangle_means(
    textures: TextureAlbedo, reflectance: np.ndarray, corners: np.ndarray, k: int = 4, clip: bool = True
) -> np.ndarray:
    """Each triangle's mean albedo (T, 3) over the centroids of its k^2 sub-triangles (the constant
    reflectance where it has neither texture nor paint): what per-triangle code paths use. clip:
    as albedo_at (False for an emitted colour)."""
    out = np.asarray(reflectance, np.float64).copy()
    tri = np.flatnonzero(textures.varies)
    if len(tri):
        out[tri] = _means(textures, reflectance, corners, tri, k, clip)
    return out


MEAN_BLOCK = 1 << 18  # samples _means evaluates at once (a few tens of MB of temporaries)


def _means(textures: TextureAlbedo, reflectance, corners, tri: np.ndarray, k: int, clip: bool) -> np.ndarray:
    """(t, 3) the means of triangles `tri` over the centroids of their k^2 sub-triangles, in blocks
    of triangles of at most MEAN_BLOCK samples (a triangle's mean does not depend on its block)."""
    uv = subtriangle_centroids(k)
    bary = np.column_stack([1 - uv.sum(axis=1), uv])  # (s, 3)
    out = np.empty((len(tri), 3))
    step = max(1, MEAN_BLOCK // len(bary))
    for lo in range(0, len(tri), step):
        part = tri[lo : lo + step]
        pts = np.einsum("sk,tkj->tsj", bary, corners[part]).reshape(-1, 3)
        rep = np.repeat(part, len(bary))
        vals = albedo_at(textures, reflectance, corners, rep, pts, clip).reshape(len(part), len(bary), 3)
        out[lo : lo + step] = vals.mean(axis=1)
    return out


def texel_spans(textures: TextureAlbedo, tri: np.ndarray) -> np.ndarray:
    """(t,) the longest edge of each triangle `tri` in texels of its map (0: no map)."""
    span = np.zeros(len(tri))
    img = textures.image_of[tri]
    mapped = np.flatnonzero(img >= 0)
    if len(mapped):
        size = np.array([[im.shape[1], im.shape[0]] for im in textures.images], np.float64)  # (w, h)
        uv = textures.uv[tri[mapped]]
        edges = (uv[:, [1, 2, 0]] - uv) * size[img[mapped], None, :]
        span[mapped] = np.sqrt(np.einsum("tej,tej->te", edges, edges)).max(axis=1)
    return span


MEAN_TEXELS = 0.5  # texel_means: a sample at least every half texel along a triangle's longest edge
MEAN_SPLIT_MOST = 64  # ... in at most 64^2 sub-triangles
MEAN_SAMPLES_MOST = 1 << 22  # ... and 4 M samples in all; beyond, every triangle's rule is coarser


def texel_means(
    textures: TextureAlbedo, reflectance: np.ndarray, corners: np.ndarray, least: int = 4, clip: bool = True
) -> np.ndarray:
    """Each triangle's mean (T, 3) as triangle_means gives it, over k^2 sub-triangles with k at
    least `least` and enough for a sample every MEAN_TEXELS texels of its map along its longest
    edge (at most MEAN_SPLIT_MOST a side, MEAN_SAMPLES_MOST samples in all): a triangle over many
    texels gets their mean, not an alias of a few of them (16 samples of a 48 x 32 image over two
    triangles made a screen emit 9 % too little)."""
    out = np.asarray(reflectance, np.float64).copy()
    tri = np.flatnonzero(textures.varies)
    if len(tri) == 0:
        return out
    k = np.clip(np.ceil(texel_spans(textures, tri) / MEAN_TEXELS), least, MEAN_SPLIT_MOST).astype(np.int64)
    total = int(np.sum(k * k))
    if total > MEAN_SAMPLES_MOST:
        k = np.maximum(least, np.floor(k * np.sqrt(MEAN_SAMPLES_MOST / total))).astype(np.int64)
    for level in np.unique(k):
        sel = tri[k == level]
        out[sel] = _means(textures, reflectance, corners, sel, int(level), clip)
    return out
