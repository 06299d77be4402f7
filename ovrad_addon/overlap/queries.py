"""Point queries on an atlas: alpha at surface points, the patches a ray lands in, coarse rules on
every support (support_points), per-patch averages of per-triangle values and reconstruction."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
from scipy.sparse import csr_matrix

from ..atlas.balls import BallRule, ball_rule
from ..atlas.support import alpha_values, pair_beta
from .contacts import seen_members
from .quadrature import patch_quadrature
from .rule import Quadrature
from .sight import Contacts

# Hits whose candidate pairs alpha_at tests at once (about four pairs a hit): every temporary then
# stays within a few hundred kB, in cache and off fresh pages (a 131 k-ray chunk's pairs at once
# cost twice as much per pair). The contact test of the members is one batch of rays for all.
HIT_BLOCK = 4096


def alpha_at(atlas, index, contacts: Contacts, points: np.ndarray, triangle: np.ndarray, side) -> csr_matrix:
    """alpha_i at surface points (m x n sparse): points (m, 3) on `triangle` (m,), seen from side (m,) +-1;
    contacts: the atlas's (overlap.contacts.contacts(), Problem.contacts)."""
    rows, cols, a = alpha_pairs(atlas, index, contacts, points, triangle, side)
    m = len(np.asarray(triangle).reshape(-1))
    indptr = np.zeros(m + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=m), out=indptr[1:])
    return csr_matrix((a, cols, indptr), shape=(m, len(atlas)))


def alpha_pairs(
    atlas, index, contacts: Contacts, points: np.ndarray, triangle: np.ndarray, side
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nonzero entries of alpha_at as (rows, cols, alpha) (k,) each, by row and, within a row,
    by patch: the order of alpha_at's CSR, for callers that sum entries themselves."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    tri = np.asarray(triangle, np.int64).reshape(-1)
    side = np.broadcast_to(np.asarray(side), tri.shape)
    m = len(tri)
    parts = [_members(atlas, index, pts, tri, side, s, min(m, s + HIT_BLOCK)) for s in range(0, m, HIT_BLOCK)]
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    rows, cols, b = parts[0] if len(parts) == 1 else (np.concatenate(x) for x in zip(*parts, strict=True))
    seen = seen_members(atlas, index, contacts, rows, cols, pts, np.ones(len(rows), bool), per_row=True)
    if not seen.all():
        keep = np.flatnonzero(seen)
        rows, cols, b = np.take(rows, keep), np.take(cols, keep), np.take(b, keep)
    return rows, cols, alpha_values(rows, b, m)


def _members(atlas, index, pts, tri, side, lo: int, hi: int):
    """(rows, patches, beta) of the member pairs of points lo:hi (rows index all the points), before
    the contact test."""
    tri, side = tri[lo:hi], side[lo:hi]
    sheets = index.sheet_of(tri, side)
    nrm = np.take(index.charts.normals, np.maximum(tri, 0), axis=0) * np.where(side < 0, -1.0, 1.0)[:, None]
    rows, cols = atlas.grid.candidates(pts[lo:hi], sheets)
    at = np.take(pts[lo:hi], rows, axis=0)
    member, b = pair_beta(atlas, cols, at, np.take(nrm, rows, axis=0), None, atlas.beta)
    keep = np.flatnonzero(member)
    return np.take(rows, keep) + lo, np.take(cols, keep), np.take(b, keep)


@dataclass(frozen=True)
class RayHits:
    """Where rays landed: ray (k,) index of each ray that hit, t (k,) its distance, points (k, 3),
    triangle (k,), and side (k,) +-1, the side of the triangle the ray arrives at."""

    ray: np.ndarray
    t: np.ndarray
    points: np.ndarray
    triangle: np.ndarray
    side: np.ndarray


def ray_hits(index, origins: np.ndarray, directions: np.ndarray) -> RayHits:
    """Cast rays (origins, unit directions (m, 3)) to the surfaces: the hits where the transport
    and the final gather look alpha up (alpha_at), on the side they arrive at. A see-through
    surface stops a ray in proportion to its material's alpha (scene.rays.SeeThroughRays)."""
    t, tri = index.rays.light_hit(origins, directions, np.inf)
    hit = np.flatnonzero(tri >= 0)
    tri = tri[hit]
    d = np.take(directions, hit, axis=0)
    side = np.where(np.einsum("ij,ij->i", d, np.take(index.charts.normals, tri, axis=0)) < 0, 1, -1)
    t = t[hit]
    return RayHits(hit, t, np.take(origins, hit, axis=0) + t[:, None] * d, tri, side)


def reconstruct(alpha: csr_matrix, values: np.ndarray) -> np.ndarray:
    """f(M) = sum_i alpha_i(M) f_i for per-patch values (n,) or (n, c); 0 where no patch covers M."""
    return alpha @ np.asarray(values, np.float64)


FINER_RINGS = 4  # rings grow this many times per pass for supports a coarse rule missed

MAX_RINGS = 256


def support_points(
    atlas,
    index,
    contacts: Contacts,
    q: int,
    rings: int,
    ids: np.ndarray | None = None,
    balls: BallRule | None = None,
) -> Quadrature:
    """A coarse rule (q, rings) on every patch's support, its points on the support only (weight
    > 0; owner: the patch; no neighbour slots). A patch much larger than its support (a disk on a
    leaf a fifth of its size, a square on a small cube's face) may have no coarse point on it: its
    rings are made FINER_RINGS times finer until some are (up to MAX_RINGS), as C's rule found it.
    Without points a patch got no transport receivers, so no light, and none of the per-patch
    means (emission, albedo): 1 365 of the production room's 9 478 patches at a target of 8 000
    had none, and its leaves baked 11 % too dark. ids: only these patches (owner still indexes the
    atlas); all by default. contacts, balls: the atlas's (Problem.contacts, Problem.balls)."""
    ids = np.arange(len(atlas)) if ids is None else np.asarray(ids, np.int64)
    if balls is None:
        balls = ball_rule(atlas, index)
    first = _on_support(patch_quadrature(atlas, index, ids, q, rings=rings, visibility=contacts, balls=balls))
    parts = [replace(first, owner=ids[first.owner])]
    missing = np.zeros(len(atlas), bool)
    missing[ids] = atlas.support_area[ids] > 0
    missing[parts[0].owner] = False
    while np.any(missing) and rings < MAX_RINGS:
        rings *= FINER_RINGS
        where = np.flatnonzero(missing)
        finer = _on_support(
            patch_quadrature(atlas, index, where, q, rings=rings, visibility=contacts, balls=balls)
        )
        parts.append(replace(finer, owner=where[finer.owner]))
        missing[where[finer.owner]] = False
    if len(parts) == 1:
        return parts[0]
    return Quadrature(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Quadrature)))


