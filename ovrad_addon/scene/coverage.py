"""See-through surfaces: a material's alpha, the share of a surface that is there.

Cycles mixes a surface with alpha a in [0, 1] as a x (its shader) + (1 - a) x (transparent): a ray
meeting it goes on with weight 1 - a, and what the surface reflects is weighted by a. Alpha-cut
foliage, fences and decals are images whose alpha is 0 or 1 per texel (bilinear between texel
centres, as the Image Texture node samples them); a constant alpha below 1 is partial transmission.
Coverage holds, per triangle, a constant alpha and optionally an alpha map through a UV map.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..digest import add_array, hasher
from ..errors import OvradError
from .albedo import barycentric, bilinear


@dataclass(frozen=True, eq=False)
class Coverage:
    """opacity: (T,) constant alpha of each triangle in [0, 1] (a factor on its map where it has
    one); images: alpha maps, each (h, w), row 0 at the bottom; image_of: (T,) int64, the map of
    each triangle (-1: none); uv: (T, 3, 2) texture coordinates of each triangle's corners."""

    opacity: np.ndarray = field(repr=False)
    images: tuple = field(default=(), repr=False)
    image_of: np.ndarray | None = field(default=None, repr=False)
    uv: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        n = len(self.opacity)
        op = self.opacity
        if not np.all(np.isfinite(op)) or op.min(initial=0.0) < 0.0 or op.max(initial=0.0) > 1.0:
            raise OvradError("alpha must lie in [0, 1]")
        if self.image_of is not None:
            if self.image_of.shape != (n,) or self.uv is None or self.uv.shape != (n, 3, 2):
                raise OvradError("alpha maps: image_of must be (T,) and uv (T, 3, 2)")
            if n and self.image_of.max(initial=-1) >= len(self.images):
                raise OvradError("alpha maps: a triangle refers to a missing image")
        for img in self.images:
            if img.ndim != 2 or min(img.shape) < 1:
                raise OvradError(f"alpha maps must be (h, w), got {img.shape}")

    @staticmethod
    def everywhere_opaque(n: int) -> Coverage:
        return Coverage(np.ones(n))

    @property
    def mapped(self) -> np.ndarray:
        """(T,) bool: the triangles whose alpha comes from a map."""
        if self.image_of is None:
            return np.zeros(len(self.opacity), bool)
        return self.image_of >= 0

    @property
    def see_through(self) -> np.ndarray:
        """(T,) bool: the triangles light may pass (alpha below 1 somewhere on them)."""
        partial = self.opacity < 1.0
        for k, img in enumerate(self.images):
            if img.min() < 1.0:
                partial |= self.image_of == k
        return partial

    def alpha(self, corners: np.ndarray, triangles, points) -> np.ndarray:
        """Alpha (m,) at surface points (m, 3) on triangles (m,); corners: (T, 3, 3) every triangle's."""
        tri = np.asarray(triangles, np.int64)
        out = self.opacity[tri].astype(np.float64)
        if self.image_of is None or len(tri) == 0:
            return out
        which = self.image_of[tri]
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        for k in np.unique(which[which >= 0]):
            sel = np.flatnonzero(which == k)
            t = tri[sel]
            bary = barycentric(corners[t], pts[sel])
            uv = np.einsum("mk,mkj->mj", bary, self.uv[t])
            img = np.asarray(self.images[k], np.float64)[..., None]
            out[sel] *= np.clip(bilinear(img, uv)[:, 0], 0.0, 1.0)
        return out

    def key(self) -> bytes:
        """Bytes that change when any alpha, map, assignment or UV changes (for cache keys)."""
        h = hasher(16)
        add_array(h, self.opacity, dtype=False)
        for a in (*self.images, self.image_of, self.uv):
            if a is not None:
                add_array(h, a, dtype=False)
        return h.digest()
