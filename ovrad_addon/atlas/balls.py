"""Ball patches: the clutter sheets' samples, balls on a world grid, and their quadrature."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..geometry import subtriangle_centroids, tangent_frame, unique_rows
from ..names import SHAPE_BALL
from .index import buried

SUBDIVISION = 4.0  # clutter samples: sub-triangles at most radius / SUBDIVISION across

MAX_LEVEL = 8

BALL_RADIUS = 0.5 * np.sqrt(3.0)  # cell circumradius over cell side


@dataclass(frozen=True)
class ClutterSamples:
    """Area-weighted points on the clutter sheets: points (m, 3), normals (m, 3) facing the
    sheet's side, weights (m,) area, triangle (m,), sheet (m,), key (m,) in [0, 1) (a fixed
    order for taking subsets)."""

    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    triangle: np.ndarray
    sheet: np.ndarray
    key: np.ndarray


def clutter_samples(index, size: np.ndarray) -> ClutterSamples:
    """Samples of every clutter sheet; size (n_sheets,) the largest sub-triangle wanted on each
    (only clutter sheets' entries are read)."""
    s, charts = index.surfaces, index.charts
    tri_all = np.flatnonzero(charts.chart >= 0)
    parts = []
    for col, side in ((0, 1), (1, -1)):
        sheet = index.sheet_table[charts.chart[tri_all], col]
        ok = sheet >= 0
        ok[ok] = index.sheet_clutter[sheet[ok]]
        tri, sheet = tri_all[ok], sheet[ok]
        level = np.clip(np.ceil(SUBDIVISION * np.sqrt(charts.areas[tri]) / size[sheet]), 1, MAX_LEVEL)
        for k in np.unique(level).astype(int):
            t = tri[level == k]
            uv = subtriangle_centroids(k)
            c = s.corners[t]
            pts = (
                c[:, None, 0] * (1.0 - uv[:, 0] - uv[:, 1])[None, :, None]
                + c[:, None, 1] * uv[None, :, 0, None]
                + c[:, None, 2] * uv[None, :, 1, None]
            )
            m = len(uv)
            parts.append(
                (
                    pts.reshape(-1, 3),
                    np.repeat(side * charts.normals[t], m, axis=0),
                    np.repeat(charts.areas[t] / m, m),
                    np.repeat(t, m),
                    np.repeat(sheet[level == k], m),
                )
            )
    if parts:
        pts, nrm, w, tri, sheet = (np.concatenate(x) for x in zip(*parts, strict=True))
    else:
        pts, nrm = np.zeros((0, 3)), np.zeros((0, 3))
        w, tri, sheet = np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64)
    keep = ~buried(index, pts, nrm, 1e-4 * size[sheet])
    key = position_key(pts)
    return ClutterSamples(pts[keep], nrm[keep], w[keep], tri[keep], sheet[keep], key[keep])


def position_key(points: np.ndarray) -> np.ndarray:
    """(m,) a value in [0, 1) per point from its coordinates alone (a hash of their bits), so a sample
    keeps its key whatever other samples the index holds (other objects' clutter at a solve)."""
    bits = np.ascontiguousarray(points, np.float64).reshape(-1, 3).view(np.uint64)
    x = bits[:, 0] ^ (bits[:, 1] * np.uint64(0x9E3779B97F4A7C15))
    x = x ^ (bits[:, 2] * np.uint64(0xC2B2AE3D27D4EB4F))
    # splitmix64's finaliser
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    x = x ^ (x >> np.uint64(31))
    return (x >> np.uint64(11)).astype(np.float64) / float(1 << 53)


def sample_size(atlas, n_sheets: int) -> np.ndarray:
    """(n_sheets,) the sample size for each sheet's ball patches (their largest radius over
    SUBDIVISION); 1 where a sheet has none."""
    size = np.zeros(n_sheets)
    ball = atlas.shapes == SHAPE_BALL
    np.maximum.at(size, atlas.sheet[ball], atlas.radii[ball] / SUBDIVISION)
    return np.where(size > 0, size, 1.0)


