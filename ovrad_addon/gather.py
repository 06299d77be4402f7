"""Final gather at bake points: the indirect irradiance arriving at a point, from hemisphere rays
that look the solved radiosity up where they land.

A bake point M reconstructs its indirect light from the patches covering it (sum_i alpha_i(M)
(B_i - B^d_i)): that light is blurred to the patches' size, leaks under objects resting on a floor
(a patch reaching under a block keeps the light of its visible part) and is too dark next to them.
Gathering instead casts N cosine-distributed rays from M; with cosine-weighted directions the
irradiance is pi x the mean incoming radiance, and a hit point N sends L = B(N) / pi towards M, so

    E_ind(M) = mean over the rays of B_reflected(hit),  B_reflected = sum_k alpha_k(hit) (B_k - E_k)

with alpha at the hit on the side the ray arrives at (the transport's machinery, lookup.py). E_k
is the emission that M computes for itself as direct light (the emitters its shadow rays sample):
an emitter sends back only what it reflects. The hit's reflected radiosity is taken whole, direct
light included: the sun patch on the floor lights the wall as indirect light. Rays that escape, or
land on a side without patches (the inside of a closed block), bring nothing.

Near hits are looked up again. A ray that lands closer than a patch radius (a point on a concave
edge or at an object's foot sends half its rays into the neighbouring face at distance ~0) would
read the patches' radiosity there, which is their mean over their support: blurred across a contact
shadow or a shadow edge, too bright in a corner. Those hits get their direct light computed where
they are, by shadow rays with the bake points' fixed rules, and only the rest (the light that came
by way of other surfaces, which varies slowly) from the patches (NearField). Everything there is a
fixed rule, so neighbouring bake points agree: no noise. (A second gather at each near hit instead
of the patches' indirect light measured 1.54 % against 1.65 % on the Cornell box, at twice the bake
time, and made neighbouring vertices of a textured floor disagree by up to 7 %.)

Noise-free and repeatable: every point uses the same stratified pattern of directions (a fixed
scrambled Sobol' net), turned into the point's tangent frame. Points of one flat face share
a frame, so they cast parallel rays: the result is as smooth as the radiosity it looks up.
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.stats import qmc

from .direct import DirectLight, direct_irradiance
from .geometry import tangent_frame
from .lights import shadow_origin
from .overlap import alpha_at, patch_average, ray_hits
from .parallel import WORKERS, threaded

GATHER_SEED = 3  # the fixed scrambling of the pattern: any seed, but always the same
MAX_RAYS = 1 << 14
INSIDE = 2e-5  # origins step this far (x scene extent) into their triangle, at most halfway to its centroid


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


# Shadow-ray samples of soft lamps and emitters at a near hit. At 16, the near hits' direct light
# (24 M hits, their shadow rays and the numpy around them) was about 45 % of the production room's
# vertex bake (py-spy); at 8 (a quad emitter: 8 points instead of 18) the bake took
# 106.7 s against 139.5 s, its error 6.857 % against 6.849 % at every vertex, and the ten real
# scenes' errors did not move in the third digit (real_scenes_bench.py): a near hit's light is
# averaged over hundreds of gather rays, where a coarser rule's steps in a penumbra even out.
NEAR_LIGHT_SAMPLES = 8
# ... but emitters of this many triangles or more, whose samples are picked on power and whose
# light tree takes each point's near field (direct._near_picked), keep this many: 8 picks stand
# farther apart and widen every near hit's near field (the large interior's 20 000-point bake at
# 4 777 patches: 74 s at 8, 42 s at 16, 42 s at 32; 8 is 0.47 % RMS off 16 and 32, which agree)
NEAR_PICKED_SAMPLES = 16
NEAR_SKY_SAMPLES = 256  # world directions at a near hit
CORNER_ALPHA = 0.25  # hits read the patches from a lattice this x the smallest radius fine (CornerCache)


@dataclass(frozen=True)
class NearField:
    """How hits closer than `reach` x the local patch radius are evaluated: the direct light of
    `light` computed at the hit, plus from the patches (n, 3 each) `indirect` (the solved radiosity
    less its first shot and emission: the light that came by way of other surfaces) and `extra` (the
    emission the far hits count too: emitters the bake points do not sample as direct light).
    sky_seen (n,) bool: the patches whose near hits cast sky rays (pipeline.sky_patches); None:
    every one, if the light has a sky. corner_size: a hit on a triangle whose longest edge is at
    most this x the hit's distance (with 256 gather rays; x sqrt(256 / rays) with others) takes its
    direct light from the triangle's corners (CornerCache); 0: every near hit casts shadow rays."""

    light: DirectLight
    indirect: np.ndarray
    extra: np.ndarray
    reach: float = 1.0
    sky_seen: np.ndarray | None = None
    corner_size: float = 0.25


