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
    barycentric weights (k, 3) of the triangle's corners; each texel appears at most once.
    outside (k,) bool: the centre lies in no triangle (rasterize's reach), None when none does."""

    texel: np.ndarray
    triangle: np.ndarray
    points: np.ndarray
    weights: np.ndarray
    outside: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.texel)


def _check_size(width: int, height: int) -> None:
    if not (1 <= width <= MAX_SIZE and 1 <= height <= MAX_SIZE):
        raise OvradError(f"image size must be between 1 and {MAX_SIZE} texels per side, got {width}x{height}")


def rasterize(
    uv, world, triangle_ids, width: int, height: int, inset: float = 0.0, reach: float = 0.0
) -> Texels:
    """Texel centres inside UV triangles (T, 3, 2), with their world points on triangles (T, 3, 3).

    A centre counts when it lies inside or on the edge of a triangle; a centre on an edge shared by
    two triangles (or covered by overlapping UV islands) goes to the first triangle in input order.
    Triangles with no area in UV space cover nothing. With `reach` > 0, a centre inside no triangle
    but within `reach` texels (UV distance in texels) of one counts too, at the nearest point of the
    nearest such triangle: the centres a bilinear filter reads at an island's edge get the light
    of the island's edge, not of a place off the surface. Results are sorted by texel index.
    `inset` moves every world point that fraction of the way to its triangle's centroid.
    """
    _check_size(width, height)
    uv = np.asarray(uv, np.float64).reshape(-1, 3, 2)
    world = np.asarray(world, np.float64).reshape(-1, 3, 3)
    ids = np.asarray(triangle_ids, np.int64).reshape(-1)
    if not (len(uv) == len(world) == len(ids)):
        raise OvradError("uv, world and triangle_ids must have one row per triangle")
    if not (np.isfinite(reach) and reach >= 0):
        raise OvradError(f"reach must be a finite number >= 0, got {reach}")
    texel, tri, wts, far = [], [], [], []
    for owner, ix, iy, w in _candidates(uv, width, height, reach):
        inside = np.all(w >= -_EDGE_TOL, axis=1)
        dist = np.zeros(len(w))
        if reach > 0 and not inside.all():
            out = ~inside
            p = np.stack([ix[out] + 0.5, iy[out] + 0.5], axis=1)
            dist[out], w[out] = _nearest(p, uv[owner[out]] * np.array([width, height], float))
            inside |= dist <= reach
        texel.append((iy * width + ix)[inside])
        tri.append(owner[inside])
        wts.append(w[inside])
        far.append(dist[inside])
    texel = np.concatenate(texel) if texel else np.zeros(0, np.int64)
    tri = np.concatenate(tri) if tri else np.zeros(0, np.int64)
    wts = np.concatenate(wts) if wts else np.zeros((0, 3))
    far = np.concatenate(far) if far else np.zeros(0)
    # One triangle per texel: one it lies in (the first in input order: the stable sort keeps it
    # first), else the nearest.
    order = np.lexsort((tri, far, texel))
    texel, tri, wts, far = texel[order], tri[order], wts[order], far[order]
    first = np.ones(len(texel), bool)
    first[1:] = texel[1:] != texel[:-1]
    texel, tri, wts, far = texel[first], tri[first], np.clip(wts[first], 0.0, 1.0), far[first]
    wts /= wts.sum(axis=1, keepdims=True)
    if inset:
        wts = (1.0 - inset) * wts + inset / 3.0
    points = np.einsum("kj,kjd->kd", wts, world[tri])
    return Texels(texel, ids[tri], points, wts, far > 0 if reach > 0 else None)


def _candidates(uv, width: int, height: int, grow: float = 0.0):
    """Per chunk of triangles: (owner, ix, iy, w) for every texel centre in a triangle's UV bounding
    box grown by `grow` texels: its triangle (k,), column and row (k,), barycentric weights (k, 3)
    (negative outside). Triangles with no area in UV space, or not finite, give none."""
    # Texel space: centres sit at integer + 0.5.
    px = uv * np.array([width, height], float)
    a, b, c = px[:, 0], px[:, 1], px[:, 2]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    lo = np.floor(px.min(axis=1) - grow - 0.5).astype(np.int64) + 1  # first centre index >= min
    hi = np.ceil(px.max(axis=1) + grow - 0.5).astype(np.int64) - 1  # last centre index <= max
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width - 1, height - 1])
    hi = np.maximum(hi, lo - 1)  # an empty range stays empty
    ok = np.isfinite(area2) & (np.abs(area2) > 1e-300) & np.all(np.isfinite(px), axis=(1, 2))
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    count = np.where(ok, nx * ny, 0)
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
            yield owner, ix, iy, _barycentric(p, a[owner], b[owner], c[owner], area2[owner])
        start = stop


