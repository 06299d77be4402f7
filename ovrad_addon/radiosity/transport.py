"""Light transport between patches: R^c[h, k] = rho^c_h G[h, k], with G[h, k] the integral over
D_h of the form factor from M to alpha_k, estimated by hemisphere rays from each patch's own
quadrature points.

With cosine-distributed directions, the form factor from M to a region is the fraction of M's
rays that land in it, so (1/n) sum_j alpha_k(N_j) estimates the integral of alpha_k(N) F(M, N)
over D_k with visibility included. The alpha at every hit sum to 1, so the rows close exactly,
sum_k G[h, k] = A_h wherever every ray hits covered surface: energy is conserved by
construction (the furnace test). Directions are stratified and seeded: a solve is repeatable.
Direct light (lamps, emitters) is not left to these rays: radiosity/first_shot.py shoots it with shadow
rays to the same quadrature points, whose test integrals are accurate to the rule.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csc_matrix, csr_matrix

from ..atlas.balls import BallRule
from ..geometry import start_of, tangent_frame
from ..overlap.queries import alpha_pairs, ray_hits, support_points
from ..overlap.sight import Contacts
from ..parallel import WORKERS, threaded
from .clusters import Clusters, pooled_fraction


@dataclass(frozen=True)
class ReceiverPoints:
    """Quadrature points of every patch's support (a coarse polar rule): owner (m,) patch,
    points (m, 3), normals (m, 3) on the patch's side, weight (m,) area (summing per patch to
    its support area A_h), triangle (m,)."""

    owner: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    weight: np.ndarray
    triangle: np.ndarray


def receiver_points(
    atlas, index, contacts: Contacts, q: int = 4, rings: int = 1, balls: BallRule | None = None
) -> ReceiverPoints:
    """Coarse rule points on every support (overlap.queries.support_points: also on a support far smaller
    than its patch), weights rescaled to the support areas A_h of C."""
    quad = support_points(atlas, index, contacts, q, rings, balls=balls)
    coarse = np.bincount(quad.owner, weights=quad.weights, minlength=len(atlas))
    w = quad.weights * (atlas.support_area / np.maximum(coarse, 1e-300))[quad.owner]
    return ReceiverPoints(quad.owner, quad.points, quad.normals, w, quad.triangle)


THIN_MIN = 2  # receiver points a thinned rule keeps per patch at least (thinned_points)


def thinned_points(points: ReceiverPoints, keep: float) -> ReceiverPoints:
    """About `keep` (0, 1] of the receiver points, at least THIN_MIN per patch (or all it has):
    an even number k of a patch's c points, every (c / k)-th in the order of its rule. The rule
    goes round the patch's centre ray by ray, so for an even c the kept points come in pairs c / 2
    apart, on opposite rays: their mean stays at the centre, and a light that varies linearly
    over the patch is integrated as exactly as by all the points. Weights rescaled so that each
    patch's still sum to its support area. The first shot of a large atlas under its ray budget
    (radiosity.first_shot.first_shot_points)."""
    if keep >= 1.0 or len(points.owner) == 0:
        return points
    order = np.argsort(points.owner, kind="stable")
    counts = np.bincount(points.owner)
    kept = np.minimum(counts, np.maximum(THIN_MIN, 2 * np.ceil(counts * keep / 2).astype(np.int64)))
    patch = np.repeat(np.arange(len(counts)), kept)
    j = np.arange(int(kept.sum())) - np.repeat(start_of(kept), kept)
    at = order[start_of(counts)[patch] + (j * counts[patch]) // kept[patch]]  # kept > 0 where repeated
    owner = points.owner[at]
    total = np.bincount(points.owner, weights=points.weight, minlength=len(counts))
    part = np.bincount(owner, weights=points.weight[at], minlength=len(counts))
    weight = points.weight[at] * (total / np.maximum(part, 1e-300))[owner]
    return ReceiverPoints(owner, points.points[at], points.normals[at], weight, points.triangle[at])


@dataclass(frozen=True)
class Transport:
    """R = diag(rho_c) G per colour channel; G (n x n, csc for column access), rho (n, 3) the
    reflectance of each patch (averaged over its support), the receiver points, rays cast, and
    how many of them escaped (hit nothing: they saw the sky, if there is one).

    With clusters (gather_transport's `far`), G = geometric + links @ push: geometric holds the
    near hits (alpha at each), links (n x clusters) the far hits per cluster, push (clusters x n,
    csc) each cluster's mean-radiosity weights (radiosity/clusters.py). Products go through the two
    factors; G itself is never formed (matrix() does, for small scenes and tests)."""

    geometric: csc_matrix
    rho: np.ndarray
    points: ReceiverPoints
    rays: int
    escaped: int = -1  # -1: not counted
    # (n,) the fraction of each patch's rays that escaped: its cosine-weighted share of the sky,
    # pooled over its cell of patches where it cast fewer than SKY_TEST_RAYS itself
    # (radiosity.clusters.pooled_fraction); NaN where all patches facing its way cast fewer (too few to
    # tell); None: unknown
    sky_fraction: np.ndarray | None = None
    links: csr_matrix | None = None
    push: csc_matrix | None = None

    @property
    def sky_seen(self) -> np.ndarray | None:
        """(n,) bool: the patch may see the sky: some of its rays escaped, or it cast too few to
        tell; None: unknown. Bake points and near gather hits skip sky rays elsewhere."""
        return None if self.sky_fraction is None else ~(self.sky_fraction == 0)

    @property
    def entries(self) -> int:
        """Stored entries of G's factors: what the transport holds in memory, 12 bytes each."""
        far = 0 if self.links is None else self.links.nnz + self.push.nnz
        return int(self.geometric.nnz + far)

    def matrix(self) -> csc_matrix:
        """G itself (n x n): geometric, plus links @ push with clusters."""
        if self.links is None:
            return self.geometric
        return (self.geometric + self.links @ self.push).tocsc()

    def received(self, cols: np.ndarray, unshot: np.ndarray) -> np.ndarray:
        """EC (n, 3): light landing in every test region when patches `cols` shoot unshot (len, 3)."""
        G = self.geometric
        if len(cols) * 8 < G.shape[1]:
            out = G[:, cols] @ unshot
            if self.links is not None:
                out += self.links @ (self.push[:, cols] @ unshot)
            return self.rho * out
        # many shooters: a product with all of G costs less than copying their columns out
        full = np.zeros((G.shape[1], unshot.shape[1]))
        full[cols] = unshot
        return self.apply(full)

    def apply(self, B: np.ndarray) -> np.ndarray:
        """R B (n, 3)."""
        out = self.geometric @ B
        if self.links is not None:
            out += self.links @ (self.push @ B)
        return self.rho * out

    def test(
        self, irradiance: np.ndarray, reflectance: np.ndarray, points: ReceiverPoints | None = None
    ) -> np.ndarray:
        """Light reflected into each test region from an irradiance (m, 3) at the receiver points
        (or at `points`, a rule of its own on the same patches: thinned_points)."""
        p = self.points if points is None else points
        out = np.zeros((len(self.rho), irradiance.shape[1]))
        np.add.at(out, p.owner, reflectance * irradiance * p.weight[:, None])
        return out


POINT_RAYS = 256  # rays per receiver point a min_rays budget aims at before it adds points

MAX_SCALE = 16

SKY_TEST_RAYS = 256  # a patch whose this many rays all hit something sees under ~1/256 of sky

SKY_TEST_SHARE = 0.1  # the sky test (_sky_test) casts at most this share of the transport's rays

MIN_POINT_RAYS = 4  # under a max_rays budget, receiver points are halved before rays go below this

MAX_POINT_RAYS = 1 << 16  # one chunk's arrays stay within a few MB per point


def receiver_scale(points: int, min_rays: int) -> int:
    """How much finer (angles and rings, each) the receiver rule is made so that `points` rule
    points grow to min_rays / POINT_RAYS: 1 for atlases that have enough points already."""
    want = min_rays / POINT_RAYS
    if points <= 0 or points >= want:
        return 1
    return int(min(MAX_SCALE, np.ceil(np.sqrt(want / points))))


def capped(points: int, rays_per_point: int, max_rays: int) -> int:
    """Rays per receiver point within a budget of max_rays in all (0: none), at least 1."""
    if max_rays <= 0 or points * rays_per_point <= max_rays:
        return rays_per_point
    return max(1, max_rays // max(points, 1))


def rays_for(points: int, rays_per_point: int, min_rays: int) -> int:
    """Rays per receiver point: rays_per_point, or more when that casts fewer than min_rays in
    all (at most MAX_POINT_RAYS); then a product a x b with a = floor(sqrt(need)) <= b, so the
    strata form a near-square grid."""
    need = min(-(-min_rays // max(points, 1)), MAX_POINT_RAYS)
    if need <= rays_per_point:
        return rays_per_point
    a = int(np.sqrt(need))
    return a * -(-need // a)


def cosine_directions(normals: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """(m, count, 3) cosine-distributed unit directions around each normal, stratified per point."""
    m = len(normals)
    # a full na x nb grid of strata (na nb = count exactly): a partial grid would weight some
    # strata twice and bias the directions (towards the normal, say)
    na = max(d for d in range(1, int(np.sqrt(count)) + 1) if count % d == 0)
    nb = count // na
    cells = np.arange(count)
    u1 = (cells % na + rng.random((m, count))) / na
    u2 = (cells // na + rng.random((m, count))) / nb
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    x, y = r * np.cos(phi), r * np.sin(phi)
    z = np.sqrt(np.maximum(1.0 - u1, 0.0))
    t, b = tangent_frame(normals)
    return x[..., None] * t[:, None] + y[..., None] * b[:, None] + z[..., None] * normals[:, None]


def gather_transport(
    atlas,
    index,
    contacts: Contacts,
    rays_per_point: int = 32,
    q: int = 4,
    progress: Callable[[float], None] | None = None,
    chunk_rays: int = 1 << 17,
    seed: int = 0,
    workers: int = WORKERS,
    min_rays: int = 0,
    max_rays: int = 0,
    far: float = 0.0,
    balls: BallRule | None = None,
) -> Transport:
    """Build G and rho by hemisphere gathering from every patch's receiver points.

    min_rays: a floor on the rays cast in all. An atlas too small to reach it with q and
    rays_per_point gets a finer receiver rule (more angles and rings, up to 16x each) and more
    rays per point, so a small scene spends the budget on accuracy (receiver_scale, rays_for).
    max_rays: a ceiling (0: none; never below min_rays). A large atlas gets a coarser receiver
    rule (q halved, down to 2, while fewer than MIN_POINT_RAYS rays per point would be left) and
    fewer rays per point, down to one, so the time and G's entries (at most a few per ray) stop
    growing with the patch count once it is reached: G's memory is bounded by the budget.
    far: hits farther than 1/far times the diagonal of a cluster of patches there (radiosity/clusters.py)
    add to that cluster's link instead of taking alpha (0: alpha at every hit); G is then
    geometric + links @ push (Transport). A cluster link holds what many alpha entries did.

    Receiver points go in chunks of about chunk_rays rays, each chunk cast and resolved (alpha
    at the hits, summed per (h, k)) on one of `workers` threads: embree and most numpy work
    release the GIL. Small chunks keep every temporary array in cache (1M-ray chunks were 1.7x
    slower, measured). Each chunk draws from its own seeded stream, so G does not depend on
    thread timing. contacts, balls: the atlas's (Problem.contacts, Problem.balls).
    """
    n = len(atlas)
    per_patch = 4 * (1 if atlas.beta == "box" else 2)  # receiver points per patch and unit of q
    while max_rays and q > 2 and n * per_patch * q * MIN_POINT_RAYS > max(max_rays, min_rays):
        q //= 2  # a very large atlas: fewer receiver points per patch before fewer rays per point
    scale = receiver_scale(n * per_patch * q, min_rays)
    pts = receiver_points(atlas, index, contacts, q * scale, scale, balls)
    rays_per_point = rays_for(len(pts.owner), rays_per_point, min_rays)
    rays_per_point = capped(len(pts.owner), rays_per_point, max(max_rays, min_rays) if max_rays else 0)
    _ = atlas.grid  # build the lookup once, before the threads need it
    offset = 1e-6 * index.surfaces.extent
    m = len(pts.owner)
    clusters = Clusters.build(atlas, pts, far, contacts.covered) if far > 0 else None
    step = max(1, chunk_rays // rays_per_point)
    starts = list(range(0, m, step))

    def chunk(k: int):
        sl = slice(starts[k], min(m, starts[k] + step))
        rng = np.random.default_rng([seed, k])
        nrm = pts.normals[sl]
        dirs = cosine_directions(nrm, rays_per_point, rng).reshape(-1, 3)
        origins = np.repeat(pts.points[sl] + offset * nrm, rays_per_point, axis=0)
        hits = ray_hits(index, origins, dirs)
        hit, t, points, tri, side = hits.ray, hits.t, hits.points, hits.triangle, hits.side
        owner = np.repeat(pts.owner[sl], rays_per_point)[hit]
        ray_w = np.repeat(pts.weight[sl] / rays_per_point, rays_per_point)[hit]
        far_part = None
        if clusters is not None:
            facing = np.take(index.charts.normals, tri, axis=0) * side[:, None]
            linked, col = clusters.columns(points, index.sheet_of(tri, side), facing, t, index.rays)
            far_part = _summed(ray_w[linked], owner[linked], col, (n, clusters.count))
            near = np.ones(len(hit), bool)
            near[linked] = False
            near = np.flatnonzero(near)
            points, tri, side = np.take(points, near, axis=0), tri[near], side[near]
            owner, ray_w = owner[near], ray_w[near]
        row, col, a = alpha_pairs(atlas, index, contacts, points, tri, side)
        # summed per (h, k) within the chunk: memory follows G, not rays
        part = _summed(a * np.take(ray_w, row), np.take(owner, row), col, (n, n))
        out = np.ones(len(dirs), bool)
        out[hit] = False
        escaped = np.bincount(np.repeat(pts.owner[sl], rays_per_point)[out], minlength=n)
        return part, far_part, escaped, sl.stop

    near_parts, far_parts = [], []
    escaped = np.zeros(n, np.int64)
    for part, far_part, out, done in threaded(chunk, len(starts), workers):
        escaped += out
        near_parts.append(part)
        if far_part is not None:
            far_parts.append(far_part)
        if progress is not None:
            progress(done / m)  # on the calling thread: a cancel raised here stops the pool
    G = _assembled(near_parts, (n, n)).tocsc()
    links = _assembled(far_parts, (n, clusters.count)).tocsr() if clusters is not None else None
    rho = np.zeros((n, 3))
    # the albedo at the receiver points (a texture's, where there is one): rho_h its mean over D_h,
    # over the part of D_h that is there where a material's alpha is below 1 (a leaf card's texels
    # outside the leaf reflect nothing: their colour does not count)
    albedo = index.surfaces.reflectance_at(pts.triangle, pts.points)
    weight = pts.weight
    if index.surfaces.coverage is not None:
        there = index.surfaces.opacity_at(pts.triangle, pts.points) * pts.weight
        held = np.bincount(pts.owner, weights=there, minlength=n)
        weight = np.where(held[pts.owner] > 0, there, pts.weight)
    np.add.at(rho, pts.owner, albedo * weight[:, None])
    rho /= np.maximum(np.bincount(pts.owner, weights=weight, minlength=n), 1e-300)[:, None]
    cast = np.bincount(pts.owner, minlength=n) * rays_per_point
    escaped, cast = _sky_test(index, pts, escaped, cast, offset, seed)
    fraction = pooled_fraction(atlas, escaped, cast, SKY_TEST_RAYS)
    push = clusters.push if clusters is not None else None
    return Transport(G, rho, pts, m * rays_per_point, int(escaped.sum()), fraction, links, push)


def _summed(values, rows, cols, shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Entries summed per (row, col), with int32 indices: G's assembly holds every chunk's at once."""
    part = coo_matrix((values, (rows, cols)), shape=shape).tocsr().tocoo()
    return part.row.astype(np.int32), part.col.astype(np.int32), part.data


def _assembled(parts, shape) -> coo_matrix:
    if not parts:
        return coo_matrix(shape)
    rows, cols, vals = zip(*parts, strict=True)
    return coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape)


def _sky_test(index, pts: ReceiverPoints, escaped: np.ndarray, cast: np.ndarray, offset: float, seed: int):
    """escaped and cast (n,) with SKY_TEST_RAYS rays in all from each patch that cast fewer (and has
    receiver points): extra occlusion rays from its receiver points, to tell whether it sees the
    sky and how much of it (Transport.sky_fraction). Ball patches over clutter and slivers on
    borders cast a few dozen transport rays each; without this test they all counted as seeing
    the sky, and every bake point and near gather hit on them cast sky rays (most of the sky rays
    of the production room's bake under a grey world). Only when the test costs at most
    SKY_TEST_SHARE of the rays already cast: under a large atlas's ray budget every patch casts
    a few, and testing them all would cost more than the transport (their cells tell instead:
    radiosity.clusters.pooled_fraction)."""
    counts = np.bincount(pts.owner, minlength=len(cast))
    short = np.flatnonzero((cast < SKY_TEST_RAYS) & (counts > 0))
    want = SKY_TEST_RAYS - cast[short]
    if len(short) == 0 or want.sum() > SKY_TEST_SHARE * cast.sum():
        return escaped, cast
    order = np.argsort(pts.owner, kind="stable")  # each patch's receiver points, together
    first = np.searchsorted(pts.owner[order], short)
    # spread each patch's extra rays over its receiver points, round-robin from its first
    owner = np.repeat(short, want)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(want) - want, want)
    point = order[np.repeat(first, want) + k % counts[owner]]
    nrm = pts.normals[point]
    rng = np.random.default_rng([seed, 1 << 20])
    dirs = cosine_directions(nrm, 1, rng).reshape(-1, 3)
    through = index.rays.transmittance(pts.points[point] + offset * nrm, dirs, np.inf)
    escaped = escaped + np.bincount(owner, weights=through, minlength=len(cast))
    cast = cast.copy()
    cast[short] = SKY_TEST_RAYS
    return escaped, cast
