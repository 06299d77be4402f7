"""The polar rule of a patch's support: Gauss points on the pieces of each rule ray between its
neighbours' rims (the Quadrature arrays, before they are moved onto the surface)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..names import SHAPE_SQUARE


@dataclass(frozen=True)
class Quadrature:
    """Rule points on the supports of some patches, flat: owner (m,) position in the ids given,
    points (m, 3), normals (m, 3) surface normal on the patch's side, weights (m,) area (0 where
    the rule point is off the support), triangle (m,) (-1 off the support)."""

    owner: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    triangle: np.ndarray
    cand: np.ndarray  # (m, M) bool: neighbour slots (of the nb given) that may contain the point


@lru_cache(maxsize=64)
def _gauss(n_sub: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1] (read-only: one pair per order, shared)."""
    x, w = np.polynomial.legendre.leggauss(n_sub)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    x.flags.writeable = w.flags.writeable = False
    return x, w


def polar_rule(
    atlas, ids: np.ndarray, nb: np.ndarray, q: int, planar: np.ndarray, rings: int, rays=None, cuts=None
):
    """Polar rule on each patch: (owner, x, y, w, cand, ray) flat, in the patch's plane
    coordinates, ray the rule ray each point lies on; rays (k, 4q) bool: those rule rays only;
    cuts (k, 4q, E): more distances to split them at.

    Along each of 4q rays from the centre, the radius is split at every crossing of a
    neighbour's rim (nb (k, M) neighbour indices, -1 padding; used on planar sheets, where
    rims are exact circles and squares in the plane) and at `rings` equal-area rings. alpha is then
    smooth inside each piece, so two Gauss points per piece (in rho^2) integrate it (and a box-beta
    alpha, constant on each piece, exactly); the angular rule is the only approximation left.
    cand (m, M) marks the neighbours that may contain each rule point: on planar sheets the
    rim crossings already tell, elsewhere every neighbour is a candidate.
    """
    theta, dtheta, ux, uy, rmax = rule_rays(atlas, ids, q)
    k, n_t = theta.shape
    r = atlas.radii[ids][:, None]
    ring = np.sqrt(np.arange(1, rings) / rings)[None, None, :] * rmax[..., None]
    breaks = [np.zeros((k, n_t, 1)), ring, rmax[..., None]]
    spans = _rim_crossings(atlas, ids, nb, planar, ux, uy, rmax) if nb.shape[1] else None
    if spans is not None:
        breaks += list(spans[:2])
    if cuts is not None:
        breaks.append(np.minimum(cuts, rmax[..., None]))
    bp = np.sort(np.concatenate(breaks, axis=2), axis=2)
    lo, hi = bp[..., :-1], bp[..., 1:]
    keep = hi > lo + 1e-12 * r[..., None]
    if rays is not None:
        keep &= rays[..., None]
    kk, tt, _ = np.nonzero(keep)
    lo, hi = lo[keep], hi[keep]
    rho, w = _radial_points(lo, hi, dtheta[kk, tt], atlas.beta)
    per_piece = rho.shape[1]
    owner = np.repeat(kk, per_piece)
    th = np.repeat(theta[kk, tt], per_piece)
    cand = np.repeat(_piece_candidates(spans, lo, hi, r, kk, tt, planar, nb), per_piece, axis=0)
    rho = rho.ravel()
    return owner, rho * np.cos(th), rho * np.sin(th), w.ravel(), cand, np.repeat(tt, per_piece)


def rule_rays(atlas, ids: np.ndarray, q: int) -> tuple[np.ndarray, ...]:
    """The 4q rays of each patch's polar rule: angles theta, angular weights dtheta, directions
    (ux, uy) = (cos, sin) theta, and rmax, where each ray leaves the disk or square; all (k, 4q)."""
    n_t = 4 * q
    # each patch's own stable random value (Atlas.random): a patch's rule, so its row of C, does not
    # depend on which other patches (other atlas objects) are integrated with it, or in what order
    rnd = np.asarray(atlas.random, np.float64)[ids]
    r = atlas.radii[ids][:, None]
    square = (atlas.shapes[ids] == SHAPE_SQUARE)[:, None]
    # Disks: equally spaced angles, turned by a random offset per patch so that neighbouring
    # rules share no alignment. Squares: Gauss angles within each quarter between corners,
    # where the distance to the square's side is smooth, so the square's area comes out exact.
    even = 2.0 * np.pi * (np.arange(n_t)[None, :] + rnd[:, None]) / n_t
    gx, gw = _gauss(q)
    quarter = np.arange(n_t) // q
    sq_theta = (-0.25 + 0.5 * quarter + 0.5 * np.tile(gx, 4)) * np.pi
    theta = np.where(square, sq_theta[None, :], even)  # (k, n_t)
    dtheta = np.where(square, 0.5 * np.pi * np.tile(gw, 4)[None, :], 2.0 * np.pi / n_t)
    ux, uy = np.cos(theta), np.sin(theta)
    rmax = np.where(square, r / np.maximum(np.abs(ux), np.abs(uy)), r)  # (k, n_t)
    return theta, dtheta, ux, uy, rmax


