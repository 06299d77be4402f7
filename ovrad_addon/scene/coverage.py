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

    def frames(self, corners: np.ndarray) -> UVFrames:
        """The affine maps from surface points to UVs of the triangles that have an alpha map;
        corners: (T, 3, 3) every triangle's (Surfaces keeps them: Surfaces.opacity_at)."""
        return UVFrames.of(corners, self.uv, self.mapped)

    def alpha(self, frames: UVFrames, triangles, points) -> np.ndarray:
        """Alpha (m,) at surface points (m, 3) on triangles (m,); frames: self.frames(corners)."""
        tri = np.asarray(triangles, np.int64)
        out = self.opacity[tri].astype(np.float64)
        if self.image_of is None or len(tri) == 0:
            return out
        which = self.image_of[tri]
        sel = np.flatnonzero(which >= 0)
        if len(sel) == 0:
            return out
        uv = frames.uv(tri[sel], np.asarray(points, np.float64).reshape(-1, 3)[sel])
        if len(self.images) == 1:
            out[sel] *= np.clip(_bilinear(self.images[0], uv), 0.0, 1.0)
            return out
        k_sel = which[sel]
        for k in np.flatnonzero(np.bincount(k_sel, minlength=len(self.images))):
            part = k_sel == k
            out[sel[part]] *= np.clip(_bilinear(self.images[k], uv[part]), 0.0, 1.0)
        return out

    def key(self) -> bytes:
        """Bytes that change when any alpha, map, assignment or UV changes (for cache keys)."""
        h = hasher(16)
        add_array(h, self.opacity, dtype=False)
        for a in (*self.images, self.image_of, self.uv):
            if a is not None:
                add_array(h, a, dtype=False)
        return h.digest()


@dataclass(frozen=True)
class UVFrames:
    """Per triangle with a map: uv(p) = uv0 + (p - origin) J, the barycentric interpolation of its
    corners' UVs written as one affine map (J (k, 3, 2); 0 for a degenerate triangle); row (T,)
    each triangle's index in them (-1: none)."""

    row: np.ndarray
    origin: np.ndarray
    uv0: np.ndarray
    J: np.ndarray

    @staticmethod
    def of(corners: np.ndarray, uv: np.ndarray | None, mapped: np.ndarray) -> UVFrames:
        tri = np.flatnonzero(mapped)
        row = np.full(len(mapped), -1, np.int64)
        row[tri] = np.arange(len(tri))
        c = corners[tri]
        e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
        d11 = np.einsum("ij,ij->i", e1, e1)
        d12 = np.einsum("ij,ij->i", e1, e2)
        d22 = np.einsum("ij,ij->i", e2, e2)
        det = d11 * d22 - d12 * d12
        ok = det > 1e-30 * np.maximum(d11 * d22, 1e-300)
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
        # barycentric (v, w) of p = p . g1, p . g2 (p from the first corner)
        g1 = (d22[:, None] * e1 - d12[:, None] * e2) * inv
        g2 = (d11[:, None] * e2 - d12[:, None] * e1) * inv
        t_uv = np.zeros((len(tri), 3, 2)) if uv is None else uv[tri]
        du1, du2 = t_uv[:, 1] - t_uv[:, 0], t_uv[:, 2] - t_uv[:, 0]
        J = g1[:, :, None] * du1[:, None, :] + g2[:, :, None] * du2[:, None, :]
        return UVFrames(row, c[:, 0].copy(), t_uv[:, 0].copy(), J)

    def uv(self, triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(m, 2) UVs of points (m, 3) on triangles (m,) that have a map."""
        r = np.take(self.row, triangles)
        rel = points - np.take(self.origin, r, axis=0)
        J = np.take(self.J, r, axis=0)
        out = np.take(self.uv0, r, axis=0)
        for k in range(3):
            out += rel[:, k : k + 1] * J[:, k]
        return out


def _bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Values (m,) of an (h, w) image at texture coordinates (m, 2), texel centres at (i + 0.5) / w,
    wrapping around (albedo.bilinear on one channel, without converting the image)."""
    h, w = image.shape
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    c0 = x0.astype(np.int64) % w
    r0 = y0.astype(np.int64) % h
    c1, r1 = (c0 + 1) % w, (r0 + 1) % h
    top = image[r1, c0] * (1 - fx) + image[r1, c1] * fx
    bottom = image[r0, c0] * (1 - fx) + image[r0, c1] * fx
    return bottom * (1 - fy) + top * fy
