"""Lightmap texels' values: radiance (or irradiance) at the texel centres texels.rasterize found,
the direct light per texel and the final gather on a sparse grid of texels when a gather at every
texel would cast more rays than a budget, interpolated in between; texels on an edge of the light
(a shadow's, a wall standing on the surface, an albedo's) hold their mean over their area."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from ..light.direct import direct_irradiance
from ..overlap.queries import alpha_at
from ..overlap.sight import COVER, blocked, geometry_over
from ..radiosity.emission import bake_sky, own_emission
from .gather import GATHER_SEED, Gather, gather_unique
from .lattice import may_see_sky
from .points import BakeRequest, bake_normals, bake_sides, irradiance_at, nudge, radiance_at
from .texels import Texels, rasterize

_CHUNK = 1 << 17  # texels reconstructed at once
# Texel points are moved this fraction of the way to their triangle's centroid, off the exact edge
# (a texel centre on a UV seam lies on a chart's border, where patch membership is decided).
INSET = 1e-6
# The points of texel centres outside an island (REACH), on its edge, are moved towards their
# triangle's centroid as the vertex bake moves corners (points.nudge): a point on an island's
# edge lies on a chart's border, on the rim of the patches placed along it.
# Texel centres outside every UV triangle but within this many texels of one are baked at the
# nearest point of the island (texels.rasterize): every centre a bilinear filter reads at a point of
# an island (those less than one texel away in x and y) holds the light of the surface there.
REACH = 1.5
# The final gather (ray count x texels) runs on every step-th texel in x and y, step the smallest
# power of two keeping it under this many rays, and is interpolated in between (the direct light
# stays per texel). 2^23 rays: about 20 s on 2 cores; a 1024 px bake at 256 rays gathers at every
# 8th texel when its islands fill the image, every texel on a small bake.
GATHER_RAY_BUDGET = 1 << 23
SPREAD = 1.25  # neighbours' gathered light this far apart: the texel between them gathers itself
# A texel whose value differs from an 8-neighbour's by more than EDGE_JUMP x the larger of the two
# lies on an edge of the light: it holds the mean of SUPERSAMPLE x SUPERSAMPLE points over its
# square (where the surface is), not its centre's value. A bilinear read where a wall stands on a
# floor then gives about the mean of both sides whatever the texels' offset to the line, where
# point values give anything between the lit and the hidden side's.
EDGE_JUMP = 0.25
SUPERSAMPLE = 2
MIN_SUB_RAYS = 16  # gather rays per sub-point at least (a texel's sub-points cast rays // s^2 each)


def gather_step(count: int, rays: int, budget: int | None = None) -> int:
    """The texel step of the final gather: the smallest power of two with (count / step^2) x rays
    gather rays at most the budget (default GATHER_RAY_BUDGET)."""
    budget = GATHER_RAY_BUDGET if budget is None else budget
    step = 1
    while count * rays > budget * step * step:
        step *= 2
    return step


def texel_sizes(uv, world, size: int) -> np.ndarray:
    """(T,) world length of a texel's side on each triangle: sqrt(world area / area in texels)."""
    e1, e2 = world[:, 1] - world[:, 0], world[:, 2] - world[:, 0]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    u1, u2 = (uv[:, 1] - uv[:, 0]) * size, (uv[:, 2] - uv[:, 0]) * size
    texels = 0.5 * np.abs(u1[:, 0] * u2[:, 1] - u1[:, 1] * u2[:, 0])
    return np.sqrt(area / np.maximum(texels, 1e-300))


