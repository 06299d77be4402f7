"""Light transport between patches: R[h, k] = integral over D_h of rho(M) times the form factor
from M to alpha_k, estimated by casting rays over each receiver point's hemisphere.

With directions drawn cosine-weighted, the form factor from M to a region is the fraction of
M's rays that land in it, so (1/n) sum_j alpha_k(N_j) estimates the integral of alpha_k(N) F(M, N)
over D_k with visibility included. Because the alpha at every hit sum to 1, the row sums of the
geometric part close exactly (sum_k G[h, k] = A_h) wherever every ray hits a covered surface:
energy is conserved by construction, the property the furnace test needs. The directions are
stratified and fixed per point (a jittered grid through Malley's method), so a solve is
deterministic and repeatable.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix

from .overlap import alpha_at, patch_quadrature


@dataclass(frozen=True)
class Transport:
    """R = diag(rho_c) G per colour channel c.

    geometric G (n x n sparse): G[h, k] = integral over D_h of the form factor to alpha_k,
    rho (n, 3) reflectance of each receiver patch (area-weighted over its support),
    rays cast to build it.
    """

    geometric: csr_matrix
    rho: np.ndarray
    rays: int

    def received(self, cols: np.ndarray, unshot: np.ndarray) -> np.ndarray:
        """EC (n, 3): light landing in every test region when patches `cols` shoot unshot (len, 3)."""
        return self.rho * (self.geometric[:, cols] @ unshot)


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


def gather_transport(
    atlas,
    index,
    rays_per_point: int = 64,
    q: int = 4,
    progress: Callable[[float], None] | None = None,
    chunk_rays: int = 1 << 20,
    seed: int = 0,
) -> Transport:
    """Build G and rho for every patch by hemisphere gathering from its quadrature points."""
    n = len(atlas)
    surfaces = index.surfaces
    offset = 1e-6 * surfaces.extent
    rng = np.random.default_rng(seed)
    rows, cols, vals = [], [], []
    rho_sum = np.zeros((n, 3))
    area = np.zeros(n)
    per_chunk = max(1, chunk_rays // (rays_per_point * 4 * q * 2 * max(q // 4, 1) * 2))
    rays = 0
    for s0 in range(0, n, per_chunk):
        ids = np.arange(s0, min(n, s0 + per_chunk))
        quad = patch_quadrature(atlas, index, ids, q, rings=max(q // 2, 1))
        on = quad.weights > 0
        owner, pts, nrm, w, tri = (
            quad.owner[on],
            quad.points[on],
            quad.normals[on],
            quad.weights[on],
            quad.triangle[on],
        )
        # The gathering rule is coarser than the one that integrated C: rescale its weights to
        # the support areas A_h of C, so that sum_k G[h, k] = A_h = sum_i C[h, i] exactly in a
        # closed scene and a uniform radiosity stays an exact solution (furnace).
        coarse_area = np.bincount(owner, weights=w, minlength=len(ids))
        w = w * (atlas.support_area[ids] / np.maximum(coarse_area, 1e-300))[owner]
        rho_pt = surfaces.reflectance[tri]
        np.add.at(rho_sum, ids[owner], rho_pt * w[:, None])
        np.add.at(area, ids[owner], w)
        dirs = cosine_directions(nrm, rays_per_point, rng).reshape(-1, 3)
        origins = np.repeat(pts + offset * nrm, rays_per_point, axis=0)
        t, hit_tri = index.rays.closest_hit(origins, dirs, np.inf)
        rays += len(dirs)
        hit = hit_tri >= 0
        ray_owner = np.repeat(owner, rays_per_point)[hit]
        ray_w = np.repeat(w / rays_per_point, rays_per_point)[hit]
        hp = origins[hit] + t[hit, None] * dirs[hit]
        facing = np.einsum("ij,ij->i", dirs[hit], index.charts.normals[hit_tri[hit]])
        side = np.where(facing < 0, 1, -1)
        alpha = alpha_at(atlas, index, hp, hit_tri[hit], side).tocoo()
        part = (
            coo_matrix(
                (alpha.data * ray_w[alpha.row], (ray_owner[alpha.row], alpha.col)), shape=(len(ids), n)
            )
            .tocsr()
            .tocoo()
        )  # summed per (h, k) within the chunk: memory grows with G, not with rays
        rows.append(ids[part.row])
        cols.append(part.col)
        vals.append(part.data)
        if progress is not None:
            progress((s0 + len(ids)) / n)
    G = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()
    rho = rho_sum / np.maximum(area, 1e-300)[:, None]
    return Transport(geometric=G, rho=rho, rays=rays)
