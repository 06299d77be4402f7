"""The light tree of emitters of more triangles than samples: its cut of nodes of equal power is
every point's far field (one sample per node); a point near a node walks its subtree (light/near.py)."""

from __future__ import annotations

import numpy as np

from ..geometry import ranges_flat
from ..scene.surfaces import triangle_geometry
from .emitters import EmitterSamples

NEAR_CONE = 0.97  # a light-tree node whose normals stray over acos(this) from its axis is never one point


def _first_max_in_runs(values: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Index of the first largest value in each run of `values`, runs starting at `first` (sorted,
    first[0] = 0) and tiling the array."""
    seg = np.repeat(np.arange(len(first)), np.diff(np.r_[first, len(values)]))
    hit = np.flatnonzero(values == np.maximum.reduceat(values, first)[seg])
    return hit[np.r_[True, seg[hit][1:] != seg[hit][:-1]]]


CUT_CONES = (0.9, 0.7, 0.5, -1.0)  # the cut's nodes have normals within acos(the first of these
# that leaves at most CUT_MOST x the samples asked) of their axis

CUT_MOST = 4

CUT_REACH = 3.0  # a point nearer a cut node's triangles than this x the node's radius walks its subtree


class LightTree:
    """The emitting triangles (corners (n, 3, 3), radiance (n, 3)) as a binary tree (a light
    hierarchy), cut into about `count` nodes of equal power whose one-point light is every point's
    far field (`samples`), the near field walked by near_picked. Level l has 2^l nodes, each a range
    [lo, hi) of the triangles in tree order; node j's children are 2j and 2j + 1 a level down (a
    single triangle's: itself and an empty range). Each node holds its area-weighted centroid,
    bounding radius, its triangles' centroids' spread about it, the least and greatest reach of their
    near fields (their size + CUT_REACH x their cut node's radius), its bounding box, a normal axis
    and how far from it a direction must be for every face to be seen from one side (from its cone:
    the least cosine of a triangle's normal, turned to the axis's side, with it), its second moment
    of area, the power vector per colour (sum of area x radiance x turned normal:
    one dot product gives a far flat node's light), the triangle nearest its centroid (a shadow
    ray's target) and its samples' range in `sample_order` (empty under the cut).

    The cut: the nodes of at most a power tau (the largest that leaves `count` of them), split
    further while their normals stray too far from their axis (CUT_CONES); each is one sample at its
    central triangle's centroid with its power vector, its normals' spread and its second moment of
    area (a curved emitter's far light is then the sum of its pieces' projected areas, not a
    quadrature of single triangles facing every way: a UV sphere of 4 032 triangles seen from 400
    directions 1 m away, 1.4-1.5 % RMS with 16 or 64 samples, against 14 and 4.6 % with triangles
    picked on power). Fewer than 4 x triangles nodes, about 1.2 kB per emitting triangle; built once
    per emitter rule, a level at a time (a sort within each node along its longest side)."""

    def __init__(self, corners: np.ndarray, radiance: np.ndarray, count: int):
        c = np.asarray(corners, np.float64)
        n = len(c)
        self.corners, self.radiance = c, np.asarray(radiance, np.float64)
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
        cen, a, nrm, rad = centroid[order], area[order], normal[order], self.radiance[order]
        size = size[order]
        corner_lo, corner_hi = c[order].min(axis=1), c[order].max(axis=1)
        spoke = c[order] - cen[:, None]
        own = np.einsum("tci,tci->ti", spoke[:, :, _PAIRS[0]], spoke[:, :, _PAIRS[1]]) / 12.0
        flux_t = a * rad.sum(axis=1)
        # per level: floats (k, 23) (columns: NODE_FLOATS), ints (k, 4) (NODE_INTS), power (k, 3, 3)
        self.levels = []
        fluxes, extra = [], []
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
            # the turned normals' mean vector (its length under 1 on a curved node) and second moment
            mean_n = np.add.reduceat(turned * a[:, None], first, axis=0) / area_sum[:, None]
            nn = np.add.reduceat(turned[:, _PAIRS[0]] * turned[:, _PAIRS[1]] * a[:, None], first, axis=0)
            nn /= area_sum[:, None]
            F = np.zeros((len(lo), 23))
            F[full] = np.column_stack(
                [
                    C,
                    np.maximum.reduceat(spread, first),
                    np.maximum.reduceat(spread + size, first),
                    np.zeros((len(full), 2)),  # the reaches, once the cut is known
                    (box_lo + box_hi) / 2,
                    (box_hi - box_lo) / 2,
                    axis,
                    one_side,
                    moment,
                ]
            )
            G = np.zeros((len(lo), 11))  # what the cut needs, apart: the walk reads F's rows
            G[full] = np.column_stack([cone, area_sum, mean_n, nn])
            I = np.zeros((len(lo), 4), np.int64)  # noqa: E741
            I[:, 0] = hi - lo
            I[full, 1] = order[_first_max_in_runs(-spread, first)]
            power = np.zeros((len(lo), 3, 3))
            power[full] = np.add.reduceat((a[:, None] * rad)[:, :, None] * turned[:, None, :], first, axis=0)
            self.levels.append((F, I, power))
            flux = np.zeros(len(lo))
            flux[full] = np.add.reduceat(flux_t, first)
            fluxes.append(flux)
            extra.append(G)
        self.state = _cut(self.levels, extra, fluxes, count)
        # the samples: one per cut node, level by level (sample_order: in tree order)
        picked = [np.flatnonzero(st == CUT) for st in self.state]
        F_c = np.concatenate([F[k] for (F, _, _), k in zip(self.levels, picked, strict=True)])
        I_c = np.concatenate([ints[k] for (_, ints, _), k in zip(self.levels, picked, strict=True)])
        P_c = np.concatenate([p[k] for (_, _, p), k in zip(self.levels, picked, strict=True)])
        G_c = np.concatenate([G[k] for G, k in zip(extra, picked, strict=True)])
        lo_c = np.concatenate([r[0][k] for r, k in zip(ranges, picked, strict=True)])
        hi_c = np.concatenate([r[1][k] for r, k in zip(ranges, picked, strict=True)])
        rep = I_c[:, NODE_INTS["rep"]]
        mean_n = G_c[:, _G["mean_normal"]]
        length = np.linalg.norm(mean_n, axis=1)
        unit = np.where((length > 0)[:, None], mean_n / np.maximum(length, 1e-300)[:, None], normal[rep])
        area_c = G_c[:, _G["area"]]
        cov = G_c[:, _G["normal_moment"]] - mean_n[:, _PAIRS[0]] * mean_n[:, _PAIRS[1]]
        self.samples = EmitterSamples(
            centroid[rep],
            normal[rep],  # the shadow ray's target steps off the central triangle along its own normal
            area_c,
            # the radiance whose light along the mean normal is the node's power vector's
            np.einsum("kcj,kj->kc", P_c, unit) / np.maximum(area_c * length, 1e-300)[:, None],
            corners=c,
            triangle_radiance=self.radiance,
            pick=rep,
            axis=unit,
            normal_length=length,
            normal_cov=cov,
            centre=F_c[:, NODE_FLOATS["centroid"]],
            moment=F_c[:, NODE_FLOATS["moment"]],
        )
        # each triangle's reach: its size + CUT_REACH x its cut node's radius
        radius_t = np.zeros(n)
        radius_t[ranges_flat(lo_c, hi_c - lo_c)] = np.repeat(F_c[:, NODE_FLOATS["radius"]], hi_c - lo_c)
        reach = size + CUT_REACH * radius_t
        at = np.sort(lo_c)  # each sample's place in tree order: its node's first triangle
        self.sample_order = np.argsort(lo_c, kind="stable")
        for (F, I, _), (lo, hi), st in zip(self.levels, ranges, self.state, strict=True):  # noqa: E741
            full = np.flatnonzero(hi > lo)
            F[full, NODE_FLOATS["reach_min"]] = np.minimum.reduceat(reach, lo[full])
            F[full, NODE_FLOATS["reach_max"]] = np.maximum.reduceat(reach, lo[full])
            I[:, 2], I[:, 3] = np.searchsorted(at, lo), np.searchsorted(at, hi)
            I[st == BELOW, 3] = I[st == BELOW, 2]  # under the cut a node has no samples of its own
        # per level, the columns the near walk's reach test reads (centroid, spread, radius, reaches)
        self.reach_columns = [np.ascontiguousarray(F[:, :REACH_COLUMNS]) for F, _, _ in self.levels]


ABOVE, CUT, BELOW = 0, 1, 2  # a node's place against the cut (LightTree.state)


def _cut(levels, extra, fluxes, count: int) -> list[np.ndarray]:
    """Each level's nodes' place against the cut of about `count` nodes: the nodes of flux at most
    tau and normals within acos(cone) of their axis whose parent is neither, or single triangles
    above them; tau the largest that leaves at least `count` nodes (or the fewest there can be),
    cone the first of CUT_CONES that leaves at most CUT_MOST x count (a sphere's cut has its
    normals within 26 degrees: 60 samples, whatever was asked)."""

    def states(tau: float, cone: float) -> list[np.ndarray]:
        out, parent = [], None
        for (_, I, _), G, flux in zip(levels, extra, fluxes, strict=True):  # noqa: E741
            count_l = I[:, NODE_INTS["count"]]
            free = np.ones(len(flux), bool) if parent is None else parent[np.arange(len(flux)) // 2] == ABOVE
            small = (flux <= tau) & (G[:, _G["cone"]] >= cone)
            cut = free & (count_l > 0) & (small | (count_l == 1))
            st = np.where(free & (count_l > 0), np.where(cut, CUT, ABOVE), BELOW)
            out.append(st)
            parent = st
        return out

    def size(st) -> int:
        return sum(int(np.sum(s == CUT)) for s in st)

    candidates = np.unique(np.concatenate(fluxes))
    for cone in CUT_CONES:
        fewest = states(candidates[-1], cone)
        if size(fewest) <= CUT_MOST * count:
            break
    if size(fewest) >= count:
        return fewest
    lo, hi = 0, len(candidates) - 1  # the cut shrinks as tau grows
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if size(states(candidates[mid], cone)) >= count:
            lo = mid
        else:
            hi = mid
    return states(candidates[lo], cone)


# columns of a LightTree level's floats and ints
NODE_FLOATS = {"centroid": slice(0, 3), "spread": 3, "radius": 4, "reach_min": 5, "reach_max": 6}
_G = {"cone": 0, "area": 1, "mean_normal": slice(2, 5), "normal_moment": slice(5, 11)}  # the cut's

REACH_COLUMNS = 7  # the first NODE_FLOATS columns: what a node's reach is tested on
NODE_FLOATS |= {"box_mid": slice(7, 10), "box_half": slice(10, 13), "axis": slice(13, 16), "one_side": 16}
NODE_FLOATS["moment"] = slice(17, 23)
NODE_INTS = {"count": 0, "rep": 1, "s_lo": 2, "s_hi": 3}

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
