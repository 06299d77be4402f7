"""Direct light at arbitrary surface points: lamps, small emitters and the sky, with shadow rays.

The solver's first shot projects direct light onto the patches, which blurs it to their size:
a shadow edge or the fast fall-off under a lamp cannot be sharper than a patch. A bake point
(vertex, texel) instead gets its direct light computed where it is, and only the indirect part,
which varies slowly, comes from the patches (pipeline.radiance_at). This is the same split as
"direct + indirect from a radiosity mesh" in classical light baking.

Emitters are integrated with one fixed rule of points on their triangles (emitter_samples),
the same for every receiver point, so that baked light has no noise. Emission shaders emit
from both sides of a face (as in Cycles), so both sides count.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from .geometry import ranges_flat, subtriangle_centroids
from .lights import Lamp, lamp_irradiance, shadow_origin
from .sky import Sky, sky_irradiance
from .surfaces import Surfaces, triangle_geometry

_CHUNK_RAYS = 1 << 20


@dataclass(frozen=True)
class DirectLight:
    """The light shot straight to bake points: lamps, the emitting triangles sampled with shadow
    rays (emitters (T,) bool over surfaces.triangles), their emission scale, samples per point;
    gather_rays: final-gather rays per bake point for the indirect light (gather.py), 0 = off;
    near_field: hits closer than a patch radius computed where they land (gather.NearField);
    sky: the world's light (sky.py), None = none; sky_samples: its directions (one fixed set);
    sky_patches (n,) bool: the patches where bake points and near gather hits cast sky rays, as
    the solve decided and stored them (pipeline.bake_sky); None: decide from the problem."""

    lamps: tuple[Lamp, ...] = ()
    emitters: np.ndarray | None = None
    emission_scale: float = 1.0
    samples: int = 64
    gather_rays: int = 0
    near_field: bool = False
    sky: Sky | None = None
    sky_samples: int = 1024
    sky_patches: np.ndarray | None = None
    emitter_samples: int = 0  # the emitters' samples per point when not `samples` (0: samples)
    area_jittered: bool = False  # area lamps: each stratum jittered per point (lights.jittered_area_samples)


def triangle_normals(surfaces: Surfaces, triangles: np.ndarray) -> np.ndarray:
    """Unit geometric normals (m, 3) of triangles (zero for degenerate ones)."""
    return triangle_geometry(surfaces.corners[np.asarray(triangles, np.int64)])[1]


@dataclass(frozen=True)
class EmitterSamples:
    """A fixed quadrature of the emitting surfaces: points (k, 3), unit normals (k, 3), the area
    each point stands for (k,), and its emitted radiance (k, 3)."""

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
    picked by systematic sampling on their power, each point standing for an equal power.
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
        return EmitterSamples(
            pts,
            normal[pick],
            area[pick] * (total / count) / power[pick],
            radiance[pick],
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


NEAR_EMITTER = 2.0  # a point closer to an emitting triangle's samples than this x their spacing
# gets that triangle's light from its exact form factor (polygon_irradiance), not from the samples
NEAR_EXACT = 4.0  # ... or, picked samples (_near_picked), a node of the light tree as one point this x its
# radius away


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


def emitter_irradiance(
    surfaces: Surfaces,
    rays,
    emitters: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    samples: int = 64,
    scale: float = 1.0,
) -> tuple[np.ndarray, int]:
    """Irradiance (m, 3) at points with unit normals (m, 3) from the emitting triangles `emitters`
    ((T,) bool), over a fixed rule of about `samples` emitter points with a shadow ray each; and
    the number of rays cast. Deterministic."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    H = np.zeros((len(pts), 3))
    src, near = _emitter_rule(surfaces, emitters, samples, scale)
    k = len(src.area)
    if len(pts) == 0 or k == 0:
        return H, 0
    eps = 1e-6 * surfaces.extent
    cast = 0
    step = max(1, _CHUNK_RAYS // k)
    for r0 in range(0, len(pts), step):
        rs = np.arange(r0, min(len(pts), r0 + step))
        P, N = pts[r0 : r0 + step], nrm[r0 : r0 + step]
        v = src.points[None, :, :] - P[:, None]
        d2 = np.einsum("rsk,rsk->rs", v, v)
        d = np.sqrt(np.maximum(d2, 1e-300))
        omega = v / d[..., None]
        cos_r = np.einsum("rsk,rk->rs", omega, N)
        facing = np.einsum("rsk,sk->rs", omega, src.normals)  # its sign: which side of the emitter
        cos_s = np.abs(facing)
        pair = (cos_r > 0) & (cos_s > 0) & (d2 > 0)
        # From just off the receiver to just off the emitter on the receiver's side: a ray aimed
        # at the sample itself would meet the emitter's own face short of it at grazing angles.
        # Built on the whole (points, samples) grid by broadcasting, then taken at the pairs once.
        origin = shadow_origin(P[:, None], N[:, None], omega, eps)
        seg = src.points[None] - (eps * np.sign(facing))[..., None] * src.normals[None] - origin
        origin, seg = origin[pair], seg[pair]
        length = np.sqrt(np.einsum("ij,ij->i", seg, seg))
        blocked = rays.occluded(origin, seg / length[:, None], length * (1 - 1e-6))
        cast += len(seg)
        lit = np.zeros(pair.shape, bool)
        lit[pair] = ~blocked
        # the unblocked pairs' geometric terms as a dense (points, samples) matrix: one product sums
        # them per point (np.add.at per pair was a fifth of a production room's near-field time)
        g = np.where(lit, cos_r * cos_s / np.maximum(d2, 1e-300) * src.area[None, :], 0.0)
        H[rs] += g @ src.radiance
        if src.run_start is not None:
            _near_emitters(H, rs, P, N, src, d, g, pair, lit)
        elif near is not None:
            cast += _near_picked(H, rs, P, N, src, near, g, rays, eps)
    return H, cast


def _near_emitters(H, rs, P, N, src: EmitterSamples, d, g, pair, lit) -> None:
    """Points within NEAR_EMITTER sample spacings of an emitting triangle's samples: its sampled light
    replaced by its exact unoccluded light x the fraction of its samples they see. A fixed rule of
    points is singular there: 1 cm over a lamp quad sampled 15 cm apart it gave 0.7 W/m^2 where the
    quad sends 38, and spikes of thousands right over a sample, which projected onto the patches
    rang into negative radiosity across a whole room."""
    start, tri = src.run_start, src.run_triangle
    near = np.minimum.reduceat(d, start, axis=1) < NEAR_EMITTER * src.spacing[tri][None, :]
    if not np.any(near):
        return
    i, e = np.nonzero(near)
    sampled = np.add.reduceat(g, start, axis=1)[i, e]
    seen = np.add.reduceat(lit.astype(np.int64), start, axis=1)[i, e]
    facing = np.add.reduceat(pair.astype(np.int64), start, axis=1)[i, e]
    seen_fraction = np.where(facing > 0, seen / np.maximum(facing, 1), 0.0)
    exact = polygon_irradiance(P[i], N[i], src.corners[tri[e]])
    np.add.at(H, rs[i], (exact * seen_fraction - sampled)[:, None] * src.triangle_radiance[tri[e]])


NEAR_POINTS = 1 << 13  # points whose near emitters _near_picked finds at once (memory: their frontier)
NEAR_CONE = 0.97  # a light-tree node whose normals stray over acos(this) from its axis is never one point


_RULES: dict = {}  # (id(surfaces), id(emitters), samples, scale) -> (weakrefs of both, rule, light tree)


def _emitter_rule(surfaces: Surfaces, emitters: np.ndarray, samples: int, scale: float):
    """emitter_samples() and its _LightTree (None unless samples are picked), made once for the
    same surfaces and emitters objects: a final gather asks for them at every chunk of its near hits
    (408 times in the production room's vertex bake). Weak references: nothing is kept alive."""
    key = (id(surfaces), id(emitters), int(samples), float(scale))
    hit = _RULES.get(key)
    if hit is not None and hit[0]() is surfaces and hit[1]() is emitters:
        return hit[2], hit[3]
    src = emitter_samples(surfaces, emitters, samples, scale)
    near = _LightTree(src) if src.pick is not None and len(src.area) else None
    for old in [k for k, v in _RULES.items() if v[0]() is None or v[1]() is None]:
        _RULES.pop(old, None)
    try:
        _RULES[key] = (weakref.ref(surfaces), weakref.ref(emitters), src, near)
    except TypeError:  # an object without weak references: not cached
        pass
    return src, near


def picked(surfaces: Surfaces, emitters: np.ndarray, samples: int, scale: float = 1.0) -> bool:
    """Whether `samples` emitter samples are picked on the power of more emitting triangles than
    samples (the light tree then takes the near field of every point within NEAR_EMITTER of their
    spacings: fewer samples spread them wider and widen that near field)."""
    return _emitter_rule(surfaces, emitters, samples, scale)[0].pick is not None


def _first_max_in_runs(values: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Index of the first largest value in each run of `values`, runs starting at `first` (sorted,
    first[0] = 0) and tiling the array."""
    seg = np.repeat(np.arange(len(first)), np.diff(np.r_[first, len(values)]))
    hit = np.flatnonzero(values == np.maximum.reduceat(values, first)[seg])
    return hit[np.r_[True, seg[hit][1:] != seg[hit][:-1]]]


class _LightTree:
    """The emitting triangles of picked samples as a binary tree (a light hierarchy), for
    _near_picked. Level l has 2^l nodes, each a range [lo, hi) of the triangles in tree order; node
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


# columns of a _LightTree level's floats and ints
_F = {"centroid": slice(0, 3), "spread": 3, "radius": 4, "reach_min": 5, "reach_max": 6}
_F |= {"box_mid": slice(7, 10), "box_half": slice(10, 13), "axis": slice(13, 16), "one_side": 16}
_F["moment"] = slice(17, 23)
_I = {"count": 0, "rep": 1, "s_lo": 2, "s_hi": 3}
_PAIRS = (np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2]))  # a symmetric 3 x 3's six entries