def place_balls(index, spacing: np.ndarray, overlap: float) -> dict[int, dict[str, np.ndarray]]:
    """Ball patches on every clutter sheet: {sheet: Placed fields}, one per occupied grid cell.

    The grid is anchored at the world origin with the sheet's spacing as its cell; the ball is
    centred on its cell and circumscribes it (times the overlap), so it holds every point of the
    cell. Its normal is the mean normal of what it holds (for display and frames only: membership
    ignores normals); its triangle is that of the sample nearest its centre.
    """
    radius_of = overlap * BALL_RADIUS * spacing
    smp = clutter_samples(index, radius_of / SUBDIVISION)
    if len(smp.points) == 0:
        return {}
    cell = spacing[smp.sheet]
    ijk = np.floor(smp.points / cell[:, None]).astype(np.int64)
    key = np.column_stack([smp.sheet, ijk])
    uniq, group = unique_rows(key, return_inverse=True)
    group = group.reshape(-1)
    k = len(uniq)
    sheet = uniq[:, 0]
    centers = (uniq[:, 1:] + 0.5) * spacing[sheet][:, None]
    wn = smp.normals * smp.weights[:, None]
    nsum = np.stack([np.bincount(group, weights=wn[:, j], minlength=k) for j in range(3)], 1)
    area = np.bincount(group, weights=smp.weights, minlength=k)
    # pieces facing every way (a closed cube) cancel: any unit normal will do for those
    normals = np.where(
        np.linalg.norm(nsum, axis=1, keepdims=True) > 1e-6 * area[:, None], nsum, [0.0, 0.0, 1.0]
    )
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    d = np.linalg.norm(smp.points - centers[group], axis=1)
    order = np.lexsort((d, group))
    nearest = order[np.searchsorted(group[order], np.arange(k))]
    radii = radius_of[sheet]
    out = {}
    for sh in np.unique(sheet):
        m = sheet == sh
        out[int(sh)] = {
            "centers": centers[m],
            "normals": normals[m],
            "tangents": tangent_frame(normals[m])[0],
            "radii": radii[m],
            "shapes": np.full(int(m.sum()), SHAPE_BALL, np.int8),
            "thickness": radii[m].copy(),
            "min_cos": np.full(int(m.sum()), -2.0),
            "triangle": smp.triangle[nearest[m]],
        }
    return out


@dataclass(frozen=True)
class BallRule:
    """The clutter samples an atlas's ball patches integrate over (their sizes from the atlas,
    sample_size) and a KD-tree of them, each sheet `gap` apart along a fourth coordinate: made once
    per atlas and index (ball_rule), where the work is prepared, and passed to every quadrature."""

    size: np.ndarray
    samples: ClutterSamples | None  # None: the atlas has no ball patches
    tree: cKDTree | None
    gap: float


def ball_rule(atlas, index, reuse: BallRule | None = None) -> BallRule:
    """The BallRule of an atlas on an index; `reuse` itself when its sample sizes are the atlas's
    (patches dropped from an atlas leave them alone unless the largest ball of a sheet goes)."""
    size = sample_size(atlas, len(index.sheet_chart))
    if reuse is not None and np.array_equal(reuse.size, size):
        return reuse
    if not np.any(atlas.shapes == SHAPE_BALL):
        return BallRule(size, None, None, 0.0)
    smp = clutter_samples(index, size)
    if len(smp.points) == 0:
        return BallRule(size, smp, None, 0.0)
    ball = atlas.shapes == SHAPE_BALL
    gap = 4.0 * float(atlas.radii[ball].max()) + 4.0 * float(np.abs(smp.points).max()) + 1.0
    return BallRule(size, smp, cKDTree(np.column_stack([smp.points, smp.sheet * gap])), gap)


def ball_quadrature(atlas, ids: np.ndarray, cap: int, rule: BallRule):
    """Rule of the ball patches `ids`: (owner, points, normals, weights, triangle), owner a
    position in ids. Every clutter sample of the patch's sheet inside its ball, or, where more
    than `cap` are, the first `cap` in the samples' fixed order with their weights scaled so the
    patch keeps its total area. rule: the atlas's (ball_rule)."""
    smp, kd, gap = rule.samples, rule.tree, rule.gap
    if len(ids) == 0 or kd is None:
        z = np.zeros(0, np.int64)
        return z, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), z
    q = np.column_stack([atlas.centers[ids], atlas.sheet[ids] * gap])
    found = kd.query_ball_point(q, r=atlas.radii[ids] * (1.0 + 1e-9), return_sorted=False)
    counts = np.fromiter((len(f) for f in found), np.int64, len(ids))
    owner = np.repeat(np.arange(len(ids)), counts)
    sample = np.fromiter((j for f in found for j in f), np.int64, int(counts.sum()))
    # sheet equality is implied by the fourth coordinate only if the gap exceeds the radius
    same = smp.sheet[sample] == atlas.sheet[ids[owner]]
    owner, sample = owner[same], sample[same]
    order = np.lexsort((smp.key[sample], owner))
    owner, sample = owner[order], sample[order]
    first = np.searchsorted(owner, np.arange(len(ids)))
    rank = np.arange(len(owner)) - first[owner]
    keep = rank < cap
    w = smp.weights[sample]
    total = np.bincount(owner, weights=w, minlength=len(ids))
    kept = np.bincount(owner[keep], weights=w[keep], minlength=len(ids))
    scale = np.where(kept > 0, total / np.maximum(kept, 1e-300), 1.0)
    owner, sample = owner[keep], sample[keep]
    return owner, smp.points[sample], smp.normals[sample], w[keep] * scale[owner], smp.triangle[sample]