def sampled_emission(atlas, index, emitters: np.ndarray | None, scale: float = 1.0, q: int = 4) -> np.ndarray:
    """(n, 3) exitance of each patch from the emitting triangles `emitters` ((T,) bool) only: the
    emission a bake point computes as direct light, which a gather must not count again."""
    surfaces = index.surfaces
    if emitters is None or not np.any(emitters) or scale == 0:
        return np.zeros((len(atlas), 3))
    em = surfaces.emission * np.asarray(emitters, bool)[:, None]
    return np.pi * scale * patch_average(atlas, index, em, q)


def gather_indirect(
    problem,
    radiosity: np.ndarray,
    emission: np.ndarray,
    points,
    normals,
    rays: int,
    triangles=None,
    progress: Callable[[float], None] | None = None,
    chunk_rays: int = 1 << 17,
    workers: int = WORKERS,
    near: NearField | None = None,
    corner_alpha: float = CORNER_ALPHA,
    spread: np.ndarray | None = None,
    corner_cache: dict | None = None,
) -> np.ndarray:
    """Indirect irradiance (m, 3) in W/m^2 at points (m, 3) with unit normals (m, 3).

    radiosity (n, 3): the solved B; emission (n, 3): the per-patch exitance not to count at the
    hits (what the points get as direct light: sampled_emission; zeros to count every emitter).
    rays: directions per point (best a power of two, see hemisphere_pattern()). triangles (m,): the triangle
    each point lies on; rays then start a hair inside it (inside()), which a point on a concave
    edge needs (a wall's foot: else the rays aimed into the wall start behind it and see nothing).
    Points go in chunks of about
    chunk_rays rays on `workers` threads; progress(fraction) is called on the calling thread.
    near: evaluate hits closer than a patch radius where they are (see NearField), else from the
    patches like the others. corner_alpha: hits read the patches' values from a lattice over their
    triangle at most this x the smallest patch radius fine (CornerCache; 0: alpha at every hit).
    spread (m, k, 3): the weighted normals N_j each point gathers for (shared_normals; the normals
    must be their gather_axis): a ray in direction d then counts sum_j max(0, N_j . d) / (n . d)
    times what it brings, so the gather estimates the weighted mean of the irradiances about each
    N_j; the light from below n's horizon but above an N_j's, which no ray samples, is taken as the
    light of the lowest rays (those under 20 degrees of elevation, at least one; exact under an even
    sky and for light from above every horizon).
    corner_cache: a dict the caller keeps across calls with the same problem, radiosity, emission
    and near field (one bake's receivers and chunks): they share one CornerCache, whose nodes are
    then filled once for all of them (a floor's lattice under many objects) and built once.
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    m = len(pts)
    out = np.zeros((m, 3))
    if m == 0 or rays <= 0:
        return out
    if rays > MAX_RAYS:
        raise ValueError(f"at most {MAX_RAYS} gather rays per point, got {rays}")
    atlas, index = problem.atlas, problem.index
    if spread is not None:
        spread = np.asarray(spread, np.float64).reshape(m, np.shape(spread)[-2], 3)
    if triangles is not None:
        pts = inside(index.surfaces, pts, triangles)
    values = np.asarray(radiosity, np.float64) - np.asarray(emission, np.float64)
    local = hemisphere_pattern(rays)
    # the rays that tell the light seen low (a spread's missed part): a cosine pattern puts
    # sin^2 of its rays under an elevation; at least the lowest one
    lowest = np.argsort(local[:, 2], kind="stable")[: max(1, int(round(rays * HORIZON**2)))]
    t_all, b_all = tangent_frame(nrm)
    eps = 1e-6 * index.surfaces.extent
    _ = atlas.grid  # build the lookup once, before the threads need it
    step = max(1, chunk_rays // rays)
    starts = list(range(0, m, step))
    key = (id(problem), rays, corner_alpha)
    cache = None if corner_cache is None else corner_cache.get(key)
    if cache is None:
        cache = CornerCache(problem, values, near, corner_alpha, rays)
        if corner_cache is not None:
            corner_cache[key] = cache

    def chunk(k: int):
        sl = slice(starts[k], min(m, starts[k] + step))
        n = nrm[sl]
        dirs = (
            local[None, :, :1] * t_all[sl, None]
            + local[None, :, 1:2] * b_all[sl, None]
            + local[None, :, 2:] * n[:, None]
        )
        dirs = dirs.reshape(-1, 3)
        origins = shadow_origin(np.repeat(pts[sl], rays, axis=0), np.repeat(n, rays, axis=0), dirs, eps)
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
                    problem, near, cache, np.take(at, close, axis=0), tri[close], side[close], t[close], sky
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

    for sl, e in threaded(chunk, len(starts), workers):
        out[sl] = e
        if progress is not None:
            progress(sl.stop / m)
    return out


def _near_values(problem, near: NearField, cache, points, triangles, sides, t, sky) -> np.ndarray:
    """rho H_direct (k, 3) at near hits (at distances t (k,)), H computed where they land (sky (k,)
    bool: may they see the sky; None: all), or from their triangle's corners where it is small
    against the distance (CornerCache). The caller adds the patches' indirect light (HitValues.near)."""
    index = problem.index
    surfaces = index.surfaces
    pts = inside(surfaces, points, triangles)
    H = np.empty((len(pts), 3))
    small = cache.size[triangles] <= cache.light_size * t
    if np.any(small):
        H[small] = cache.light_at(points[small], triangles[small], sides[small])
    exact = np.flatnonzero(~small)
    if len(exact):
        tri = triangles[exact]
        normals = np.take(index.charts.normals, tri, axis=0) * sides[exact, None]
        sky_at = None if sky is None else sky[exact]
        at = np.take(pts, exact, axis=0)
        H[exact] = direct_irradiance(surfaces, index.rays, near.light, at, normals, sky_at)[0]
    return surfaces.reflectance_at(triangles, pts) * H


