"""Emissive triangles as a fixed rule of samples (the same for every receiver point: no noise) and
the exact irradiance of a triangle at a point (polygon_irradiance)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import subtriangle_centroids
from ..scene.surfaces import Surfaces, triangle_geometry


@dataclass(frozen=True)
class EmitterSamples:
    """A fixed quadrature of the emitting surfaces: points (k, 3), unit normals (k, 3), the area
    each point stands for (k,), and its emitted radiance (k, 3) (of picked samples, scaled per
    channel: emitter_samples)."""

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    radiance: np.ndarray
    # each emitting triangle's own samples (None when samples stand for a share of the total power):
    # the first sample of each triangle's run (s,), the triangle (s,) of each run, and per emitting
    # triangle its corners (E, 3, 3), radiance (E, 3) and spacing of its samples (E,)
    run_start: np.ndarray | None = None
    run_triangle: np.ndarray | None = None
    corners: np.ndarray | None = None
    triangle_radiance: np.ndarray | None = None
    spacing: np.ndarray | None = None
    # samples picked on the power of more emitting triangles than samples: each one's triangle (k,),
    # non-decreasing (a triangle's samples are one run); corners, triangle_radiance and spacing
    # then hold every emitting triangle's
    pick: np.ndarray | None = None


def emitter_samples(
    surfaces: Surfaces, emitters: np.ndarray, count: int, scale: float = 1.0
) -> EmitterSamples:
    """About `count` points over the emitting triangles, shared by every receiver point.

    A fixed rule instead of random samples per receiver: neighbouring bake points see the same
    samples, so the result is smooth (no noise); its error is that of a midpoint rule. Each
    triangle gets points in proportion to its power, as the centroids of its k^2 congruent
    sub-triangles; when there are more emitting triangles than points, `count` of them are
    picked by systematic sampling on their power, each point standing for an equal power, its
    colour scaled per channel so that the points emit the triangles' power in each channel.
    """
    tri = np.flatnonzero(np.asarray(emitters, bool) & (surfaces.emission.sum(axis=1) > 0))
    c = surfaces.corners[tri]
    area, normal = triangle_geometry(c)
    radiance = surfaces.emission[tri] * scale
    power = area * radiance.sum(axis=1)
    keep = power > 0
    c, normal, area, radiance, power = c[keep], normal[keep], area[keep], radiance[keep], power[keep]
    if len(c) == 0 or count < 1:
        z = np.zeros((0, 3))
        return EmitterSamples(z, z, np.zeros(0), z)
    total = power.sum()
    if len(c) >= count:
        pick = np.searchsorted(np.cumsum(power) / total, (np.arange(count) + 0.5) / count)
        pick = np.minimum(pick, len(c) - 1)
        pts = c[pick].mean(axis=1)
        # one sample stands for total / count of the power: on triangle t, for this much area (a dim
        # triangle's at most what an even spread of the samples over the area would give it: its
        # near field is as faint as its light, and the search for near triangles stays local)
        spacing = np.minimum(np.sqrt(total / count / radiance.sum(axis=1)), np.sqrt(area.sum() / count))
        weight = area[pick] * (total / count) / power[pick]
        # picked on the power summed over the channels, the samples give a colour more or fewer
        # samples than its share (a grid mesh is picked row by row, and the stride can keep landing
        # in the same columns: 16 samples on a panel half red, half blue give one half up to 23 %
        # too much light, the other too little); each channel is scaled so that the samples emit
        # the emitters' power in it (a single-colour emitter's scale is 1)
        sampled = weight @ radiance[pick]
        scale_rgb = np.divide(area @ radiance, sampled, out=np.ones(3), where=sampled > 0)
        return EmitterSamples(
            pts,
            normal[pick],
            weight,
            radiance[pick] * scale_rgb,
            corners=c,
            triangle_radiance=radiance,
            spacing=spacing,
            pick=pick,
        )
    want = np.maximum(1, np.round(count * power / total)).astype(np.int64)
    side = np.ceil(np.sqrt(want)).astype(np.int64)
    pts, nrm, wts, rad, owner = [], [], [], [], []
    for k in np.unique(side):
        sel = np.flatnonzero(side == k)
        uv = subtriangle_centroids(int(k))
        cc = c[sel]
        p = cc[:, None, 0] + uv[None, :, :1] * (cc[:, None, 1] - cc[:, None, 0])
        p = p + uv[None, :, 1:] * (cc[:, None, 2] - cc[:, None, 0])
        pts.append(p.reshape(-1, 3))
        nrm.append(np.repeat(normal[sel], len(uv), axis=0))
        wts.append(np.repeat(area[sel] / len(uv), len(uv)))
        rad.append(np.repeat(radiance[sel], len(uv), axis=0))
        owner.append(np.repeat(sel, len(uv)))
    owner = np.concatenate(owner)  # each triangle's samples are one run
    start = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
    spacing = np.sqrt(area / side**2)
    return EmitterSamples(
        np.vstack(pts),
        np.vstack(nrm),
        np.concatenate(wts),
        np.vstack(rad),
        start,
        owner[start],
        c,
        radiance,
        spacing,
    )


def polygon_irradiance(points: np.ndarray, normals: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Irradiance (k,) at points (k, 3) with unit normals (k, 3) from triangles (k, 3, 3) of unit
    radiance emitting from both sides, unoccluded: (1/2) |sum over edges gamma_i n . c_i| (Lambert's
    contour integral, pi x the form factor) over the part of the triangle above the point's plane."""
    h = np.einsum("kcj,kj->kc", triangles - points[:, None], normals)
    whole = h.min(axis=1) > 0
    if whole.all():
        return _unclipped_irradiance(triangles - points[:, None], normals)
    if whole.any():
        out = np.empty(len(points))
        out[whole] = _unclipped_irradiance(triangles[whole] - points[whole, None], normals[whole])
        part = ~whole
        out[part] = polygon_irradiance(points[part], normals[part], triangles[part])
        return out
    slots = np.zeros((len(points), 6, 3))
    valid = np.zeros((len(points), 6), bool)
    for j in range(3):  # Sutherland-Hodgman: each corner above the plane, each edge's crossing
        a, b = triangles[:, j], triangles[:, (j + 1) % 3]
        ha, hb = h[:, j], h[:, (j + 1) % 3]
        slots[:, 2 * j], valid[:, 2 * j] = a, ha > 0
        cross = (ha > 0) != (hb > 0)
        f = np.where(cross, ha / np.where(cross, ha - hb, 1.0), 0.0)
        slots[:, 2 * j + 1], valid[:, 2 * j + 1] = a + f[:, None] * (b - a), cross
    r = slots - points[:, None]
    total = np.zeros(len(points))
    for j in range(6):  # each kept vertex to the next kept one, cyclically
        nxt = np.full(len(points), -1)
        for o in range(5, 0, -1):
            nxt = np.where(valid[:, (j + o) % 6], (j + o) % 6, nxt)
        use = valid[:, j] & (nxt >= 0)
        a = r[:, j]
        b = np.take_along_axis(r, np.maximum(nxt, 0)[:, None, None].repeat(3, axis=2), axis=1)[:, 0]
        c = np.cross(a, b)
        cn = np.linalg.norm(c, axis=1)
        gamma = np.arctan2(cn, np.einsum("kj,kj->k", a, b))
        total += np.where(
            use & (cn > 0), gamma * np.einsum("kj,kj->k", c, normals) / np.maximum(cn, 1e-300), 0.0
        )
    return 0.5 * np.abs(total)


def _unclipped_irradiance(r: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """polygon_irradiance of triangles wholly above the points' planes, given as their corners less
    the points (k, 3, 3): the contour's three edges, nothing to clip."""
    total = np.zeros(len(r))
    for j in range(3):
        a, b = r[:, j], r[:, (j + 1) % 3]
        c = np.cross(a, b)
        cn = np.sqrt(np.einsum("kj,kj->k", c, c))
        gamma = np.arctan2(cn, np.einsum("kj,kj->k", a, b))
        total += np.where(cn > 0, gamma * np.einsum("kj,kj->k", c, normals) / np.maximum(cn, 1e-300), 0.0)
    return 0.5 * np.abs(total)
