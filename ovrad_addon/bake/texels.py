"""Baking to images on plain arrays: texel centres covered by UV triangles, and seam-hiding dilation.

Image layout is Blender's: row 0 is the bottom row (v from 0 to 1/H), the flat texel index is
row * W + column, and texel (column i, row j) has its centre at UV ((i + 0.5) / W, (j + 0.5) / H).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OvradError

MAX_SIZE = 16384  # texels per side

_CHUNK = 1 << 22  # candidate texels tested at once (bounded memory)

_EDGE_TOL = 1e-12  # barycentric slack: a centre on a shared edge belongs to one triangle, not none


@dataclass(frozen=True)
class Texels:
    """Texel centres on the surface: flat index (k,), triangle id (k,), world point (k, 3) and
    barycentric weights (k, 3) of the triangle's corners; each texel appears at most once."""

    texel: np.ndarray
    triangle: np.ndarray
    points: np.ndarray
    weights: np.ndarray

    def __len__(self) -> int:
        return len(self.texel)


def _check_size(width: int, height: int) -> None:
    if not (1 <= width <= MAX_SIZE and 1 <= height <= MAX_SIZE):
        raise OvradError(f"image size must be between 1 and {MAX_SIZE} texels per side, got {width}x{height}")


def rasterize(uv, world, triangle_ids, width: int, height: int, inset: float = 0.0) -> Texels:
    """Texel centres inside UV triangles (T, 3, 2), with their world points on triangles (T, 3, 3).

    A centre counts when it lies inside or on the edge of a triangle; a centre on an edge shared by
    two triangles (or covered by overlapping UV islands) goes to the first triangle in input order.
    Triangles with no area in UV space cover nothing. Results are sorted by texel index. `inset`
    moves every world point that fraction of the way to its triangle's centroid (off the edges).
    """
    _check_size(width, height)
    uv = np.asarray(uv, np.float64).reshape(-1, 3, 2)
    world = np.asarray(world, np.float64).reshape(-1, 3, 3)
    ids = np.asarray(triangle_ids, np.int64).reshape(-1)
    if not (len(uv) == len(world) == len(ids)):
        raise OvradError("uv, world and triangle_ids must have one row per triangle")
    # Texel space: centres sit at integer + 0.5.
    px = uv * np.array([width, height], float)
    a, b, c = px[:, 0], px[:, 1], px[:, 2]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    lo = np.floor(px.min(axis=1) - 0.5).astype(np.int64) + 1  # first centre index >= min
    hi = np.ceil(px.max(axis=1) - 0.5).astype(np.int64) - 1  # last centre index <= max
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width - 1, height - 1])
    hi = np.maximum(hi, lo - 1)  # an empty range stays empty
    ok = np.isfinite(area2) & (np.abs(area2) > 1e-300) & np.all(np.isfinite(px), axis=(1, 2))
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    count = np.where(ok, nx * ny, 0)
    texel, tri, wts = [], [], []
    start = 0
    cum = np.cumsum(count)
    while start < len(uv):
        # triangles [start, stop) hold at most _CHUNK candidates (at least one triangle per chunk)
        base = cum[start - 1] if start else 0
        stop = max(start + 1, int(np.searchsorted(cum, base + _CHUNK, side="right")))
        sel = np.arange(start, stop)
        cnt = count[sel]
        owner = np.repeat(sel, cnt)
        if len(owner):
            offset = np.arange(len(owner)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
            ix = lo[owner, 0] + offset % nx[owner]
            iy = lo[owner, 1] + offset // nx[owner]
            p = np.stack([ix + 0.5, iy + 0.5], axis=1)
            w = _barycentric(p, a[owner], b[owner], c[owner], area2[owner])
            inside = np.all(w >= -_EDGE_TOL, axis=1)
            texel.append((iy * width + ix)[inside])
            tri.append(owner[inside])
            wts.append(w[inside])
        start = stop
    texel = np.concatenate(texel) if texel else np.zeros(0, np.int64)
    tri = np.concatenate(tri) if tri else np.zeros(0, np.int64)
    wts = np.concatenate(wts) if wts else np.zeros((0, 3))
    # One triangle per texel: the first in input order (stable sort keeps it first).
    order = np.lexsort((tri, texel))
    texel, tri, wts = texel[order], tri[order], wts[order]
    first = np.ones(len(texel), bool)
    first[1:] = texel[1:] != texel[:-1]
    texel, tri, wts = texel[first], tri[first], np.clip(wts[first], 0.0, 1.0)
    wts /= wts.sum(axis=1, keepdims=True)
    if inset:
        wts = (1.0 - inset) * wts + inset / 3.0
    points = np.einsum("kj,kjd->kd", wts, world[tri])
    return Texels(texel, ids[tri], points, wts)


def _barycentric(p, a, b, c, area2) -> np.ndarray:
    """Weights (k, 3) of corners a, b, c for 2D points p (k, 2), given twice the signed area."""

    def cross(u, v, q):
        return (u[:, 0] - q[:, 0]) * (v[:, 1] - q[:, 1]) - (u[:, 1] - q[:, 1]) * (v[:, 0] - q[:, 0])

    wa = cross(b, c, p) / area2
    wb = cross(c, a, p) / area2
    return np.stack([wa, wb, 1.0 - wa - wb], axis=1)


def dilate(image, mask, margin: int) -> tuple[np.ndarray, np.ndarray]:
    """Extend filled texels into `margin` rings of empty ones, so filtering shows no seams.

    image (H, W, C), mask (H, W) True where filled. Each ring gives every empty texel with a
    filled 8-neighbour the mean of those neighbours; texels farther than `margin` steps
    (Chebyshev distance) from any filled texel are left as they were. Returns (image, mask).
    """
    img = np.array(image, np.float64, copy=True)
    filled = np.array(mask, bool, copy=True)
    if img.ndim != 3 or filled.shape != img.shape[:2]:
        raise OvradError("dilate: image must be (H, W, C) and mask (H, W)")
    if margin < 0:
        raise OvradError(f"margin must be >= 0, got {margin}")
    h, w = filled.shape
    for _ in range(int(margin)):
        if filled.all() or not filled.any():
            break
        vals = np.pad(img * filled[..., None], ((1, 1), (1, 1), (0, 0)))
        cnt = np.pad(filled.astype(np.float64), 1)
        acc = np.zeros_like(img)
        n = np.zeros((h, w))
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                acc += vals[dy : dy + h, dx : dx + w]
                n += cnt[dy : dy + h, dx : dx + w]
        ring = ~filled & (n > 0)
        img[ring] = acc[ring] / n[ring, None]
        filled |= ring
    return img, filled


def to_image(
    texels: Texels, values, width: int, height: int, channels: int = 4
) -> tuple[np.ndarray, np.ndarray]:
    """Scatter per-texel values (k, c) into an (H, W, channels) image (alpha 1 where filled) and mask."""
    _check_size(width, height)
    vals = np.asarray(values, np.float64).reshape(len(texels), -1)
    img = np.zeros((height * width, channels))
    c = min(vals.shape[1], channels)
    img[texels.texel, :c] = vals[:, :c]
    if channels == 4 and c < 4:
        img[texels.texel, 3] = 1.0
    mask = np.zeros(height * width, bool)
    mask[texels.texel] = True
    return img.reshape(height, width, channels), mask.reshape(height, width)