@dataclass(frozen=True)
class HitValues:
    """What the patches give at gather hits (k each): far (k, 3), the reflected radiosity; near
    (k, 3), their indirect light and unsampled emission (NearField); radius (k,), the local patch
    radius (alpha-weighted); sky (k,) bool, may the hit see the sky (None: all may)."""

    far: np.ndarray
    near: np.ndarray
    radius: np.ndarray
    sky: np.ndarray | None


# Hits closer than this many local patch radii to their bake point read alpha where they land when
# their triangle side is cut in more than one cell: there the lattice's linear cells smear the
# patches' steps (a contact line under a box, a visibility edge) over a large solid angle. Cornell
# box, 2 131 patches, every vertex: lattice everywhere 1.70 %, alpha at every hit 1.595 %, with
# this 1.595 % (lamps_doorway 1.94 / 1.762 / 1.762 %).
LATTICE_REACH = 1.5
MAX_DIVISIONS = 256  # a triangle side needing a finer lattice (over 33 k nodes) reads alpha at its hits


class CornerCache:
    """The gather's hits read from values kept at the nodes of a lattice over their triangle.

    Two things are computed once per lattice node (stepped a hair inside the triangle, as bake
    points are) and interpolated linearly across the lattice's cells:
    - alpha-weighted patch values (HitValues), on a lattice over each triangle side whose spacing is
      at most corner_alpha x the smallest patch radius of the side's sheet: alpha varies on the
      patches' scale, and a quarter of the smallest radius is finer than any patch resolves. A
      triangle at most that size is its own cell (its corners); a wall's large triangle at 100 k
      patches is cut in up to a few hundred rows of cells. The production room's vertex bake at
      100 k patches sends 52 M gather rays to 10.5 M nodes, of which about 3 M are ever asked
      (alpha at every hit was 40 % of that bake, py-spy). Hits closer than LATTICE_REACH patch
      radii on a side cut in several cells take alpha where they land;
    - the near field's direct light at the triangle's corners, for hits whose triangle is at most
      NearField.corner_size (0.25) x their distance at 256 rays (x sqrt(256 / rays) at other
      counts): smaller than the spacing of the gather's rays where they land (256 rays: about 0.16
      rad apart), so the gather does not resolve light inside it. (test_gather.py: on a floor in
      4.4 cm triangles beside a 4 cm shadow band, 0.25 x the distance moved the light gathered by
      4 096 rays by under 0.2 %; 0.5 x smeared the band, up to 2.7 %.)
    Other near hits (a large triangle seen close: the floor at an object's foot) cast shadow rays
    where they land; a side whose lattice would be finer than MAX_DIVISIONS takes alpha at each hit.
    Values depend only on the node, never on which thread or bake point asked first: no noise, the
    same result on any number of threads.
    """

    def __init__(
        self,
        problem,
        values: np.ndarray,
        near: NearField | None,
        corner_alpha: float = CORNER_ALPHA,
        rays: int = 256,
    ):
        self.problem, self.values, self.near = problem, values, near
        index, atlas = problem.index, problem.atlas
        c = index.surfaces.corners
        T = len(c)
        edges = np.stack([c[:, 1] - c[:, 0], c[:, 2] - c[:, 1], c[:, 0] - c[:, 2]], axis=1)
        self.size = np.sqrt(np.einsum("tej,tej->te", edges, edges).max(axis=1))
        smallest = np.full(len(index.sheet_chart) + 1, np.inf)  # last: no sheet (-1)
        np.minimum.at(smallest, atlas.sheet, atlas.radii)
        self.alpha_size = corner_alpha * smallest if corner_alpha > 0 else np.full_like(smallest, -1.0)
        tri = np.arange(T)
        divisions = np.zeros((2, T), np.int64)  # (back, triangle); 0: alpha at each hit
        if corner_alpha > 0:
            for back in (0, 1):
                h = self.alpha_size[index.sheet_of(tri, np.full(T, 1 - 2 * back))]
                n = np.ceil(self.size / h)  # a side without patches (h = inf): one cell
                divisions[back] = np.where(n <= MAX_DIVISIONS, np.maximum(n, 1), 0)
        self.frames = TriangleFrames(c)
        self.patch_nodes = LatticeValues(self.frames, divisions, 8, np.float32, self._values)
        # the spacing of the gather's rays where they land goes as 1 / sqrt(rays)
        self.light_size = 0.0 if near is None else near.corner_size * np.sqrt(256.0 / max(rays, 1))
        self.light_nodes = None
        if near is not None:
            self.light_nodes = LatticeValues(
                self.frames, np.ones((2, T), np.int64), 3, np.float64, self._light
            )

    def _values(self, tri, side, pts) -> np.ndarray:
        pts = inside(self.problem.index.surfaces, pts, tri)
        a = alpha_at(self.problem.atlas, self.problem.index, pts, tri, side)
        return _patch_values(self.problem, a, self.values, self.near)

    def _light(self, tri, side, pts) -> np.ndarray:
        problem, near = self.problem, self.near
        index = problem.index
        pts = inside(index.surfaces, pts, tri)
        normals = index.charts.normals[tri] * side[:, None]
        sky_at = None
        if near.light.sky is not None and near.sky_seen is not None:
            sky_at = may_see_sky(alpha_at(problem.atlas, index, pts, tri, side), near.sky_seen)
        return direct_irradiance(index.surfaces, index.rays, near.light, pts, normals, sky_at)[0]

    def light_at(self, points, triangles, sides) -> np.ndarray:
        """Near-field direct irradiance (k, 3) at points on triangles (k,), seen from sides (k,)."""
        return self.light_nodes.at(points, triangles, sides)

    def values_at(self, points, triangles, sides, t=None) -> HitValues:
        """HitValues at hits: from the lattice where their side has one, from alpha at the others
        and, given the hits' distances t (k,), at hits closer than LATTICE_REACH local patch radii
        on a side cut in more than one cell."""
        problem = self.problem
        n = self.patch_nodes.divisions[(np.asarray(sides) < 0).astype(np.int64), triangles]
        out = np.empty((len(points), 8))
        s = np.flatnonzero(n > 0)
        if len(s):
            out[s] = self.patch_nodes.at(np.take(points, s, axis=0), triangles[s], sides[s])
        exact = n == 0
        if t is not None:
            exact |= (n > 1) & (t < LATTICE_REACH * out[:, 6])
        e = np.flatnonzero(exact)
        if len(e):
            a = alpha_at(problem.atlas, problem.index, np.take(points, e, axis=0), triangles[e], sides[e])
            out[e] = _patch_values(problem, a, self.values, self.near)
        sky = None
        if self.near is not None and self.near.light.sky is not None and self.near.sky_seen is not None:
            sky = out[:, 7] > 0
        return HitValues(out[:, :3], out[:, 3:6], out[:, 6], sky)


