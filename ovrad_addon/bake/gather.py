"""Final gather at bake points: the indirect irradiance arriving at a point, from hemisphere rays
that look the solved radiosity up where they land.

A bake point M reconstructs its indirect light from the patches covering it (sum_i alpha_i(M)
(B_i - B^d_i)): that light is blurred to the patches' size, leaks under objects resting on a floor
(a patch reaching under a block keeps the light of its visible part) and is too dark next to them.
Gathering instead casts N cosine-distributed rays from M; with cosine-weighted directions the
irradiance is pi x the mean incoming radiance, and a hit point N sends L = B(N) / pi towards M, so

    E_ind(M) = mean over the rays of B_reflected(hit),  B_reflected = sum_k alpha_k(hit) (B_k - E_k)

with alpha at the hit on the side the ray arrives at (the transport's machinery, atlas/lookup.py). E_k
is the emission that M computes for itself as direct light (the emitters its shadow rays sample):
an emitter sends back only what it reflects. The hit's reflected radiosity is taken whole, direct
light included: the sun patch on the floor lights the wall as indirect light. Rays that escape, or
land on a side without patches (the inside of a closed block), bring nothing.

Near hits are looked up again. A ray that lands closer than a patch radius (a point on a concave
edge or at an object's foot sends half its rays into the neighbouring face at distance ~0) would
read the patches' radiosity there, which is their mean over their support: blurred across a contact
shadow or a shadow edge, too bright in a corner. Those hits get their direct light computed where
they are, by shadow rays with the bake points' fixed rules, and the rest (the light that came by
way of other surfaces) from a second gather of a few rays (SolveSettings.near_gather_rays, 16) at
the nodes of a lattice over the hit's triangle, interpolated: the patches' indirect light is their
mean over their support, too bright in a corner where walls meet (doorway room, every vertex: +2.8
% at the vertices on the room's edges, +12.5 % in its corners with the patches' indirect light;
+1.4 / +7.7 % with the second gather). Everything there is a fixed rule, and the nodes are shared
by every hit on their triangle, so neighbouring bake points agree: no noise. (A second gather at
each near hit itself instead measured 1.54 % against 1.65 % on the Cornell box, at twice the bake
time, and made neighbouring vertices of a textured floor disagree by up to 7 %.)

Noise-free and repeatable: every point uses the same stratified pattern of directions (a fixed
scrambled Sobol' net), turned into the point's tangent frame. Points of one flat face share
a frame, so they cast parallel rays: the result is as smooth as the radiosity it looks up.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from ..geometry import tangent_frame
from ..light.direct import direct_irradiance
from ..overlap.queries import ray_hits
from ..parallel import WORKERS, threaded
from ..settings import MAX_GATHER_RAYS
from .lattice import CORNER_ALPHA, CornerCache, NearField, inside, pattern_rays

GATHER_SEED = 3  # the fixed scrambling of the pattern: any seed, but always the same
SECOND_SEED = 5  # the second gather's (NearField.second_rays), other directions than the first's


def strata(count: int) -> tuple[int, int]:
    """A full na x nb grid of strata with na nb = count, na the largest divisor <= sqrt(count)."""
    na = max(d for d in range(1, int(np.sqrt(count)) + 1) if count % d == 0)
    return na, count // na


def hemisphere_pattern(count: int, seed: int = GATHER_SEED) -> np.ndarray:
    """(count, 3) cosine-distributed unit directions in a local frame (z = the normal), from the
    first `count` points of a scrambled Sobol' sequence (fixed seed) mapped by Malley's method.

    With count a power of two they form a (0, m, 2)-net: every na x nb grid of strata of the unit
    square with na nb = count holds exactly one point, so they are at least as well stratified as a
    jittered grid, and finer in every other aspect ratio too. Measured on the form factor from floor
    points to a block's face (400 points): 11 / 5.1 / 3.4 % relative RMS error with 64 / 128 / 256
    directions, where a jittered 8 x 8 ... 16 x 16 grid gives 13 / 8.9 / 6.8 %.
    """
    with warnings.catch_warnings():  # counts other than powers of two lose the net property only
        warnings.simplefilter("ignore")
        u = qmc.Sobol(2, scramble=True, seed=seed).random(count)
    r = np.sqrt(u[:, 0])
    phi = 2.0 * np.pi * u[:, 1]
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(1.0 - u[:, 0], 0.0))])


# Shadow-ray samples of soft lamps and emitters at a near hit. With 16, the near hits' direct light
# (24 M hits, their shadow rays and the numpy around them) is about 45 % of the production room's
# vertex bake (py-spy); with 8 (a quad emitter: 8 points against 18) the bake takes 106.7 s against
# 139.5 s, its error 6.857 % against 6.849 % at every vertex, and the ten real scenes' errors agree
# in the third digit (benchmarks/real_scenes_bench.py): a near hit's light is averaged over
# hundreds of gather rays, where a coarser rule's steps in a penumbra even out.
NEAR_LIGHT_SAMPLES = 8

# ... but emitters of this many triangles or more, whose samples are picked on power and whose
# light tree takes each point's near field (light.near.near_picked), keep this many: 8 picks stand
# farther apart and widen every near hit's near field (the large interior's 20 000-point bake at
# 4 777 patches: 74 s at 8, 42 s at 16, 42 s at 32; 8 is 0.47 % RMS off 16 and 32, which agree)
NEAR_PICKED_SAMPLES = 16

NEAR_SKY_SAMPLES = 256  # world directions at a near hit


@dataclass(frozen=True)
class Gather:
    """What a final gather reads where its rays land, and how it casts them.

    radiosity (n, 3): the solved B; emission (n, 3): the per-patch exitance not to count at the
    hits (what the points get as direct light: sampled_emission; zeros to count every emitter).
    rays: directions per point (best a power of two, see hemisphere_pattern()). near: evaluate
    hits closer than a patch radius where they are (see NearField), else from the patches like the
    others. corner_alpha: hits read the patches' values from a lattice over their triangle at most
    this x the smallest patch radius fine (CornerCache; 0: alpha at every hit). corner_cache: a dict
    the caller that owns one bake keeps across its calls (the same problem, radiosity, emission and
    near field: the bake's receivers and chunks): they share one CornerCache per ray count and
    corner_alpha, whose nodes are then filled once for all of them (a floor's lattice under many
    objects) and built once. Points go in chunks of about chunk_rays rays on `workers` threads;
    progress(fraction) is called on the calling thread after each. seed: the pattern's scrambling
    (hemisphere_pattern); gathers with other seeds cast other directions.
    """

    radiosity: np.ndarray
    emission: np.ndarray
    rays: int
    near: NearField | None = None
    corner_alpha: float = CORNER_ALPHA
    corner_cache: dict | None = None
    chunk_rays: int = 1 << 17
    workers: int = WORKERS
    progress: Callable[[float], None] | None = None
    seed: int = GATHER_SEED


def gather_indirect(problem, gather: Gather, points, normals, triangles=None, spread=None) -> np.ndarray:
    """Indirect irradiance (m, 3) in W/m^2 at points (m, 3) with unit normals (m, 3), gathered as
    `gather` says.

    triangles (m,): the triangle each point lies on; rays then start a hair inside it (inside()),
    which a point on a concave edge needs (a wall's foot: else the rays aimed into the wall start
    behind it and see nothing).
    spread (m, k, 3): the weighted normals N_j each point gathers for (shared_normals; the normals
    must be their gather_axis): a ray in direction d then counts sum_j max(0, N_j . d) / (n . d)
    times what it brings, so the gather estimates the weighted mean of the irradiances about each
    N_j; the light from below n's horizon but above an N_j's, which no ray samples, is taken as the
    light of the lowest rays (those under 20 degrees of elevation, at least one; exact under an even
    sky and for light from above every horizon).
    """
    rays, near, corner_alpha = gather.rays, gather.near, gather.corner_alpha
    corner_cache = gather.corner_cache
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    m = len(pts)
    out = np.zeros((m, 3))
    if m == 0 or rays <= 0:
        return out
    if rays > MAX_GATHER_RAYS:
        raise ValueError(f"at most {MAX_GATHER_RAYS} gather rays per point, got {rays}")
    atlas, index = problem.atlas, problem.index
    if spread is not None:
        spread = np.asarray(spread, np.float64).reshape(m, np.shape(spread)[-2], 3)
    if triangles is not None:
        pts = inside(index.surfaces, pts, triangles)
    values = np.asarray(gather.radiosity, np.float64) - np.asarray(gather.emission, np.float64)
    local = hemisphere_pattern(rays, gather.seed)
    # the rays that tell the light seen low (a spread's missed part): a cosine pattern puts
    # sin^2 of its rays under an elevation; at least the lowest one
    lowest = np.argsort(local[:, 2], kind="stable")[: max(1, int(round(rays * HORIZON**2)))]
    t_all, b_all = tangent_frame(nrm)
    eps = 1e-6 * index.surfaces.extent
    _ = atlas.grid  # build the lookup once, before the threads need it
    step = max(1, gather.chunk_rays // rays)
    starts = list(range(0, m, step))
    key = (rays, corner_alpha)
    cache = None if corner_cache is None else corner_cache.get(key)
    if cache is not None and cache.problem is not problem:
        raise ValueError("a corner cache serves one bake of one problem: give each bake its own")
    if cache is None:
        second = None
        if near is not None and near.second_rays > 0:
            second = hemisphere_pattern(near.second_rays, SECOND_SEED)
        cache = CornerCache(problem, values, near, corner_alpha, rays, second)
        if corner_cache is not None:
            corner_cache[key] = cache

    def chunk(k: int):
        sl = slice(starts[k], min(m, starts[k] + step))
        origins, dirs = pattern_rays(pts[sl], nrm[sl], local, eps, (t_all[sl], b_all[sl]))
        hits = ray_hits(index, origins, dirs)
        hit, t, at, tri, side = hits.ray, hits.t, hits.points, hits.triangle, hits.side
        got = np.zeros((len(dirs), 3))
        v = cache.values_at(at, tri, side, t)
        got[hit] = v.far
        if near is not None:
            # weight 1 below half the reach, 0 beyond 1.5 reaches, linear between: a bake point moving
            # away from a wall sees its rays change over from one estimate to the other smoothly
            reach = near.reach * v.radius
            w = np.clip(1.5 - t / np.maximum(reach, 1e-300), 0.0, 1.0) * (reach > 0)
            close = np.flatnonzero(w > 0)
            if len(close):
                sky = None if v.sky is None else v.sky[close]
                there = _near_values(
                    problem,
                    near,
                    cache,
                    np.take(at, close, axis=0),
                    tri[close],
                    side[close],
                    t[close],
                    sky,
                    v.radius[close] > 0,
                )
                there += v.near[close]
                got[hit[close]] += w[close, None] * (there - got[hit[close]])
        got = got.reshape(-1, rays, 3)
        if spread is None or spread.shape[1] == 1:
            return sl, got.mean(axis=1)
        sp = spread[sl]
        several = np.flatnonzero(np.any(sp[:, 1:] != 0.0, axis=(1, 2)))
        if len(several) == 0:
            return sl, got.mean(axis=1)
        g = got[several]
        # the light from between the axis's horizon and a normal's, which no ray samples: for a
        # normal N_j at angle a_j from the axis it is (1 - cos a_j) / 2 of light arriving evenly from
        # there, so sum_j |N_j| (1 - cos a_j) / 2 = (1 - |sum_j N_j|) / 2 of the light seen low
        low = g[:, lowest, :].mean(axis=1)
        missed = 0.5 * (1.0 - np.linalg.norm(sp[several].sum(axis=1), axis=1))
        d = dirs.reshape(-1, rays, 3)[several]
        cos = np.maximum(np.einsum("prj,pkj->prk", d, sp[several]), 0.0).sum(axis=2)
        out = got.mean(axis=1)
        out[several] = (g * (cos / local[None, :, 2])[..., None]).mean(axis=1) + missed[:, None] * low
        return sl, out

    for sl, e in threaded(chunk, len(starts), gather.workers):
        out[sl] = e
        if gather.progress is not None:
            gather.progress(sl.stop / m)
    return out


def _near_values(problem, near: NearField, cache, points, triangles, sides, t, sky, covered) -> np.ndarray:
    """rho H (k, 3) at near hits (at distances t (k,)): H_direct computed where they land (sky (k,)
    bool: may they see the sky; None: all), or from their triangle's corners where it is small
    against the distance (CornerCache); with a second gather (NearField.second_rays), plus its
    irradiance where patches cover the hit (covered (k,) bool). The caller adds HitValues.near (the
    patches' indirect light without a second gather, their unsampled emission)."""
    index = problem.index
    surfaces = index.surfaces
    pts = inside(surfaces, points, triangles)
    rho = surfaces.reflectance_at(triangles, pts)
    dark = ~np.any(rho > 0, axis=1)  # reflects nothing (an Emission shader, a metal): no light asked
    H = np.zeros((len(pts), 3))
    small = (cache.size[triangles] <= cache.light_size * t) & ~dark
    if np.any(small):
        H[small] = cache.light_at(points[small], triangles[small], sides[small])
    exact = np.flatnonzero(~small & ~dark)
    if len(exact):
        tri = triangles[exact]
        normals = np.take(index.charts.normals, tri, axis=0) * sides[exact, None]
        sky_at = None if sky is None else sky[exact]  # unused when the lattice holds the sky
        at = np.take(pts, exact, axis=0)
        light = cache.hit_light  # without the sky when the lattice holds it
        H[exact] = direct_irradiance(problem.emitter_rules, index.rays, light, at, normals, sky_at)[0]
    if cache.second_nodes is not None:
        some = np.flatnonzero(~dark)
        indirect, sky_light = cache.second_at(points[some], triangles[some], sides[some])
        H[some] += indirect * covered[some, None]
        if cache.sky_nodes and len(exact):
            # the sky's light at the exact hits from the lattice (the small ones have it from corners)
            lit = exact if sky is None else exact[sky[exact]]
            H[lit] += sky_light[np.searchsorted(some, lit)]
    return rho * H


def unique_points(points, normals, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices of one representative per distinct (position, normal) and the inverse map (m,):
    positions equal within about `tolerance` (a length) and normals within about 1e-6 are one.
    A vertex bake gathers once per vertex and face normal, not once per triangle corner."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    key = np.column_stack([np.round(p / max(tolerance, 1e-300)), np.round(n * 1e6)]).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return first, inverse.ravel()


# Corners of one vertex whose face normals all lie within this angle of their mean share one
# gather (shared_normals): a vertex of a flat-shaded curved mesh otherwise gathers once per face
# around it.
SHARE_ANGLE = np.radians(20.0)

SHARE_MOST = 16  # distinct normals per shared gather at most (more: one gather per face)

HORIZON = np.sin(np.radians(20.0))  # rays under this elevation (its sine) tell the light seen low


def shared_normals(
    groups, normals, weights, max_angle: float = SHARE_ANGLE, most: int = SHARE_MOST
) -> np.ndarray:
    """(m, k, 3) the normals each of m points gathers for, scaled by their share (summing to 1):
    its group's distinct unit normals weighted by `weights` where every one is within max_angle of
    their mean and there are at most `most` of them, else its own normal alone (k = 1 when none
    shares; zero rows pad).

    groups (m,) int: points that may share (a vertex's corners on one side; -1: never); weights (m,)
    >= 0 (a corner's angle). A gather for such a set casts about the set's mean and weights each ray
    so that it estimates the weighted mean of the irradiances about each normal (gather_indirect):
    at a vertex of a smooth mesh one gather stands for the faces around it; at a crease (a box's edge)
    the normals are apart and each face keeps its own gather.
    """
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    m = len(nrm)
    g = np.asarray(groups, np.int64)
    w_all = np.asarray(weights, np.float64)
    share = np.flatnonzero(g >= 0)
    if len(share) == 0:
        return nrm[:, None, :].copy()
    # the distinct normals of each group (a quad's two triangles, a fan's repeats), weights summed
    key = np.column_stack([g[share], np.round(nrm[share] * 1e9).astype(np.int64)])
    _, first, u = np.unique(key, axis=0, return_index=True, return_inverse=True)
    u = u.ravel()
    n_u = nrm[share[first]]
    w_u = np.bincount(u, weights=w_all[share])
    _, k = np.unique(g[share[first]], return_inverse=True)  # the group of each distinct normal
    k = k.ravel()
    count = np.bincount(k)
    weight = np.bincount(k, weights=w_u)
    total = np.stack([np.bincount(k, weights=w_u * n_u[:, j]) for j in range(3)], axis=1)
    length = np.linalg.norm(total, axis=1)
    worst = np.full(len(total), np.inf)
    np.minimum.at(worst, k, np.einsum("ij,ij->i", n_u, total[k]) / np.maximum(length[k], 1e-300))
    ok = (worst >= np.cos(max_angle)) & (count > 1) & (count <= most) & (weight > 0) & (length > 0)
    out = np.zeros((m, int(count[ok].max()) if np.any(ok) else 1, 3))
    out[:, 0] = nrm
    # each shared group's distinct normals, in slots 0 .. count - 1 of every member's row
    keep = np.flatnonzero(ok[k])
    order = keep[np.argsort(k[keep], kind="stable")]
    kk = k[order]
    slot = np.arange(len(kk)) - np.searchsorted(kk, kk)
    rows = np.zeros((len(count), out.shape[1], 3))
    rows[kk, slot] = n_u[order] * (w_u[order] / weight[kk])[:, None]
    group = k[u]  # each sharing point's group
    sharing = ok[group]
    out[share[sharing]] = rows[group[sharing]]
    return out


def gather_axis(spread: np.ndarray) -> np.ndarray:
    """(m, 3) the unit normal a gather for the weighted normals `spread` (m, k, 3) casts about."""
    total = np.asarray(spread, np.float64).sum(axis=1)
    return total / np.maximum(np.linalg.norm(total, axis=1, keepdims=True), 1e-300)


def gather_unique(problem, gather: Gather, points, normals, triangles=None, spread=None) -> np.ndarray:
    """gather_indirect once per distinct (position, normal) (within 1e-7 of the scene extent),
    scattered back to every point: repeated points cost one gather (from the first one's
    triangle; spread: the first one's, see gather_indirect)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    first, inverse = unique_points(pts, nrm, 1e-7 * problem.index.surfaces.extent)
    tri = None if triangles is None else np.broadcast_to(np.asarray(triangles, np.int64), (len(pts),))[first]
    pts, nrm = pts[first], nrm[first]
    if spread is not None:
        spread = np.asarray(spread, np.float64)
        spread = spread.reshape(len(inverse), spread.shape[-2], 3)[first]
    return gather_indirect(problem, gather, pts, nrm, tri, spread)[inverse]