def sparse_gather(
    problem, radiosity, texels, width: int, light, step: int, size, sky: bool = False
) -> np.ndarray:
    """(k, 3) gathered indirect irradiance at the texels (with sky: plus the sky's direct light):
    gathered at the texels whose x and y are multiples of step, interpolated to the others from the
    (up to) 4 nearest gathered ones on the same plane within 2 steps (inverse distance); texels with
    none (a small island), or whose neighbours differ by more than SPREAD (an edge of the light),
    gather themselves. size (k,): the world length of a texel's side at each texel (texel_sizes())."""
    tri = texels.triangle
    sides = bake_sides(problem, tri)
    normals = bake_normals(problem, tri, sides)
    own = own_emission(problem, light.emitters, light.emission_scale)
    seen = bake_sky(problem, light, radiosity) if sky else None
    sky_only = replace(light, lamps=(), emitters=None)

    def gather(k):
        out = gather_unique(
            problem, Gather(radiosity, own, light.gather_rays), texels.points[k], normals[k], tri[k]
        )
        if sky:  # as a bake point's direct light gets it (bake.points), at these texels only
            pts = texels.points[k]
            a = alpha_at(problem.atlas, problem.index, problem.contacts, pts, tri[k], sides[k])
            rays = problem.index.rays
            out += direct_irradiance(
                problem.emitter_rules, rays, sky_only, pts, normals[k], may_see_sky(a, seen)
            )[0]
        return out

    x, y = texels.texel % width, texels.texel // width
    coarse = np.flatnonzero((x % step == 0) & (y % step == 0))
    if len(coarse) == 0:
        return gather(np.arange(len(texels)))
    out = np.zeros((len(texels), 3))
    out[coarse] = gather(coarse)
    pts = texels.points
    dist, nb = cKDTree(pts[coarse]).query(pts, k=min(4, len(coarse)))
    dist, nb = dist.reshape(len(pts), -1), nb.reshape(len(pts), -1)
    ok = np.isfinite(dist) & (dist <= 2.0 * step * size[:, None])
    g = coarse[np.minimum(nb, len(coarse) - 1)]
    same = np.einsum("ijk,ik->ij", normals[g], normals) > 0.999
    plane = np.abs(np.einsum("ijk,ik->ij", pts[g] - pts[:, None], normals)) <= 1e-5 * problem.surfaces.extent
    ok &= same & plane
    w = np.where(ok, 1.0 / np.maximum(dist, 1e-12 * problem.surfaces.extent), 0.0)
    # Where the neighbours disagree by more than SPREAD (a contact shadow's edge, the floor under
    # a block), interpolating would blur light across the edge: those texels gather themselves.
    level = out[g].sum(axis=2)
    hi = np.where(ok, level, -np.inf).max(axis=1)
    lo = np.where(ok, level, np.inf).min(axis=1)
    has = (w.sum(axis=1) > 0) & (hi <= SPREAD * lo + 1e-9 * max(float(np.abs(out).max()), 1e-300))
    rest = np.flatnonzero(has)
    rest = rest[~np.isin(rest, coarse)]
    wn = w[rest] / w[rest].sum(axis=1, keepdims=True)
    out[rest] = np.einsum("ij,ijk->ik", wn, out[g[rest]])
    alone = np.flatnonzero(~has)
    alone = alone[~np.isin(alone, coarse)]
    if len(alone):
        out[alone] = gather(alone)
    return out


def nudged(problem, texels) -> Texels:
    """The texels with the points of those outside their island (texels.outside) moved towards their
    triangle's centroid (points.nudge)."""
    if texels.outside is None:
        return texels
    out = texels.outside
    points = texels.points.copy()
    centres = problem.surfaces.corners[texels.triangle[out]].mean(axis=1)
    points[out] = nudge(problem, texels.points[out], centres)
    return Texels(texels.texel, texels.triangle, points, texels.weights, texels.outside)


def subset(texels, keep) -> Texels:
    """The texels where keep (k,) bool is True."""
    outside = None if texels.outside is None else texels.outside[keep]
    return Texels(
        texels.texel[keep], texels.triangle[keep], texels.points[keep], texels.weights[keep], outside
    )


def bake_values(
    problem,
    radiosity,
    texels,
    quantity: str,
    first_shot=None,
    light=None,
    width: int | None = None,
    size=None,
) -> np.ndarray:
    """Radiance (or irradiance / pi) (k, 3) at texel points, seen from the side bake.points.bake_sides
    picks for their triangle (as the vertex bake does); direct light computed at the texels when
    the solve's first shot and light are given, and the final gather on a grid of every
    gather_step()-th texel when it would cast more than GATHER_RAY_BUDGET rays (width: the image's,
    size (k,): each texel's world size, texel_sizes()); returns the values and that step."""
    fn = irradiance_at if quantity == "IRRADIANCE" else radiance_at
    indirect = None
    step = 1
    if light is not None and first_shot is not None and light.gather_rays > 0 and width is not None:
        step = gather_step(len(texels), light.gather_rays)
        if step > 1:
            # the sky's direct light, soft as the indirect, is computed and interpolated with it
            sky = light.sky is not None and light.sky.emits
            indirect = sparse_gather(problem, radiosity, texels, width, light, step, size, sky)
            if sky:
                light = replace(light, sky=None)
    out = np.zeros((len(texels), 3))
    cache: dict = {}  # one lattice cache for every chunk (bake.gather.Gather.corner_cache)
    for s in range(0, len(texels), _CHUNK):
        sl = slice(s, s + _CHUNK)
        pts, tri = texels.points[sl], texels.triangle[sl]
        part = None if indirect is None else indirect[sl]
        request = BakeRequest(radiosity, first_shot, light, indirect=part, corner_cache=cache)
        out[sl] = fn(problem, request, pts, tri, bake_sides(problem, tri))
    # Smooth beta rings slightly below 0 next to contact shadows; light is never negative.
    return np.maximum(out, 0.0), step