class LatticeValues:
    """Values kept at the nodes of a regular lattice over each triangle side, filled when first
    asked and read by linear interpolation in the lattice cell a point falls in.

    divisions (2, T): the lattice of (front, back) side of triangle t cuts each edge in n pieces
    ((n + 1)(n + 2) / 2 nodes: i, j >= 0, i + j <= n at corner weights (n - i - j, i, j) / n);
    n = 1 is the triangle's corners; 0: none (at() must not be asked there). fill(tri, side, points)
    -> (k, width) computes values at nodes. Slots are given to a side when a point first lands on
    it (at 100 k patches the production room's lattices hold 10.5 M nodes, of which a bake asks
    about 3 M). Threads may fill the same node at once: both compute it, the first stored stays,
    and since a node's value depends on the node only, they agree.
    """

    def __init__(self, frames: TriangleFrames, divisions: np.ndarray, width: int, dtype, fill):
        self.frames = frames
        self.divisions = np.asarray(divisions, np.int64)
        self.base = np.full(self.divisions.shape, -1, np.int64)  # a side's first slot, once asked
        self.slot = np.full(1024, -1, np.int64)  # node -> row; both grown by doubling
        self.used = 0
        self.rows = np.zeros((64, width), dtype)
        self.count = 0
        self.fill = fill
        self.lock = threading.Lock()

    def at(self, points, triangles, sides) -> np.ndarray:
        """Interpolated values (k, width) at points (k, 3) on triangles (k,), seen from sides (k,) +-1.

        A point at lattice coordinates (u, v) = n x its barycentric weights of the second and third
        corners lies in the cell of node (i0, j0) = floor(u, v): the lower cell (i0, j0), (i0 + 1, j0),
        (i0, j0 + 1) when fu + fv <= 1, else the upper one, which shares the last two nodes and swaps
        the first for (i0 + 1, j0 + 1) (the last row of cells has no upper one)."""
        back = (np.asarray(sides) < 0).astype(np.int64)
        n = self.divisions[back, triangles]
        vw = self.frames.coordinates(triangles, points)
        u, v = vw[:, 0] * n, vw[:, 1] * n
        i0 = np.clip(np.floor(u), 0, n - 1).astype(np.int64)
        j0 = np.clip(np.floor(v), 0, n - 1 - i0).astype(np.int64)
        fu, fv = u - i0, v - j0
        upper = (fu + fv > 1.0) & (i0 + j0 <= n - 2)
        weight = np.empty((len(n), 3))
        weight[:, 0] = np.where(upper, fu + fv - 1.0, 1.0 - fu - fv)
        weight[:, 1] = np.where(upper, 1.0 - fv, fu)
        weight[:, 2] = np.where(upper, 1.0 - fu, fv)
        np.clip(weight, 0.0, 1.0, out=weight)
        weight /= np.maximum(weight.sum(axis=1, keepdims=True), 1e-300)
        # node (i, j) of a lattice of n: rows i' < i hold n + 1 - i' nodes each
        base = self._base(back, triangles)
        first = base + i0 * (2 * n + 3 - i0) // 2 + j0  # (i0, j0)
        node = np.empty((len(n), 3), np.int64)
        node[:, 1] = base + (i0 + 1) * (2 * n + 2 - i0) // 2 + j0  # (i0 + 1, j0)
        node[:, 2] = first + 1  # (i0, j0 + 1)
        node[:, 0] = np.where(upper, node[:, 1] + 1, first)  # (i0 + 1, j0 + 1) or (i0, j0)
        rows = self._rows(node, triangles, sides, i0, j0, upper, n)
        return np.matmul(weight[:, None, :], rows)[:, 0]

    def _base(self, back, triangles) -> np.ndarray:
        """First slot of each side's nodes (k,), given out when a side is first asked: only the
        sides hits land on hold slots (a wall's lattice at 100 k patches has thousands of nodes)."""
        base = self.base[back, triangles]
        if np.any(base < 0):
            with self.lock:
                new = np.unique(triangles[base < 0] * 2 + back[base < 0])
                t_new, b_new = new // 2, new % 2
                new = new[self.base[b_new, t_new] < 0]
                t_new, b_new = new // 2, new % 2
                n = self.divisions[b_new, t_new]
                count = (n + 1) * (n + 2) // 2
                if self.used + count.sum() > len(self.slot):
                    grown = np.full(max(2 * len(self.slot), self.used + int(count.sum())), -1, np.int64)
                    grown[: len(self.slot)] = self.slot
                    self.slot = grown
                self.base[b_new, t_new] = self.used + np.cumsum(count) - count
                self.used += int(count.sum())
            base = self.base[back, triangles]
        return base

    def _rows(self, node, triangles, sides, i0, j0, upper, n) -> np.ndarray:
        slot = self.slot[node]
        need = slot < 0
        if np.any(need):
            new, first = np.unique(node[need], return_index=True)
            k, c = np.nonzero(need)
            k, c = k[first], c[first]
            # the nodes' (i, j), in at()'s column order
            ni = i0[k] + np.where(c == 0, upper[k], c == 1)
            nj = j0[k] + np.where(c == 0, upper[k], c == 2)
            nn = n[k].astype(np.float64)
            a, b = ni / nn, nj / nn
            w = np.column_stack([1.0 - a - b, a, b])
            w[:, 0] = np.where(ni + nj == n[k], 0.0, w[:, 0])  # exact on the far edge
            pts = np.einsum("kc,kcj->kj", w, self.frames.corners[triangles[k]])
            vals = self.fill(triangles[k], np.where(np.asarray(sides)[k] < 0, -1, 1), pts)
            with self.lock:
                fresh = self.slot[new] < 0
                new, vals = new[fresh], vals[fresh]
                rows, count = self.rows, self.count
                if count + len(new) > len(rows):  # readers keep the old array; its rows stay valid
                    grown = np.empty((max(2 * len(rows), count + len(new)), rows.shape[1]), rows.dtype)
                    grown[:count] = rows[:count]
                    self.rows = rows = grown
                rows[count : count + len(new)] = vals
                self.count = count + len(new)
                self.slot[new] = count + np.arange(len(new))  # after the rows
            slot = self.slot[node]
        return np.take(self.rows, slot, axis=0).astype(np.float64, copy=False)