def _second_order(moment: np.ndarray, u: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
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


def _near_picked(H, rs, P, N, src: EmitterSamples, tree: _LightTree, g, rays, eps: float) -> int:
    """_near_emitters for samples picked on the power of more triangles than samples (a subdivided
    panel, an emissive mesh): the emitting triangles within NEAR_EMITTER sample spacings of a point
    give their own light in place of what the samples picked on them gave. Walking the light tree,
    a node of them farther than NEAR_EXACT x its radius, wholly above the point's horizon and flat
    enough that the point sees all its faces from one side, gives its light as one point (its power
    vector, corrected to second order for its extent: _second_order); a node wholly under the
    horizon gives none; a single triangle nearer than that, its exact unoccluded light (Lambert's
    contour);
    each x whether the point sees the node's central triangle's centroid (one shadow ray). Points
    go in blocks of NEAR_POINTS. Returns the rays cast."""
    cast = 0
    for b0 in range(0, len(P), NEAR_POINTS):
        block = np.arange(b0, min(len(P), b0 + NEAR_POINTS))
        cast += _near_block(H, rs, P, N, src, tree, g, rays, eps, block)
    return cast


def _near_block(H, rs, P, N, src: EmitterSamples, tree: _LightTree, g, rays, eps, block) -> int:
    """_near_picked for the points `block`: the tree walked a level at a time for all of them at once
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
                fix = _second_order(f[p, _F["moment"]], v[p], Ni[p], axis)
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
    seen = np.ones(len(i), bool)  # a centroid under the point's horizon: the clipped part is seen
    cast = int(ask.sum())
    if cast:
        normal = tree.normal_t[rep[ask]]
        facing = np.einsum("ij,ij->i", omega[ask], normal)
        origin = shadow_origin(P[i][ask], N[i][ask], omega[ask], eps)
        seg = target[ask] - (eps * np.sign(facing))[:, None] * normal - origin
        length = np.linalg.norm(seg, axis=1)
        seen[ask] = ~rays.occluded(origin, seg / np.maximum(length, 1e-300)[:, None], length * (1 - 1e-6))
    np.add.at(H, rs[i], E * seen[:, None])
    # less what the samples picked on those triangles gave (a node's samples are one run)
    many = s_hi - s_lo
    if many.sum():
        row = np.repeat(i, many)
        sample = tree.sample_order[ranges_flat(s_lo, many)]
        np.add.at(H, rs[row], -g[row, sample][:, None] * src.radiance[sample])
    return cast


def direct_irradiance(
    surfaces: Surfaces,
    rays,
    light: DirectLight,
    points: np.ndarray,
    normals: np.ndarray,
    sky_at: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Direct irradiance (m, 3) in W/m^2 at points with unit normals: lamps, the sampled
    emitters and the sky of `light`; and the rays cast. sky_at (m,) bool: the points that may see
    the sky (the others get none of it, and cast no sky rays); None: all."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    H = np.zeros((len(pts), 3))
    cast = 0
    if light.lamps:
        for c0 in range(0, len(pts), _CHUNK_RAYS):
            sl = slice(c0, c0 + _CHUNK_RAYS)
            h, n = lamp_irradiance(
                light.lamps, pts[sl], nrm[sl], rays, surfaces.extent, light.samples, light.area_jittered
            )
            H[sl] += h
            cast += n
    if light.emitters is not None and np.any(light.emitters):
        samples = light.emitter_samples or light.samples
        h, n = emitter_irradiance(surfaces, rays, light.emitters, pts, nrm, samples, light.emission_scale)
        H += h
        cast += n
    if light.sky is not None and light.sky.emits:
        at = np.arange(len(pts)) if sky_at is None else np.flatnonzero(sky_at)
        h, n = sky_irradiance(light.sky, rays, pts[at], nrm[at], surfaces.extent, light.sky_samples)
        H[at] += h
        cast += n
    return H, cast