def texel_values(problem, radiosity, texels, quantity: str, first_shot, light, width: int, sizes):
    """(k, 3) values of a lightmap's texels (texels.rasterize; width: the image's) and the largest
    gather step used: the centres in the islands first, then those just outside (their points
    nudged, their gathers not interpolated from the others'). sizes (k,): texel_sizes() per texel."""
    texels = nudged(problem, texels)
    outside = np.zeros(len(texels), bool) if texels.outside is None else texels.outside
    values = np.zeros((len(texels), 3))
    step = 1
    for part in (~outside, outside):
        if part.any():
            values[part], s = bake_values(
                problem, radiosity, subset(texels, part), quantity, first_shot, light, width, sizes[part]
            )
            step = max(step, s)
    return values, step


def edge_texels(
    problem, texels, values, width: int, height: int, sizes, jump: float = EDGE_JUMP
) -> np.ndarray:
    """(k,) bool: texels (inside their island) on a geometric edge of the light: their summed value
    differs from an 8-neighbour's by more than jump x the larger of the two (differences under
    1e-6 x the largest value ignored) and the segment between their points, lifted a hundredth of
    a texel off the surface, is blocked (a wall standing on the surface, or the surface entering a
    solid), or one of them is covered and the other not (geometry over it closer than COVER x the
    median patch radius: a panel under a ceiling, a board over a floor). A shadow's or an albedo's
    edge, with nothing between or over the texels, is none: there the texels keep their centre's
    value (what a vertex there gets). sizes (k,): texel_sizes()."""
    k = len(texels)
    level = np.full(width * height, np.nan)
    level[texels.texel] = np.asarray(values, np.float64).sum(axis=1)
    where = np.full(width * height, -1, np.int64)
    where[texels.texel] = np.arange(k)
    if texels.outside is not None:
        level[texels.texel[texels.outside]] = np.nan  # centres outside the islands are no edge
    img = np.pad(level.reshape(height, width), 1, constant_values=np.nan)
    idx = np.pad(where.reshape(height, width), 1, constant_values=-1)
    centre, me = img[1:-1, 1:-1], idx[1:-1, 1:-1]
    floor = 1e-6 * max(float(np.nanmax(level, initial=0.0)), 1e-300)
    first, second = [], []
    with np.errstate(invalid="ignore"):
        for dy, dx in ((0, 2), (1, 2), (2, 2), (2, 1)):  # each neighbour pair once
            nb, other = img[dy : dy + height, dx : dx + width], idx[dy : dy + height, dx : dx + width]
            diff = np.abs(centre - nb)
            pair = (diff > jump * np.fmax(centre, nb)) & (diff > floor)
            first.append(me[pair])
            second.append(other[pair])
    a, b = np.concatenate(first), np.concatenate(second)
    out = np.zeros(k, bool)
    if len(a) == 0:
        return out
    # the texels of the pairs: their normals and a lift of a hundredth of a texel, once each
    ends, pair = np.unique(np.concatenate([a, b]), return_inverse=True)
    pa, pb = pair[: len(a)], pair[len(a) :]
    t_end = texels.triangle[ends]
    normals = bake_normals(problem, t_end, bake_sides(problem, t_end))
    lift = np.maximum(0.01 * np.asarray(sizes, np.float64)[ends], 1e-6 * problem.surfaces.extent)
    hit = blocked(problem.index, normals[pa], lift[pa], texels.points[a], texels.points[b])
    # ... or one of the two is covered and the other not (a panel hung under a ceiling, a board
    # low over a floor: the contacts' rule, overlap.sight.covered, at the median patch radius)
    reach = np.full(len(ends), COVER * float(np.median(problem.atlas.radii)))
    over = geometry_over(problem.index.rays, texels.points[ends], normals, lift, reach)
    hit |= over[pa] != over[pb]
    out[a[hit]] = True
    out[b[hit]] = True
    return out