def _patch_values(problem, alpha, values, near: NearField | None) -> np.ndarray:
    """(k, 8) at points with alpha (k, n): alpha @ values, alpha @ (near.indirect + near.extra),
    alpha @ radii, and 1 where the point may see the sky (may_see_sky), else 0."""
    out = np.zeros((alpha.shape[0], 8))
    out[:, :3] = alpha @ values
    out[:, 6] = alpha @ problem.atlas.radii
    if near is not None:
        out[:, 3:6] = alpha @ (near.indirect + near.extra)
        if near.light.sky is not None and near.sky_seen is not None:
            out[:, 7] = may_see_sky(alpha, near.sky_seen)
    return out


class TriangleFrames:
    """Barycentric coordinates on fixed triangles (T, 3, 3), with what depends on the triangle alone
    computed once: a point's weights of the second and third corners are two dot products of its
    offset from the first corner. A degenerate triangle gives a third to each corner."""

    def __init__(self, corners: np.ndarray):
        self.corners = corners = np.asarray(corners, np.float64)
        self.first = a = np.ascontiguousarray(corners[:, 0])
        e1, e2 = corners[:, 1] - a, corners[:, 2] - a
        d11, d12, d22 = (np.einsum("kj,kj->k", x, y) for x, y in ((e1, e1), (e1, e2), (e2, e2)))
        den = d11 * d22 - d12 * d12
        self.ok = den > 1e-12 * np.maximum(d11 * d22, 1e-300)
        safe = np.where(self.ok, den, 1.0)[:, None]
        # v = (d22 p.e1 - d12 p.e2) / den, w = (d11 p.e2 - d12 p.e1) / den for p = point - a
        self.rows = np.stack(
            [(d22[:, None] * e1 - d12[:, None] * e2) / safe, (d11[:, None] * e2 - d12[:, None] * e1) / safe],
            axis=1,
        )
        self.rows[~self.ok] = 0.0

    def coordinates(self, triangles, points) -> np.ndarray:
        """(k, 2) weights of the second and third corners of points (k, 3) on triangles (k,),
        clipped to the triangle (the three weights at least 0, summing to 1)."""
        d = np.asarray(points, np.float64) - np.take(self.first, triangles, axis=0)
        vw = np.matmul(np.take(self.rows, triangles, axis=0), d[:, :, None])[:, :, 0]
        ok = np.take(self.ok, triangles)
        first = np.maximum(1.0 - vw[:, 0] - vw[:, 1], 0.0)
        np.maximum(vw, 0.0, out=vw)
        total = first + vw[:, 0] + vw[:, 1]
        vw /= np.where(total > 0, total, 1.0)[:, None]
        vw[~ok | (total <= 0)] = 1.0 / 3.0
        return vw


