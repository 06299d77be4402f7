"""The light tree of emitters picked on power: nodes of nearby emitting triangles taken as one point
where far enough, the near ones by their exact form factor (near_picked)."""

from __future__ import annotations

import numpy as np

from ..geometry import ranges_flat
from ..scene.surfaces import triangle_geometry
from .emitters import EmitterSamples, polygon_irradiance
from .lamps import shadow_origin

NEAR_EMITTER = 2.0  # a point closer to an emitting triangle's samples than this x their spacing
# gets that triangle's light from its exact form factor (polygon_irradiance), not from the samples
NEAR_EXACT = 4.0  # ... or, picked samples (near_picked), a node of the light tree as one point this x its
# radius away

NEAR_POINTS = 1 << 13  # points whose near emitters near_picked finds at once (memory: their frontier)

NEAR_CONE = 0.97  # a light-tree node whose normals stray over acos(this) from its axis is never one point


def _first_max_in_runs(values: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Index of the first largest value in each run of `values`, runs starting at `first` (sorted,
    first[0] = 0) and tiling the array."""
    seg = np.repeat(np.arange(len(first)), np.diff(np.r_[first, len(values)]))
    hit = np.flatnonzero(values == np.maximum.reduceat(values, first)[seg])
    return hit[np.r_[True, seg[hit][1:] != seg[hit][:-1]]]


class LightTree:
    """The emitting triangles of picked samples as a binary tree (a light hierarchy), for
    near_picked. Level l has 2^l nodes, each a range [lo, hi) of the triangles in tree order; node
    j's children are 2j and 2j + 1 a level down (a single triangle's: itself and an empty range).
    Each node holds its area-weighted centroid, bounding radius, its triangles' centroids' spread
    about it, the least and greatest reach of their near fields (their size + NEAR_EMITTER x their
    samples' spacing), its bounding box, a normal axis and how far from it a direction must be for
    every face to be seen from one side (from its cone: the least cosine of a triangle's normal,
    turned to the axis's side, with it), its second moment of area, the power vector per colour
    (sum of area x radiance x turned normal: one dot product gives a far flat node's light), the
    triangle nearest its centroid (a shadow ray's target) and its samples' range in `sample_order`.
    Fewer than 4 x triangles nodes, 288 bytes each (about 1.2 kB per emitting triangle); built once
    per emitter rule, a level at a time (a sort within each node along its longest side)."""

    def __init__(self, src: EmitterSamples):
        c = src.corners
        n = len(c)
        self.corners, self.radiance = c, src.triangle_radiance
        centroid = c.mean(axis=1)
        size = np.linalg.norm(c - centroid[:, None], axis=2).max(axis=1)
        area, normal = triangle_geometry(c)
        self.centroid_t, self.normal_t = centroid, normal
        order = np.arange(n)
        lo, hi = np.zeros(1, np.int64), np.full(1, n, np.int64)
        ranges = [(lo, hi)]
        while np.any(hi - lo > 1):
            seg = np.repeat(np.arange(len(lo)), hi - lo)
            x = centroid[order]
            full = hi > lo
            span = np.maximum.reduceat(x, lo[full], axis=0) - np.minimum.reduceat(x, lo[full], axis=0)
            side = np.zeros(len(lo), np.int64)
            side[full] = span.argmax(axis=1)
            order = order[np.lexsort((x[np.arange(n), side[seg]], seg))]
            mid = np.where(hi - lo > 1, lo + (hi - lo + 1) // 2, hi)
            lo, hi = np.stack([lo, mid], 1).ravel(), np.stack([mid, hi], 1).ravel()
            ranges.append((lo, hi))
        rank = np.empty(n, np.int64)
        rank[order] = np.arange(n)
        at = rank[src.pick]
        self.sample_order = np.argsort(at, kind="stable")
        at = at[self.sample_order]
        cen, a, nrm, rad = centroid[order], area[order], normal[order], src.triangle_radiance[order]
        size, reach = size[order], size[order] + NEAR_EMITTER * src.spacing[order]
        corner_lo, corner_hi = c[order].min(axis=1), c[order].max(axis=1)
        spoke = c[order] - cen[:, None]
        own = np.einsum("tci,tci->ti", spoke[:, :, _PAIRS[0]], spoke[:, :, _PAIRS[1]]) / 12.0
        self.levels = []  # per level: floats (k, 23) (columns: _F), ints (k, 4) (_I), power (k, 3, 3)
        for lo, hi in ranges:
            full = np.flatnonzero(hi > lo)
            first = lo[full]
            run = np.repeat(np.arange(len(full)), (hi - lo)[full])  # the full nodes tile the triangles
            area_sum = np.add.reduceat(a, first)
            C = np.add.reduceat(cen * a[:, None], first, axis=0) / area_sum[:, None]
            off = cen - C[run]
            spread = np.linalg.norm(off, axis=1)
            box_lo = np.minimum.reduceat(corner_lo, first, axis=0)
            box_hi = np.maximum.reduceat(corner_hi, first, axis=0)
            # the axis: the node's largest triangle's normal, then the area-weighted mean of the
            # normals turned to its side; the cone: the least cosine of a turned normal with it
            big = _first_max_in_runs(a, first)
            turned = nrm * np.where(np.einsum("ij,ij->i", nrm, nrm[big[run]]) < 0, -1.0, 1.0)[:, None]
            axis = np.add.reduceat(turned * a[:, None], first, axis=0)
            axis /= np.maximum(np.linalg.norm(axis, axis=1), 1e-300)[:, None]
            cone = np.minimum.reduceat(np.einsum("ij,ij->i", turned, axis[run]), first)
            # seen from one side where |axis . direction| >= this (never for a cone wider than NEAR_CONE)
            one_side = np.where(cone >= NEAR_CONE, np.sqrt(np.maximum(1.0 - cone**2, 0.0)), np.inf)
            # the node's second moment of area about C over its area (xx, yy, zz, xy, xz, yz): each
            # triangle's centroid offset, plus its own (1/12 of the sum of its corners' offsets squared)
            moment = a[:, None] * (off[:, _PAIRS[0]] * off[:, _PAIRS[1]] + own)
            moment = np.add.reduceat(moment, first, axis=0) / area_sum[:, None]
            F = np.zeros((len(lo), 23))
            F[full] = np.column_stack(
                [
                    C,
                    np.maximum.reduceat(spread, first),
                    np.maximum.reduceat(spread + size, first),
                    np.minimum.reduceat(reach, first),
                    np.maximum.reduceat(reach, first),
                    (box_lo + box_hi) / 2,
                    (box_hi - box_lo) / 2,
                    axis,
                    one_side,
                    moment,
                ]
            )
            I = np.zeros((len(lo), 4), np.int64)  # noqa: E741
            I[:, 0] = hi - lo
            I[full, 1] = order[_first_max_in_runs(-spread, first)]
            I[:, 2], I[:, 3] = np.searchsorted(at, lo), np.searchsorted(at, hi)
            power = np.zeros((len(lo), 3, 3))
            power[full] = np.add.reduceat((a[:, None] * rad)[:, :, None] * turned[:, None, :], first, axis=0)
            self.levels.append((F, I, power))


# columns of a LightTree level's floats and ints
_F = {"centroid": slice(0, 3), "spread": 3, "radius": 4, "reach_min": 5, "reach_max": 6}

_F |= {"box_mid": slice(7, 10), "box_half": slice(10, 13), "axis": slice(13, 16), "one_side": 16}
_F["moment"] = slice(17, 23)
_I = {"count": 0, "rep": 1, "s_lo": 2, "s_hi": 3}

_PAIRS = (np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2]))  # a symmetric 3 x 3's six entries


def second_order(moment: np.ndarray, u: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The relative correction (k,) of a node's one-point light for its extent: with u from the
    point to the node's centroid, a the point's normal and b the node's axis on the point's side,
    the light is A f(u) + (1/2) tr(S Hess f) for f = (a.u)(b.u)/|u|^4 and S the node's second moment
    of area (k, 6: xx, yy, zz, xy, xz, yz), A f(u) the one-point rule; divided by A f(u):
    a.S.b/((a.u)(b.u)) - 4 (u.S.a/(a.u) + u.S.b/(b.u))/|u|^2 - 2 tr S/|u|^2 + 12 u.S.u/|u|^4."""
    S = np.empty((len(u), 3, 3))
    S[:, _PAIRS[0], _PAIRS[1]] = moment
    S[:, _PAIRS[1], _PAIRS[0]] = moment
    Su = np.einsum("kij,kj->ki", S, u)
    au, bu = np.einsum("kj,kj->k", a, u), np.einsum("kj,kj->k", b, u)
    r2 = np.einsum("kj,kj->k", u, u)
    aSb = np.einsum("ki,kij,kj->k", a, S, b)
    tr = moment[:, 0] + moment[:, 1] + moment[:, 2]
    return (
        aSb / (au * bu)
        - 4.0 * (np.einsum("kj,kj->k", Su, a) / au + np.einsum("kj,kj->k", Su, b) / bu) / r2
        - 2.0 * tr / r2
        + 12.0 * np.einsum("kj,kj->k", Su, u) / r2**2
    )


def near_picked(H, rs, P, N, src: EmitterSamples, tree: LightTree, g, rays, eps: float) -> int:
    """_near_emitters for samples picked on the power of more triangles than samples (a subdivided
    panel, an emissive mesh): the emitting triangles within NEAR_EMITTER sample spacings of a point
    give their own light in place of what the samples picked on them gave. Walking the light tree,
    a node of them farther than NEAR_EXACT x its radius, wholly above the point's horizon and flat
    enough that the point sees all its faces from one side, gives its light as one point (its power
    vector, corrected to second order for its extent: second_order); a node wholly under the
    horizon gives none; a single triangle nearer than that, its exact unoccluded light (Lambert's
    contour);
    each x whether the point sees the node's central triangle's centroid (one shadow ray). Points
    go in blocks of NEAR_POINTS. Returns the rays cast."""
    cast = 0
    for b0 in range(0, len(P), NEAR_POINTS):
        block = np.arange(b0, min(len(P), b0 + NEAR_POINTS))
        cast += _near_block(H, rs, P, N, src, tree, g, rays, eps, block)
    return cast


def _near_block(H, rs, P, N, src: EmitterSamples, tree: LightTree, g, rays, eps, block) -> int:
    """near_picked for the points `block`: the tree walked a level at a time for all of them at once
    (a frontier of (point, node) pairs), then one batch of shadow rays."""
    i, j = block, np.zeros(len(block), np.int64)
    found = []  # per level: points, irradiance (., 3), central triangle, samples' range
    for F, I, power in tree.levels:  # noqa: E741
        ints = I[j]
        live = ints[:, _I["count"]] > 0
        if not live.all():
            i, j, ints = i[live], j[live], ints[live]
        if len(i) == 0:
            break
        f, Pi, Ni = F[j], P[i], N[i]
        v = f[:, _F["centroid"]] - Pi
        d = np.sqrt(np.einsum("ij,ij->i", v, v))
        spread, radius = f[:, _F["spread"]], f[:, _F["radius"]]
        near = d + spread < f[:, _F["reach_min"]]
        far = d - spread >= f[:, _F["reach_max"]]
        single = ints[:, _I["count"]] == 1
        rep = ints[:, _I["rep"]]
        height = np.einsum("ij,ij->i", v, Ni)
        # wholly above the point's horizon, or wholly under it (no light, and its samples gave none):
        # by the node's bounding ball or its box (a flat node parallel to the point's plane, a panel
        # under a ceiling, has a thin box); a single triangle's by its corners
        box = np.einsum("ij,ij->i", f[:, _F["box_mid"]] - Pi, Ni)
        half = np.einsum("ij,ij->i", f[:, _F["box_half"]], np.abs(Ni))
        above = (height > radius) | (box > half)
        under = (height < -radius) | (box < -half)
        one = np.flatnonzero(single & near)
        h = np.einsum("kcj,kj->kc", tree.corners[rep[one]] - Pi[one][:, None], Ni[one])
        above[one], under[one] = h.min(axis=1) > 0, h.max(axis=1) <= 0
        far |= under
        near &= ~under
        omega = v / np.maximum(d, 1e-300)[:, None]
        sees_one_side = np.abs(np.einsum("ij,ij->i", omega, f[:, _F["axis"]])) >= f[:, _F["one_side"]]
        point = near & above & sees_one_side & (d > NEAR_EXACT * radius)
        contour = near & single & ~point
        E = np.zeros((len(i), 3))
        p = np.flatnonzero(point)
        cos_r = height[p] / np.maximum(d[p], 1e-300)
        E[p] = cos_r[:, None] * np.abs(np.einsum("kcj,kj->kc", power[j[p]], omega[p])) / d[p, None] ** 2
        if len(p):
            axis = f[p, _F["axis"]]
            axis *= np.where(np.einsum("ij,ij->i", axis, v[p]) < 0, -1.0, 1.0)[:, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                fix = second_order(f[p, _F["moment"]], v[p], Ni[p], axis)
            E[p] *= np.clip(np.nan_to_num(1.0 + fix, nan=1.0), 0.0, 2.0)[:, None]
        q = np.flatnonzero(contour)
        E[q] = polygon_irradiance(Pi[q], Ni[q], tree.corners[rep[q]])[:, None] * tree.radiance[rep[q]]
        done = np.flatnonzero(point | contour)
        found.append((i[done], E[done], rep[done], ints[done, _I["s_lo"]], ints[done, _I["s_hi"]]))
        down = ~far
        down[done] = False
        i, j = np.repeat(i[down], 2), (2 * j[down, None] + [0, 1]).ravel()
    if not found:
        return 0
    i, E, rep, s_lo, s_hi = (np.concatenate(x) for x in zip(*found, strict=True))
    if len(i) == 0:
        return 0
    target = tree.centroid_t[rep]
    v = target - P[i]
    omega = v / np.maximum(np.linalg.norm(v, axis=1), 1e-300)[:, None]
    ask = (np.einsum("ij,ij->i", omega, N[i]) > 0) & (E.sum(axis=1) > 0)
    seen = np.ones(len(i))  # a centroid under the point's horizon: the clipped part is seen
    cast = int(ask.sum())
    if cast:
        normal = tree.normal_t[rep[ask]]
        facing = np.einsum("ij,ij->i", omega[ask], normal)
        origin = shadow_origin(P[i][ask], N[i][ask], omega[ask], eps)
        seg = target[ask] - (eps * np.sign(facing))[:, None] * normal - origin
        length = np.linalg.norm(seg, axis=1)
        seen[ask] = rays.transmittance(origin, seg / np.maximum(length, 1e-300)[:, None], length * (1 - 1e-6))
    np.add.at(H, rs[i], E * seen[:, None])
    # less what the samples picked on those triangles gave (a node's samples are one run)
    many = s_hi - s_lo
    if many.sum():
        row = np.repeat(i, many)
        sample = tree.sample_order[ranges_flat(s_lo, many)]
        np.add.at(H, rs[row], -g[row, sample][:, None] * src.radiance[sample])
    return cast
