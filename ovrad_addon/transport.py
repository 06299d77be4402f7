"""Light transport in test space, estimated on one shared set of surface samples.

Every receiving sheet is covered by stratified samples s (area weight w_s). From each sample,
cosine-distributed rays find what it sees; with Y[s, k] the sum over its rays of alpha_k at the
hit points and X[s, h] = 1 where s lies in D_h:

    R^c[h, k] = sum_s X[s, h] w_s rho^c_s Y[s, k] / n_rays      (R of method.md, per channel)
    C[h, i]   = sum_s X[s, h] w_s alpha_i(s)                     (the overlap matrix, same samples)

Using the same samples for C and R matters: the noise of ray estimates is then one field shared
by all test regions, so C^-1 does not amplify it into checkerboards between overlapping
patches. Because the alpha at every hit sum to 1, sum_k R[h, k] = rho A_h exactly wherever all
rays hit covered surface (energy is conserved by construction: the furnace test). Directions are
stratified and seeded, so a solve is deterministic.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csc_matrix, csr_matrix, diags

from .overlap import alpha_at


@dataclass(frozen=True)
class Samples:
    """Stratified points on every sheet that has patches: (S, 3) points and normals (on the
    sheet's side), triangle (S,), side (S,) +-1, weight (S,) area."""

    points: np.ndarray
    normals: np.ndarray
    triangle: np.ndarray
    side: np.ndarray
    weight: np.ndarray


def surface_samples(atlas, index, per_radius: float = 3.0, seed: int = 0) -> Samples:
    """About per_radius^2 samples per r^2 (r the sheet's patch radius), stratified per triangle."""
    rng = np.random.default_rng(seed)
    ch = index.charts
    corners = index.surfaces.corners
    out = []
    for sheet, (c, side) in enumerate(zip(index.sheet_chart, index.sheet_side, strict=True)):
        on = atlas.sheet == sheet
        if not on.any():
            continue
        delta = float(np.median(atlas.radii[on])) / per_radius
        tri = np.flatnonzero(ch.chart == c)
        k = np.maximum(np.round(ch.areas[tri] / delta**2), 1).astype(np.int64)
        t = np.repeat(tri, k)
        # jittered strata of the unit square, warped onto the triangle (area-preserving)
        start = np.repeat(np.cumsum(k) - k, k)
        j = np.arange(len(t)) - start
        g = np.ceil(np.sqrt(k)).astype(np.int64)[np.repeat(np.arange(len(tri)), k)]
        a = (j % g + rng.random(len(t))) / g
        b = ((j // g) % g + rng.random(len(t))) / g
        sa = np.sqrt(a)
        u, v = 1.0 - sa, b * sa
        cc = corners[t]
        p = cc[:, 0] + u[:, None] * (cc[:, 1] - cc[:, 0]) + v[:, None] * (cc[:, 2] - cc[:, 0])
        out.append(
            (
                p,
                side * ch.normals[t],
                t,
                np.full(len(t), side),
                (ch.areas[tri] / k)[np.repeat(np.arange(len(tri)), k)],
            )
        )
    cols = list(zip(*out, strict=True))
    return Samples(*(np.concatenate(c) for c in cols))


@dataclass(frozen=True)
class Transport:
    """R and C on shared samples (see module docstring).

    X (S x n csr) membership of samples in patches, Y (S x n csc) summed alpha at ray hits,
    w (S,) sample areas, rho (S, 3) reflectance at samples, n_rays per sample, C (n x n csr)."""

    X: csr_matrix
    Y: csc_matrix
    w: np.ndarray
    rho: np.ndarray
    n_rays: int
    C: csr_matrix
    samples: Samples
    rays: int

    def received(self, cols: np.ndarray, unshot: np.ndarray) -> np.ndarray:
        """EC (n, 3): light landing in every test region when patches `cols` shoot unshot (len, 3)."""
        at_samples = self.Y[:, cols] @ unshot
        return self.X.T @ (at_samples * (self.w[:, None] * self.rho / self.n_rays))

    def apply(self, B: np.ndarray) -> np.ndarray:
        """R B (n, 3) for radiosity B (n, 3)."""
        return self.X.T @ ((self.Y @ B) * (self.w[:, None] * self.rho / self.n_rays))

    def test(self, field_at_samples: np.ndarray) -> np.ndarray:
        """Integral over each D_h of a field given at the samples: X^T (w f), (n, c)."""
        return self.X.T @ (field_at_samples * self.w[:, None])


def cosine_directions(normals: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """(m, count, 3) cosine-distributed unit directions around each normal, stratified per point."""
    m = len(normals)
    side = int(np.ceil(np.sqrt(count)))
    cells = np.arange(side * side)[:count]
    u1 = (cells % side + rng.random((m, count))) / side
    u2 = (cells // side + rng.random((m, count))) / side
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    x, y = r * np.cos(phi), r * np.sin(phi)
    z = np.sqrt(np.maximum(1.0 - u1, 0.0))
    helper = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
    t = np.cross(helper, normals)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(normals, t)
    return x[..., None] * t[:, None] + y[..., None] * b[:, None] + z[..., None] * normals[:, None]


def _membership_and_alpha(atlas, index, s: Samples, sl: slice) -> tuple[csr_matrix, csr_matrix]:
    from .overlap import candidate_patches
    from .support import alpha_from_pairs, pair_beta

    pts = s.points[sl]
    sheets = index.sheet_of(s.triangle[sl], s.side[sl])
    rows, cols = candidate_patches(atlas, pts)
    member, b = pair_beta(atlas, cols, pts[rows], s.normals[sl][rows], sheets[rows], atlas.beta)
    X = coo_matrix(
        (np.ones(member.sum()), (rows[member], cols[member])), shape=(len(pts), len(atlas))
    ).tocsr()
    return X, alpha_from_pairs(rows, cols, member, b, (len(pts), len(atlas)))


def gather_transport(
    atlas,
    index,
    rays_per_point: int = 64,
    progress: Callable[[float], None] | None = None,
    chunk_rays: int = 1 << 20,
    seed: int = 0,
    per_radius: float = 3.0,
) -> Transport:
    """Samples, their membership and alpha (C), and their hemisphere rays (R)."""
    n = len(atlas)
    s = surface_samples(atlas, index, per_radius, seed)
    rng = np.random.default_rng(seed + 1)
    offset = 1e-6 * index.surfaces.extent
    S = len(s.weight)
    per_chunk = max(1, chunk_rays // rays_per_point)
    Xs, As, Ys = [], [], []
    for s0 in range(0, S, per_chunk):
        sl = slice(s0, min(S, s0 + per_chunk))
        X, A = _membership_and_alpha(atlas, index, s, sl)
        Xs.append(X)
        As.append(A)
        nrm = s.normals[sl]
        dirs = cosine_directions(nrm, rays_per_point, rng).reshape(-1, 3)
        origins = np.repeat(s.points[sl] + offset * nrm, rays_per_point, axis=0)
        t, hit_tri = index.rays.closest_hit(origins, dirs, np.inf)
        hit = hit_tri >= 0
        hp = origins[hit] + t[hit, None] * dirs[hit]
        facing = np.einsum("ij,ij->i", dirs[hit], index.charts.normals[hit_tri[hit]])
        a = alpha_at(atlas, index, hp, hit_tri[hit], np.where(facing < 0, 1, -1)).tocoo()
        owner = np.repeat(np.arange(sl.stop - sl.start), rays_per_point)[hit]
        Ys.append(coo_matrix((a.data, (owner[a.row], a.col)), shape=(sl.stop - sl.start, n)).tocsr())
        if progress is not None:
            progress(sl.stop / S)
    from scipy.sparse import vstack

    X = vstack(Xs).tocsr()
    A = vstack(As).tocsr()
    Y = vstack(Ys).tocsc()
    C = (X.T @ diags(s.weight) @ A).tocsr()
    return Transport(
        X=X,
        Y=Y,
        w=s.weight,
        rho=index.surfaces.reflectance[s.triangle],
        n_rays=rays_per_point,
        C=C,
        samples=s,
        rays=S * rays_per_point,
    )