def _on_support(quad: Quadrature) -> Quadrature:
    """The rule points of quad that lie on the supports (weight > 0). Field by field, each full
    array released as soon as it is cut (100 k patches: the full rule is about 0.5 GB)."""
    arrays = {f.name: getattr(quad, f.name) for f in fields(Quadrature)}
    del quad  # the caller passes a temporary: these are now the only references
    on = arrays["weights"] > 0
    return Quadrature(**{name: arrays.pop(name)[on] for name in list(arrays)})


def patch_average(
    atlas, index, contacts: Contacts, per_triangle: np.ndarray, q: int = 4, balls: BallRule | None = None
) -> np.ndarray:
    """Area-weighted mean over each patch's support of a per-triangle quantity (T, c) -> (n, c).

    A support lies on its patch's sheet, so only patches of sheets with a nonzero triangle are
    integrated (the rest are 0): a room's emission is on its lamps' few patches (at 100 k patches
    the whole rule took ~8 s per per-patch mean the vertex bake asked for)."""
    vals = np.asarray(per_triangle, np.float64)
    out = np.zeros((len(atlas), vals.shape[1]))
    nonzero = np.flatnonzero(np.any(vals != 0, axis=1))
    if len(atlas) == 0 or len(nonzero) == 0:
        return out
    sheets = np.concatenate([index.sheet_of(nonzero, np.full(len(nonzero), s)) for s in (1, -1)])
    ids = np.flatnonzero(np.isin(atlas.sheet, sheets[sheets >= 0]))
    if len(ids) == 0:
        return out
    quad = support_points(atlas, index, contacts, q, max(q // 2, 1), ids, balls)
    w = quad.weights
    np.add.at(out, quad.owner, vals[quad.triangle] * w[:, None])
    area = np.bincount(quad.owner, weights=w, minlength=len(atlas))
    return out / np.maximum(area, 1e-300)[:, None]