def _rim_crossings(
    atlas,
    ids: np.ndarray,
    nb: np.ndarray,
    planar: np.ndarray,
    ux: np.ndarray,
    uy: np.ndarray,
    rmax: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each rule ray (directions ux, uy (k, n_t) in the patch's plane) enters and leaves
    each neighbour nb (k, M): (c_in, c_out, hit), each (k, n_t, M), distances clipped to
    [0, rmax]. hit is False for padding, for rays that miss the neighbour, and off planar sheets
    (rims are exact circles and squares in the plane only there)."""
    t_h = atlas.tangents[ids]
    b_h = atlas.bitangents[ids]
    ok = (nb >= 0) & planar[:, None]
    j = np.maximum(nb, 0)
    rel = atlas.centers[j] - atlas.centers[ids][:, None]
    cx = np.einsum("kmd,kd->km", rel, t_h)[..., None]
    cy = np.einsum("kmd,kd->km", rel, b_h)[..., None]
    rj = atlas.radii[j][..., None]
    uxe, uye = ux[:, None], uy[:, None]  # (k, 1, n_t)
    # disk neighbour: |rho u - c| = r_j
    cu = cx * uxe + cy * uye
    disc = cu * cu - (cx * cx + cy * cy) + rj * rj
    sq = np.sqrt(np.maximum(disc, 0.0))
    d_in, d_out = cu - sq, cu + sq
    # square neighbour: slabs along its own axes, expressed in this patch's plane
    tj = atlas.tangents[j]
    ax = np.einsum("kmd,kd->km", tj, t_h)[..., None]
    ay = np.einsum("kmd,kd->km", tj, b_h)[..., None]
    lo_e, hi_e = [], []
    for a1, a2 in ((ax, ay), (-ay, ax)):
        ua = uxe * a1 + uye * a2
        ca = cx * a1 + cy * a2
        with np.errstate(divide="ignore", invalid="ignore"):
            e1 = (ca - rj) / ua
            e2 = (ca + rj) / ua
        lo_e.append(np.where(ua != 0, np.minimum(e1, e2), -np.inf))
        hi_e.append(np.where(ua != 0, np.maximum(e1, e2), np.inf))
    s_in = np.maximum(lo_e[0], lo_e[1])
    s_out = np.minimum(hi_e[0], hi_e[1])
    is_sq = (atlas.shapes[j] == SHAPE_SQUARE)[..., None]
    c_in = np.where(is_sq, s_in, d_in)
    c_out = np.where(is_sq, s_out, d_out)
    hit = ok[..., None] & np.where(is_sq, s_in < s_out, disc > 0)
    big = rmax[:, None]
    c_in = np.where(hit, np.clip(c_in, 0.0, big), big)
    c_out = np.where(hit, np.clip(c_out, 0.0, big), big)
    return np.moveaxis(c_in, 1, 2), np.moveaxis(c_out, 1, 2), np.moveaxis(hit, 1, 2)


def _radial_points(
    lo: np.ndarray, hi: np.ndarray, dtheta: np.ndarray, beta: str
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss points rho (p, g) and their area weights (p, g) on the radial pieces [lo, hi] (p,)
    of rays with angular weights dtheta (p,)."""
    # alpha is constant on each piece with box beta: one point per piece is exact there
    gx, gw = _gauss(1 if beta == "box" else 2)
    # Gauss points in s = rho^2 (the area coordinate along the ray): integrands polynomial in
    # rho^2, like a smooth field's radial variation, are integrated exactly on each piece.
    s_lo, s_hi = lo * lo, hi * hi
    rho = np.sqrt(s_lo[:, None] + (s_hi - s_lo)[:, None] * gx[None])
    w = dtheta[:, None] * 0.5 * (s_hi - s_lo)[:, None] * gw[None]
    return rho, w


def _piece_candidates(spans, lo, hi, r, kk, tt, planar, nb) -> np.ndarray:
    """(p, M) bool: the neighbours that may contain the pieces [lo, hi] (p,) of rays tt of
    patches kk: on planar sheets those whose rim crossings (spans) hold the piece's middle,
    elsewhere every neighbour."""
    if spans is None:
        return np.zeros((len(kk), 0), bool)
    mid = (0.5 * (lo + hi))[:, None]
    tol = 1e-9 * r[kk]
    c_in, c_out, hit = (a[kk, tt] for a in spans)
    inside = hit & (c_in - tol < mid) & (mid < c_out + tol)
    return np.where(planar[kk][:, None], inside, nb[kk] >= 0)