def _nearest(p, tri) -> tuple[np.ndarray, np.ndarray]:
    """Distance (k,) from 2D points p (k, 2) to triangles tri (k, 3, 2) they lie outside, and the
    barycentric weights (k, 3) of each triangle's point nearest to it (on one of its edges)."""
    best = np.full(len(p), np.inf)
    wts = np.zeros((len(p), 3))
    rows = np.arange(len(p))
    for i in range(3):
        j = (i + 1) % 3
        a, e = tri[:, i], tri[:, j] - tri[:, i]
        along = np.einsum("kd,kd->k", p - a, e) / np.maximum(np.einsum("kd,kd->k", e, e), 1e-300)
        t = np.clip(along, 0.0, 1.0)
        d = np.linalg.norm(a + t[:, None] * e - p, axis=1)
        closer = d < best
        best = np.where(closer, d, best)
        w = np.zeros((len(p), 3))
        w[rows, i], w[rows, j] = 1.0 - t, t
        wts[closer] = w[closer]
    return best, wts


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


# A UV map is unfit for a lightmap when more than this share of the texel centres its triangles
# cover lie strictly inside two or more of them (overlapping or mirrored islands).
OVERLAP_SHARE = 1e-3
# ... or when triangles with no area in UV space carry more than this share of the world area.
COLLAPSED_SHARE = 1e-3


def _areas(uv, world) -> tuple[np.ndarray, np.ndarray]:
    """(T,) UV areas and (T,) world areas of triangles uv (T, 3, 2), world (T, 3, 3)."""
    uv = np.asarray(uv, np.float64).reshape(-1, 3, 2)
    world = np.asarray(world, np.float64).reshape(-1, 3, 3)
    u1, u2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    uv_area = 0.5 * np.abs(u1[:, 0] * u2[:, 1] - u1[:, 1] * u2[:, 0])
    w_area = 0.5 * np.linalg.norm(np.cross(world[:, 1] - world[:, 0], world[:, 2] - world[:, 0]), axis=1)
    return uv_area, w_area


def lightmap_problem(uv, world, width: int, height: int) -> str | None:
    """Why a UV map (T, 3, 2) of triangles world (T, 3, 3) is unfit for a lightmap of width x height
    texels, None when it is fit: UVs not finite or outside the unit square, faces with no area in
    UV space (more than COLLAPSED_SHARE of the world area), or texel centres inside two or more
    triangles (more than OVERLAP_SHARE of those covered: overlapping or mirrored islands)."""
    _check_size(width, height)
    uv = np.asarray(uv, np.float64).reshape(-1, 3, 2)
    if len(uv) == 0:
        return "it has no faces"
    if not np.all(np.isfinite(uv)):
        return "its UVs are not finite numbers"
    if uv.min() < 0.0 or uv.max() > 1.0:
        return f"its UVs reach outside the unit square ({uv.min():.3g} to {uv.max():.3g})"
    uv_area, w_area = _areas(uv, world)
    collapsed = float(w_area[uv_area <= 1e-12 * max(float(uv_area.max()), 1e-300)].sum())
    if collapsed > COLLAPSED_SHARE * float(w_area.sum()):
        share = 100 * collapsed / float(w_area.sum())
        return f"faces holding {share:.1f} % of its area have no area in UV space"
    counts = np.zeros(width * height, np.int64)
    for _owner, ix, iy, w in _candidates(uv, width, height):
        inside = np.all(w > _EDGE_TOL, axis=1)  # strictly inside: a shared edge counts once
        np.add.at(counts, (iy * width + ix)[inside], 1)
    covered = int(np.count_nonzero(counts))
    twice = int(np.count_nonzero(counts > 1))
    if covered and twice > OVERLAP_SHARE * covered:
        return f"its UV islands overlap ({100 * twice / covered:.1f} % of its texels are covered twice)"
    return None


def density_size(uv, world, density: float, multiple: int = 4) -> int:
    """Texels per side of a square image giving `density` texels per unit length on the surface
    through UV map uv (T, 3, 2) of triangles world (T, 3, 3): density x sqrt(world area / UV area),
    rounded up to a multiple of `multiple`. OvradError when the map has no area."""
    if not density > 0:
        raise OvradError(f"the texel density must be positive, got {density}")
    uv_area, w_area = _areas(uv, world)
    a, w = float(uv_area.sum()), float(w_area.sum())
    if not (a > 0 and w > 0 and np.isfinite(a) and np.isfinite(w)):
        raise OvradError("the UV map or the surface has no area")
    texels = density * np.sqrt(w / a)
    return int(multiple * max(1, int(np.ceil(texels / multiple - 1e-9))))