def may_see_sky(alpha, seen: np.ndarray | None) -> np.ndarray | None:
    """(k,) bool: the points (alpha (k, n) of the patches there) that may see the sky: a patch
    there is marked in `seen` (n,) (pipeline.sky_patches), or none covers them; None: all of them
    (seen is None)."""
    if seen is None:
        return None
    return (alpha @ np.asarray(seen, np.float64) > 0) | (np.asarray(alpha.sum(axis=1)).ravel() <= 0)


def inside(surfaces, points: np.ndarray, triangles) -> np.ndarray:
    """Points (m, 3) moved towards the centroids of their triangles (m,) by INSIDE x the scene
    extent, at most halfway: off every edge of the triangle, so off the plane of a neighbouring face
    that meets it at a concave edge, by far more than the rays' start offset."""
    c = np.take(surfaces.corners, np.asarray(triangles, np.int64), axis=0).mean(axis=1)
    to = c - points
    dist = np.linalg.norm(to, axis=1, keepdims=True)
    step = np.minimum(INSIDE * surfaces.extent, 0.5 * dist)
    return points + to * (step / np.maximum(dist, 1e-300))


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


def gather_unique(
    problem,
    radiosity: np.ndarray,
    emission: np.ndarray,
    points,
    normals,
    rays: int,
    triangles=None,
    progress: Callable[[float], None] | None = None,
    near: NearField | None = None,
    spread: np.ndarray | None = None,
    corner_cache: dict | None = None,
) -> np.ndarray:
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
    out = gather_indirect(
        problem,
        radiosity,
        emission,
        pts,
        nrm,
        rays,
        tri,
        progress,
        near=near,
        spread=spread,
        corner_cache=corner_cache,
    )
    return out[inverse]