def sub_points(uv, world, ids, texels, flagged, width: int, height: int, s: int):
    """The sub-points of the flagged texels: the centres of an s x s grid over each texel's square
    that lie on one of the UV triangles (rasterize at s times the size). Returns (Texels, parent
    (m,) the index of each one's texel in texels, slot (m,) its place in the grid, 0 .. s^2 - 1)."""
    mark = np.zeros(width * height, bool)
    mark[texels.texel[flagged]] = True
    # only triangles whose UV bounding box meets a flagged texel (a summed-area table of the marks)
    table = np.zeros((height + 1, width + 1))
    table[1:, 1:] = mark.reshape(height, width).cumsum(axis=0).cumsum(axis=1)
    px = np.asarray(uv, np.float64) * (width, height)
    lo = np.clip(np.floor(px.min(axis=1)).astype(np.int64), 0, (width - 1, height - 1))
    hi = np.clip(np.floor(px.max(axis=1)).astype(np.int64), 0, (width - 1, height - 1)) + 1
    hits = (
        table[hi[:, 1], hi[:, 0]]
        - table[lo[:, 1], hi[:, 0]]
        - table[hi[:, 1], lo[:, 0]]
        + table[lo[:, 1], lo[:, 0]]
    )
    near = np.flatnonzero(np.isfinite(hits) & (hits > 0))
    sub = rasterize(uv[near], world[near], ids[near], width * s, height * s, inset=INSET)
    col, row = sub.texel % (width * s), sub.texel // (width * s)
    parent_texel = (row // s) * width + col // s
    keep = mark[parent_texel]
    sub = subset(sub, keep)
    parent = np.searchsorted(texels.texel, parent_texel[keep])
    slot = ((row % s) * s + col % s)[keep]
    return sub, parent, slot


def supersampled(problem, radiosity, sub, parent, slot, count: int, quantity: str, first_shot, light, s: int):
    """(count, 3) the mean value over each texel's sub-points (sub_points(); NaN for a texel with
    none). Each sub-point gets its own direct light and a final gather of gather_rays // s^2 rays
    (at least MIN_SUB_RAYS), the sub-points of one slot with a pattern of their own, so a texel's
    sub-points together cast about as many distinct directions as one gather."""
    fn = irradiance_at if quantity == "IRRADIANCE" else radiance_at
    values = np.zeros((len(sub), 3))
    cache: dict = {}
    for k in range(s * s):
        at = np.flatnonzero(slot == k)
        if len(at) == 0:
            continue
        lit = light
        if light is not None and light.gather_rays > 0:
            rays = max(MIN_SUB_RAYS, light.gather_rays // (s * s))
            lit = replace(light, gather_rays=min(rays, light.gather_rays), gather_seed=GATHER_SEED + 1 + k)
        for c in range(0, len(at), _CHUNK):
            part = at[c : c + _CHUNK]
            tri = sub.triangle[part]
            request = BakeRequest(radiosity, first_shot, lit, corner_cache=cache)
            values[part] = fn(problem, request, sub.points[part], tri, bake_sides(problem, tri))
    total = np.zeros((count, 3))
    for c in range(3):
        total[:, c] = np.bincount(parent, weights=np.maximum(values[:, c], 0.0), minlength=count)
    n = np.bincount(parent, minlength=count).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return total / n[:, None]


def bake_lightmap(
    problem,
    radiosity,
    uv,
    world,
    ids,
    size: int,
    quantity: str,
    first_shot,
    light,
    supersample: int = SUPERSAMPLE,
):
    """A lightmap's texels and their values (k, 3) through UV triangles uv (T, 3, 2) on world
    triangles (T, 3, 3) with surface triangle ids (T,), an image size x size: the centres
    (texel_values), then the mean over SUPERSAMPLE^2 sub-points on the texels on an edge of the
    light (edge_texels; supersample 1: none). Returns (texels, values, gather step, edge texels)."""
    uv = np.asarray(uv, np.float64).reshape(-1, 3, 2)
    world = np.asarray(world, np.float64).reshape(-1, 3, 3)
    ids = np.asarray(ids, np.int64).reshape(-1)
    texels = rasterize(uv, world, ids, size, size, inset=INSET, reach=REACH)
    if len(texels) == 0:
        return texels, np.zeros((0, 3)), 1, 0
    order = np.argsort(ids, kind="stable")
    sizes = texel_sizes(uv, world, size)[order[np.searchsorted(ids[order], texels.triangle)]]
    values, step = texel_values(problem, radiosity, texels, quantity, first_shot, light, size, sizes)
    if supersample <= 1:
        return texels, values, step, 0
    flagged = edge_texels(problem, texels, values, size, size, sizes)
    if not flagged.any():
        return texels, values, step, 0
    sub, parent, slot = sub_points(uv, world, ids, texels, flagged, size, size, supersample)
    means = supersampled(
        problem, radiosity, sub, parent, slot, len(texels), quantity, first_shot, light, supersample
    )
    got = flagged & np.isfinite(means[:, 0])
    values[got] = means[got]
    return texels, values, step, int(got.sum())
