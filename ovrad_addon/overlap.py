"""Integrals over patch supports: quadrature points on the surface, the overlap matrix C, alpha at points.

C[h, i] = c_ih = integral over D_h of alpha_i; its row sums are the support areas A_h and its
diagonal the effective areas c_hh. Integration uses a polar rule on each patch's disk or square
(polar_rule: Gauss points on the pieces of each ray between neighbours' rims), with every rule
point moved onto the patch's own sheet along the patch normal (rule points that land nowhere
on the sheet are outside the support and get no weight).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from functools import lru_cache

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.spatial import cKDTree

from .contact import contacts, planar_patches, seen_members, visible
from .geometry import ranges_flat, unique_rows
from .names import SHAPE_BALL, SHAPE_DISK, SHAPE_SQUARE
from .parallel import WORKERS, threaded
from .support import alpha_from_pairs, pair_beta


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


QUADRATURE_CHUNK = 8192  # patches per patch_quadrature pass


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
    theta, dtheta, ux, uy, rmax = _rule_rays(atlas, ids, q)
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


def _rule_rays(atlas, ids: np.ndarray, q: int) -> tuple[np.ndarray, ...]:
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


def patch_quadrature(
    atlas,
    index,
    ids: np.ndarray,
    q: int,
    nb: np.ndarray | None = None,
    rings: int | None = None,
    visibility: bool = True,
) -> Quadrature:
    """Quadrature of the supports D_h for patches `ids`, on the surface, with area weights.

    Rule points are moved onto the patch's own sheet along its normal; points that land on
    another sheet, or nowhere, are outside the support and get weight 0. Where that happens
    (the sheet's border cuts the patch) the rule rays it cuts are split where they cross it
    (support_cuts), so the cut is resolved closely. Ball patches (clutter.py) are integrated
    with samples of the pieces they hold.
    With `visibility`, points a cut patch cannot see along its sheet are outside it (contact.py).
    """
    if nb is None:
        nb = np.zeros((len(ids), 0), np.int64)
    if len(ids) > QUADRATURE_CHUNK:
        # a patch's rule depends on itself and its neighbours only: in chunks, the temporaries of
        # every patch's rays and rule points are never held at once (100 k patches: 2.8 GB at once)
        parts = []
        for s in range(0, len(ids), QUADRATURE_CHUNK):
            sl = slice(s, s + QUADRATURE_CHUNK)
            part = patch_quadrature(atlas, index, ids[sl], q, nb[sl], rings, visibility)
            parts.append(replace(part, owner=part.owner + s))
        return Quadrature(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Quadrature)))
    ball = atlas.shapes[ids] == SHAPE_BALL
    if ball.any():
        return _with_balls(atlas, index, ids, q, nb, rings, ball, visibility)
    if rings is None:
        # coarse rings first. On each rule ray where a point fell off the support (a border, a
        # crease, a contact cuts the patch there), every change between on and off along the ray
        # is found (support_cuts) and the ray split there, so each piece is on or off the support
        # as a whole. Splitting the cut rays into 2q rings instead took 2 300 rule points per
        # patch on the production room's small pieces at 100 k patches (most of its Generate:
        # each point is cast onto the surface and paired with every neighbour)
        coarse, ray, flat = _surface_rule(atlas, index, ids, q, nb, max(q // 4, 1), visibility)
        off = coarse.triangle < 0
        if not off.any():
            return coarse
        cut_rays = np.zeros((len(ids), 4 * q), bool)
        cut_rays[coarse.owner[off], ray[off]] = True
        # rays with a point on the sheet but off the support: a contact or a closed object hides it
        hidden = np.zeros_like(cut_rays)
        hidden[coarse.owner[off & flat], ray[off & flat]] = True
        where = np.flatnonzero(cut_rays.any(axis=1))
        on = cut_rays[coarse.owner, ray]
        cuts = support_cuts(atlas, index, ids[where], q, cut_rays[where], hidden[where], visibility)
        fine = _surface_rule(
            atlas, index, ids[where], q, nb[where], max(q // 4, 1), visibility, cut_rays[where], cuts
        )[0]
        keep = ~on
        return Quadrature(
            owner=np.concatenate([coarse.owner[keep], where[fine.owner]]),
            points=np.concatenate([coarse.points[keep], fine.points]),
            normals=np.concatenate([coarse.normals[keep], fine.normals]),
            weights=np.concatenate([coarse.weights[keep], fine.weights]),
            triangle=np.concatenate([coarse.triangle[keep], fine.triangle]),
            cand=np.concatenate([coarse.cand[keep], fine.cand]),
        )
    return _surface_rule(atlas, index, ids, q, nb, rings, visibility)[0]


BISECTION_STEPS = 4  # a cut along a rule ray found to 1/16 of the distance between two points
# Points per q along a cut rule ray, where support_cuts looks for its changes (strips and gaps
# narrower than their spacing can be missed). Production room at 100 k patches: 2 -> 1 took
# Generate from 89.6 to 81.0 s, error 4.940 -> 4.937 % at every vertex.
CUT_SAMPLES = 1
GRADED = 4  # breaks toward a cut on a curved sheet: at 1, 1/2, 1/4, 1/8 of rmax / 2q from it


def support_cuts(atlas, index, ids, q: int, rays, hidden, visibility) -> np.ndarray:
    """(k, 4q, E) the distances from the centre at which the rule rays `rays` (k, 4q) bool of
    patches ids (k,) cross their support's edge (padded with inf; on curved sheets with GRADED
    breaks beside each), by bisection between two points along a ray, one on and one off, to
    1/2^BISECTION_STEPS of their distance.

    On a planar sheet, a ray that only the sheet's border can cut (not `hidden`) is cut exactly where
    it crosses a border edge of its chart (border_crossings; charts of at most MAX_BORDER border
    edges): the production room at 100 k patches has half its 1.3 M cut rays so, and its C took 55
    instead of 60 s (q = 12). The other rays are sampled: CUT_SAMPLES x q points along the ray
    (equal-area spacing) and its centre and rim, so a strip or a gap wider than their spacing is
    found. Where the sheet ends (its border, a crease, a face turned away) the sheet alone tells
    (one short ray each: _on_surface without the buried and visibility tests); on the rays `hidden`
    (k, 4q) bool, where a point of the coarse rule is on the sheet but off the support (buried,
    hidden by a contact), every test does."""
    theta, _, _, _, rmax = _rule_rays(atlas, ids, q)
    planar = index.planar[index.sheet_chart[atlas.sheet[ids]]]

    def status(k, t, r) -> np.ndarray:
        """(m,) bool: the points at r along rays t of patches k are on the support (every test
        on the hidden rays, the sheet alone elsewhere)."""
        x, y = r * np.cos(theta[k, t]), r * np.sin(theta[k, t])
        full = hidden[k, t]
        out = np.empty(len(r), bool)
        for tests in (False, True):
            a = np.flatnonzero(full == tests)
            out[a] = _on_surface(
                atlas, index, ids[k[a]], x[a], y[a], planar[k[a]], visibility and tests, tests
            )[4]
        return out

    def changes(k, t, r, s):
        """Consecutive points along a ray, one on and one off: (patch, ray, lo, hi, status at lo)."""
        order = np.lexsort((r, t, k))
        k, t, r, s = k[order], t[order], r[order], s[order]
        at = np.flatnonzero((k[1:] == k[:-1]) & (t[1:] == t[:-1]) & (s[1:] != s[:-1]))
        return k[at], t[at], r[at], r[at + 1], s[at]

    kk, tt = np.nonzero(rays)
    # Rays on a planar sheet that only its border cuts (not hidden): where they cross a border edge
    # of their chart, found exactly in the patch's plane (border_crossings) instead of by sampling
    chart = index.sheet_chart[atlas.sheet[ids]]
    start, _, _ = chart_borders(index)
    exact = planar & (start[chart + 1] - start[chart] <= MAX_BORDER) & ~index.sheet_clutter[atlas.sheet[ids]]
    analytic = exact[kk] & ~hidden[kk, tt]
    xk, xt, xr = border_crossings(atlas, index, ids, theta, rmax, kk[analytic], tt[analytic])
    kk, tt = kk[~analytic], tt[~analytic]
    dense = CUT_SAMPLES * q
    frac = np.concatenate([[0.0], np.sqrt((np.arange(dense) + 0.5) / dense), [1.0 - 1e-6]])
    dk, dt = np.repeat(kk, len(frac)), np.repeat(tt, len(frac))
    dr = (rmax[kk, tt][:, None] * frac[None, :]).ravel()
    ck, ct, lo, hi, s_lo = changes(dk, dt, dr, status(dk, dt, dr))
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        same = status(ck, ct, mid) == s_lo
        lo, hi = np.where(same, mid, lo), np.where(same, hi, mid)
    cut = 0.5 * (lo + hi)
    # On a curved sheet the area element 1 / cos grows steeply toward a cut where the surface
    # turns away (a pebble's rim): the piece on the support's side is split toward the cut in
    # halves (GRADED pieces), so two Gauss points each follow it (the production room's curved
    # BoomBox at 100 k patches: mean support error 1.3 -> 0.55 % against a rule of twice the order)
    curved = np.flatnonzero(~planar[ck])
    if len(curved):
        step = np.where(s_lo[curved], -1.0, 1.0)[:, None] * (rmax[ck[curved], ct[curved]] / (2 * q))[:, None]
        graded = cut[curved, None] + step * 0.5 ** np.arange(GRADED)[None, :]
        ck = np.concatenate([ck, np.repeat(ck[curved], GRADED)])
        ct = np.concatenate([ct, np.repeat(ct[curved], GRADED)])
        cut = np.concatenate([cut, np.maximum(graded.ravel(), 0.0)])
    ck, ct, cut = np.concatenate([ck, xk]), np.concatenate([ct, xt]), np.concatenate([cut, xr])
    # each ray's cuts in the slots of a (k, 4q, E) array
    key = ck * rays.shape[1] + ct
    order = np.argsort(key, kind="stable")
    key, cut = key[order], cut[order]
    slot = np.arange(len(key)) - np.searchsorted(key, key)
    out = np.full((*rays.shape, int(slot.max(initial=-1)) + 1), np.inf)
    out[key // rays.shape[1], key % rays.shape[1], slot] = cut
    return out


MAX_BORDER = 256  # planar charts with more border edges than this are cut by sampling (support_cuts)


def chart_borders(index) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each chart's border: its edges that only one of its triangles uses (vertices welded as
    find_charts welds them, Surfaces.welded), as (start (n_charts + 1,), a (E, 3), b (E, 3)): chart c's
    edges run from a to b in rows start[c]:start[c + 1]. Cached on the index."""
    hit = index.cache.get("chart borders")
    if hit is not None:
        return hit
    surfaces, charts = index.surfaces, index.charts
    first, weld = surfaces.welded
    tri = np.flatnonzero(charts.chart >= 0)
    t = weld[surfaces.triangles[tri]]
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    c = np.tile(charts.chart[tri], 3)
    keep = e[:, 0] != e[:, 1]
    edges, uses = unique_rows(np.column_stack([c[keep], e[keep]]), return_counts=True)
    border = edges[uses == 1]  # sorted by chart
    start = np.searchsorted(border[:, 0], np.arange(charts.count + 1))
    at = surfaces.vertices[first]
    out = (start, at[border[:, 1]], at[border[:, 2]])
    index.cache["chart borders"] = out
    return out


def border_crossings(atlas, index, ids, theta, rmax, kk, tt) -> tuple[np.ndarray, ...]:
    """Where the rule rays tt of patches ids[kk] (planar; theta, rmax (k, 4q) from _rule_rays) cross
    a border edge of their chart, in the patch's plane: (patch, ray, distance from the centre) per
    crossing in (0, rmax). On a planar sheet the support ends only there (or where a contact, a
    footprint or a cover hides it: those rays are sampled, support_cuts), so this is the exact set of
    changes sampling would look for. An edge inside the sheet that one triangle alone uses (a
    T-junction, a crack) adds a crossing where nothing changes: a break in a ray's rule, harmless."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(kk) == 0:
        return empty
    start, pa, pb = chart_borders(index)
    # border edges within reach of each patch holding such rays
    patches = np.unique(kk)
    g = ids[patches]
    chart = index.sheet_chart[atlas.sheet[g]]
    count = start[chart + 1] - start[chart]
    owner = np.repeat(np.arange(len(patches)), count)
    edge = ranges_flat(start[chart], count)
    c = atlas.centers[g][owner]
    a, d = pa[edge] - c, pb[edge] - pa[edge]
    s = np.clip(-np.einsum("ij,ij->i", a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    gap = a + s[:, None] * d
    reach = rmax[patches].max(axis=1)[owner]
    near = np.einsum("ij,ij->i", gap, gap) <= reach * reach * (1.0 + 1e-9)
    owner, edge, a, d = owner[near], edge[near], a[near], d[near]
    # segments in each patch's plane coordinates
    t_h, b_h = atlas.tangents[g][owner], atlas.bitangents[g][owner]
    ax, ay = np.einsum("ij,ij->i", a, t_h), np.einsum("ij,ij->i", a, b_h)
    dx, dy = np.einsum("ij,ij->i", d, t_h), np.einsum("ij,ij->i", d, b_h)
    # pair each ray with its patch's near edges
    slot = np.searchsorted(patches, kk)
    per = np.bincount(owner, minlength=len(patches))
    first = np.searchsorted(owner, np.arange(len(patches)))
    n_pairs = per[slot]
    ray = np.repeat(np.arange(len(kk)), n_pairs)
    seg = ranges_flat(first[slot], n_pairs)
    th = theta[kk[ray], tt[ray]]
    ux, uy = np.cos(th), np.sin(th)
    # centre + rho u = a + s d: rho = (a x d) / (u x d), s = (a x u) / (u x d)
    den = ux * dy[seg] - uy * dx[seg]
    ok = np.abs(den) > 1e-12 * np.sqrt(dx[seg] ** 2 + dy[seg] ** 2)
    den = np.where(ok, den, 1.0)
    rho = (ax[seg] * dy[seg] - ay[seg] * dx[seg]) / den
    s = (ax[seg] * uy - ay[seg] * ux) / den
    lim = rmax[kk[ray], tt[ray]]
    # (a crossing at the centre or the rim breaks nothing: a square's side lying on the border)
    ok &= (s >= 0.0) & (s <= 1.0) & (rho > 1e-9 * lim) & (rho < (1.0 - 1e-9) * lim)
    return kk[ray[ok]], tt[ray[ok]], rho[ok]


def _surface_rule(
    atlas, index, ids: np.ndarray, q: int, nb: np.ndarray, rings: int, visibility: bool, rays=None, cuts=None
) -> tuple[Quadrature, np.ndarray, np.ndarray]:
    """patch_quadrature of plain patches with `rings` rings (on the rule rays `rays` (k, 4q) bool
    only, None: all; split at `cuts` too, polar_rule), the rule ray (m,) each point lies on and
    whether it is on the sheet facing its way (m,) (_on_surface)."""
    chart = index.sheet_chart[atlas.sheet[ids]]
    planar = index.planar[chart]
    owner, x, y, w, cand, ray = polar_rule(atlas, ids, nb, q, index.flat[chart], rings, rays, cuts)
    pts, tri_n, tri, jac, ok, flat = _on_surface(atlas, index, ids[owner], x, y, planar[owner], visibility)
    quad = Quadrature(
        owner=owner,
        points=pts,
        normals=tri_n,
        weights=np.where(ok, w * jac, 0.0),
        triangle=np.where(ok, tri, -1),
        cand=cand,
    )
    return quad, ray, flat


def _on_surface(
    atlas,
    index,
    g: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    on_plane: np.ndarray,
    visibility,
    buried_test=True,
):
    """Points (x, y) in the planes of patches g (m,) cast onto their sheet along the normal:
    (points (m, 3), normals on the patch's side (m, 3), triangle (m,), jacobian (m,), on the
    support (m,) bool, on the sheet and facing its way (m,) bool: on the support but for the
    buried and visibility tests). On planar sheets (on_plane) the plane point is already on the
    surface. Without buried_test, points inside closed objects count as on the support."""
    n = atlas.normals[g]
    plane = atlas.centers[g] + x[:, None] * atlas.tangents[g] + y[:, None] * atlas.bitangents[g]
    lift = atlas.thickness[g] * 1.0001
    origins = plane + lift[:, None] * n
    hit_t, tri = index.rays.closest_hit(origins, -n, 2.0002 * atlas.thickness[g])
    side = index.sheet_side[atlas.sheet[g]]
    tri_n = index.charts.normals[np.maximum(tri, 0)] * side[:, None]
    cos = np.einsum("ij,ij->i", tri_n, n)
    ok = (tri >= 0) & (index.sheet_of(tri, side) == atlas.sheet[g]) & (cos >= atlas.min_cos[g])
    hit_t = np.where(np.isfinite(hit_t), hit_t, 0.0)
    pts = np.where(on_plane[:, None], plane, origins - hit_t[:, None] * n)
    jac = np.where(on_plane, 1.0, 1.0 / np.maximum(np.abs(cos), 1e-12))
    flat = ok.copy()
    if buried_test:
        ok[ok] = ~buried(index, pts[ok], tri_n[ok], 1e-4 * atlas.radii[g[ok]])
    if visibility:
        ok[ok] = visible(atlas, index, g[ok], pts[ok])
    return pts, tri_n, tri, jac, ok, flat


def _with_balls(atlas, index, ids, q, nb, rings, ball, visibility) -> Quadrature:
    """patch_quadrature of ids when some are ball patches: their rule from clutter samples (at
    most 8 q^2 points each), the others' as usual, in one Quadrature."""
    from .clutter import ball_quadrature

    parts = []
    where = np.flatnonzero(ball)
    owner, pts, nrm, w, tri = ball_quadrature(atlas, index, ids[where], 8 * q * q)
    cand = nb[where][owner] >= 0  # any same-sheet neighbour may hold a sample
    parts.append(Quadrature(where[owner], pts, nrm, w, tri, cand))
    rest = np.flatnonzero(~ball)
    if len(rest):
        other = patch_quadrature(atlas, index, ids[rest], q, nb[rest], rings, visibility)
        parts.append(replace(other, owner=rest[other.owner]))
    return Quadrature(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Quadrature)))


def buried(index, points: np.ndarray, normals: np.ndarray, lift: np.ndarray) -> np.ndarray:
    """Surface points inside a closed object (a box's footprint on the floor it stands on).

    A ray along the normal that first meets the inside of a watertight mesh started inside it;
    light never reaches such points, so they are no part of any patch's support (else they
    would pull the light of the visible part of the patch down).
    """
    if len(points) == 0:
        return np.zeros(0, bool)
    origins = points + (lift + 1e-7 * index.surfaces.extent)[:, None] * normals
    _, tri = index.rays.closest_hit(origins, normals, np.inf)
    hit = tri >= 0
    chart = index.charts.chart[np.maximum(tri, 0)]
    back = np.einsum("ij,ij->i", index.charts.normals[np.maximum(tri, 0)], normals) > 0
    return hit & back & (chart >= 0) & index.charts.closed[np.maximum(chart, 0)]


def neighbour_pairs(atlas) -> tuple[np.ndarray, np.ndarray]:
    """All (h, i) on the same sheet whose bounding balls intersect, h == i included.

    Searched per sheet (a fourth coordinate keeps sheets apart) with each patch's own reach (its
    bounding radius plus the largest on its sheet): a search radius of the largest patch anywhere
    would pair every small patch of a cluster of small pieces with thousands of others.
    """
    br = atlas.bounding_radii
    n = len(atlas)
    sheet = np.asarray(atlas.sheet, np.int64)
    _, local_sheet = np.unique(sheet, return_inverse=True)
    largest = np.zeros(local_sheet.max() + 1 if n else 0)
    np.maximum.at(largest, local_sheet, br)
    gap = 4.0 * float(br.max()) + 1.0
    pts = np.column_stack([atlas.centers, local_sheet * gap])
    found = cKDTree(pts).query_ball_point(pts, r=br + largest[local_sheet], return_sorted=False)
    counts = np.fromiter((len(f) for f in found), np.int64, n)
    a = np.repeat(np.arange(n), counts)
    b = np.fromiter((j for f in found for j in f), np.int64, int(counts.sum()))
    d = np.linalg.norm(atlas.centers[a] - atlas.centers[b], axis=1)
    keep = (a < b) & (d <= br[a] + br[b]) & (sheet[a] == sheet[b])
    a, b = a[keep], b[keep]
    h = np.concatenate([a, b, np.arange(n)])
    i = np.concatenate([b, a, np.arange(n)])
    order = np.lexsort((i, h))
    return h[order], i[order]


@dataclass(frozen=True)
class RowCopies:
    """Rows of C taken from another patch's: member (k,) patches, rep (k,) the patch whose row each
    copies, and their neighbours in matching order, nb_member and nb_rep (k, c) (one block per
    neighbour count c)."""

    member: np.ndarray
    rep: np.ndarray
    nb_member: np.ndarray
    nb_rep: np.ndarray


KEY_SCALE = 1e6  # configurations equal to 1e-6 of the patch radius are one


def repeated_rows(atlas, index, ph: np.ndarray, pi: np.ndarray, start: np.ndarray) -> list[RowCopies]:
    """Patches whose row of C is another's, found by their neighbourhoods.

    A row C[h, .] = the integrals over D_h of the alpha_i depends on nothing but the disks and
    squares around h when h's support is plain: a disk on a planar sheet, whole (every point of its
    coarse rule on the sheet: no border, footprint or hole in it, contact.Contacts.whole), and no
    contact line cutting it or any patch overlapping it (their memberships are then geometric).
    Two such patches whose neighbours sit at the same offsets in their planes (1e-6 of the radius),
    with the same radii, shapes and square orientations, have the same row up to the rotation of
    the rule. A sheet's patches lie on a regular grid, so most interior patches of large flat faces
    repeat a few configurations: the Cornell box at 25 000 patches has 15 300 plain patches in 1 012
    configurations. Each configuration is integrated once per sheet, on the member with the
    smallest Atlas.random: the choice depends on neither the patches' order nor other sheets, so a
    row stays a function of its own sheet's patches (kept_overlaps.py relies on it).
    """
    n = len(atlas)
    con = contacts(atlas, index)
    plain = np.zeros(n, bool)
    plain[planar_patches(atlas, index)] = True
    uncut = plain & ~con.cut & ~con.covered  # a covered patch's disk may reach past its cover
    ok = uncut & con.whole & (atlas.shapes == SHAPE_DISK)
    other = ph != pi
    ok[ph[other & ~uncut[pi]]] = False  # a neighbour cut by a contact line
    deg = np.diff(start)
    rel = atlas.centers[pi] - atlas.centers[ph]
    r = atlas.radii
    t, b = atlas.tangents, atlas.bitangents
    kx = np.round(np.einsum("ij,ij->i", rel, t[ph]) / r[ph] * KEY_SCALE).astype(np.int64)
    ky = np.round(np.einsum("ij,ij->i", rel, b[ph]) / r[ph] * KEY_SCALE).astype(np.int64)
    kr = np.round(r[pi] / r[ph] * KEY_SCALE).astype(np.int64)
    # a square neighbour's turn in h's plane (a quarter turn is the same square)
    turn = np.arctan2(np.einsum("ij,ij->i", t[pi], b[ph]), np.einsum("ij,ij->i", t[pi], t[ph]))
    square = atlas.shapes[pi] == SHAPE_SQUARE
    ka = np.where(square, np.round(np.mod(turn, 0.5 * np.pi) * KEY_SCALE), -1).astype(np.int64)
    size = np.round(r / max(float(r.max()), 1e-300) * 1e9).astype(np.int64)
    out = []
    for c in np.unique(deg[ok]):
        rows = np.flatnonzero(ok & (deg == c))
        slot = start[rows][:, None] + np.arange(c)[None, :]
        keys = [kx[slot], ky[slot], kr[slot], ka[slot]]
        order = np.lexsort(keys[::-1], axis=1)
        keys = [np.take_along_axis(k, order, axis=1) for k in keys]
        nb = np.take_along_axis(pi[slot], order, axis=1)
        sheet = np.asarray(atlas.sheet, np.int64)[rows]  # a row is copied within its own sheet only
        _, group = unique_rows(np.column_stack([sheet, size[rows], *keys]), return_inverse=True)
        group = group.ravel()
        first = np.lexsort((rows, atlas.random[rows], group))  # by group, smallest random first
        lead = np.empty(group.max() + 1, np.int64)
        lead[group[first[::-1]]] = first[::-1]
        rep = lead[group]
        copy = rep != np.arange(len(rows))
        out.append(RowCopies(rows[copy], rows[rep[copy]], nb[copy], nb[rep[copy]]))
    return out


def overlap_matrix(
    atlas,
    index,
    q: int,
    progress: Callable[[float], None] | None = None,
    chunk_points: int = 1_000_000,
    workers: int = WORKERS,
    rows: np.ndarray | None = None,
    reuse: bool = True,
) -> tuple[csr_matrix, np.ndarray]:
    """C (n x n sparse, C[h, i] = c_ih) and the support areas A_h (n,).

    Row h is integrated on D_h with a rule that depends on patch h and the patches of its sheet
    around it only (never on the other patches' order, or on patches elsewhere), so the rows
    of one atlas object's patches are the same whatever atlases are integrated with it.
    rows: integrate these rows only (the others are empty, their support areas 0).
    Patches go in chunks of about chunk_points rule-point pairs, on `workers` threads
    (parallel.py): 2.0 s instead of 4.1 s for 6 400 patches on 2 cores.
    reuse: a row that repeats another's configuration is copied from it (repeated_rows)."""
    n = len(atlas)
    rows = np.arange(n) if rows is None else np.asarray(rows, np.int64)
    if len(rows) == 0:
        return csr_matrix((n, n)), np.zeros(n)
    ph, pi = neighbour_pairs(atlas)
    start = np.searchsorted(ph, np.arange(n + 1))
    deg = np.diff(start)
    wanted = rows
    copies = []
    if reuse:
        asked = np.zeros(n, bool)
        asked[wanted] = True
        for block in repeated_rows(atlas, index, ph, pi, start):
            keep = asked[block.member]
            if np.any(keep):
                copies.append(
                    RowCopies(block.member[keep], block.rep[keep], block.nb_member[keep], block.nb_rep[keep])
                )
        if copies:
            copied = np.concatenate([c.member for c in copies])
            todo = np.ones(n, bool)
            todo[copied] = False
            rows = np.union1d(wanted[todo[wanted]], np.concatenate([c.rep for c in copies]))
    # rule points per patch grow with its neighbours (rim crossings), and each point is paired
    # with every neighbour of its chunk's widest patch: rows go by degree, in chunks whose pairs
    # stay within budget. (Sized by the atlas's widest patch, the production room's chunks at
    # 100 k patches held 7 patches each: numpy's per-call cost then outweighed the work. By degree,
    # counting rule points only, Generate's peak there was 3.6 GB; with support_cuts' samples
    # counted too, 0.57 GB in the same 91 s.)
    rows = rows[np.argsort(deg[rows], kind="stable")]
    # a patch's pairs: its rule points (and, if cut, up to 4q (CUT_SAMPLES q + 2) support_cuts samples)
    # times its neighbours
    cost = (8 * q * (deg[rows] + q // 4 + 1) + 4 * q * (CUT_SAMPLES * q + 2)) * np.maximum(deg[rows], 2)
    starts = [0]
    while starts[-1] < len(rows):
        a = starts[-1]
        # the patches after a whose cost times the chunk's last (widest) one stays within budget
        span = min(len(rows) - a, chunk_points // int(cost[a]) + 1)
        fit = np.searchsorted(np.arange(1, span + 1) * cost[a : a + span], chunk_points, side="right")
        starts.append(a + max(1, int(fit)))
    bounds = list(zip(starts[:-1], starts[1:], strict=True))

    def chunk(k: int):
        ids = rows[bounds[k][0] : bounds[k][1]]
        lo, hi = start[ids], start[ids + 1]
        m = int((hi - lo).max())
        slot = np.arange(m)[None, :]
        nb = np.where(slot < (hi - lo)[:, None], pi[np.minimum(lo[:, None] + slot, len(pi) - 1)], -1)
        nb = np.where(nb == ids[:, None], -1, nb)
        quad = patch_quadrature(atlas, index, ids, q, nb)
        area = np.bincount(quad.owner, weights=quad.weights, minlength=len(ids))
        # Pair every rule point with its own patch and the neighbours that may contain it.
        pt, slot = np.nonzero(quad.cand)
        prow = np.concatenate([np.arange(len(quad.owner)), pt])
        pcol = np.concatenate([ids[quad.owner], nb[quad.owner[pt], slot]])
        sheets = np.where(quad.triangle >= 0, atlas.sheet[ids[quad.owner]], -1)
        at = np.take(quad.points, prow, axis=0)
        member, b = pair_beta(atlas, pcol, at, np.take(quad.normals, prow, axis=0), sheets[prow], atlas.beta)
        member = seen_members(atlas, index, prow, pcol, at, member)
        alpha = alpha_from_pairs(prow, pcol, member, b, (len(quad.owner), n)).tocoo()
        # Sum per (h, i) within the chunk: what is kept is then the size of C, not of the rule.
        part = (
            coo_matrix(
                (alpha.data * quad.weights[alpha.row], (quad.owner[alpha.row], alpha.col)),
                shape=(len(ids), n),
            )
            .tocsr()
            .tocoo()
        )
        return ids, area, ids[part.row], part.col, part.data

    r_all, c_all, v_all = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros(0)]
    support = np.zeros(n)
    done = 0
    for ids, area, r, c, v in threaded(chunk, len(bounds), workers):
        support[ids] = area
        r_all.append(r)
        c_all.append(c)
        v_all.append(v)
        done += len(ids)
        if progress is not None:
            progress(min(1.0, done / max(len(rows), 1)))
    C = coo_matrix((np.concatenate(v_all), (np.concatenate(r_all), np.concatenate(c_all))), shape=(n, n))
    C = C.tocsr()
    if copies:
        C, support = _with_copies(C, support, copies, wanted)
    C.eliminate_zeros()
    return C, support


def _with_copies(C: csr_matrix, support: np.ndarray, copies: list[RowCopies], wanted: np.ndarray):
    """C and support with the copied rows filled from their representatives', and only the
    `wanted` rows kept (a representative integrated for others only is dropped)."""
    n = C.shape[0]
    support = support.copy()
    keep = np.zeros(n, bool)
    keep[wanted] = True
    base = C.tocoo()
    on = keep[base.row]
    r_all, c_all, v_all = [base.row[on]], [base.col[on]], [base.data[on]]
    for block in copies:
        k, c = block.nb_member.shape
        vals = np.asarray(C[np.repeat(block.rep, c), block.nb_rep.ravel()]).ravel()
        r_all.append(np.repeat(block.member, c))
        c_all.append(block.nb_member.ravel())
        v_all.append(vals)
        support[block.member] = support[block.rep]
    support[~keep] = 0.0
    out = coo_matrix((np.concatenate(v_all), (np.concatenate(r_all), np.concatenate(c_all))), shape=(n, n))
    return out.tocsr(), support


def alpha_at(atlas, index, points: np.ndarray, triangle: np.ndarray, side) -> csr_matrix:
    """alpha_i at surface points (m x n sparse): points (m, 3) on `triangle` (m,), seen from side (m,) +-1."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    tri = np.asarray(triangle, np.int64)
    side = np.broadcast_to(np.asarray(side), tri.shape)
    sheets = index.sheet_of(tri, side)
    nrm = np.take(index.charts.normals, np.maximum(tri, 0), axis=0) * np.where(side < 0, -1.0, 1.0)[:, None]
    rows, cols = atlas.grid.candidates(pts, sheets)
    at = np.take(pts, rows, axis=0)
    member, b = pair_beta(atlas, cols, at, np.take(nrm, rows, axis=0), None, atlas.beta)
    member = seen_members(atlas, index, rows, cols, at, member)
    return alpha_from_pairs(rows, cols, member, b, (len(pts), len(atlas)))


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
    and the final gather look alpha up (alpha_at), on the side they arrive at."""
    t, tri = index.rays.closest_hit(origins, directions, np.inf)
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


def support_points(atlas, index, q: int, rings: int, ids: np.ndarray | None = None) -> Quadrature:
    """A coarse rule (q, rings) on every patch's support, its points on the support only (weight
    > 0; owner: the patch; no neighbour slots). A patch much larger than its support (a disk on a
    leaf a fifth of its size, a square on a small cube's face) may have no coarse point on it: its
    rings are made FINER_RINGS times finer until some are (up to MAX_RINGS), as C's rule found it.
    Without points a patch got no transport receivers, so no light, and none of the per-patch
    means (emission, albedo): 1 365 of the production room's 9 478 patches at a target of 8 000
    had none, and its leaves baked 11 % too dark. ids: only these patches (owner still indexes the
    atlas); all by default."""
    ids = np.arange(len(atlas)) if ids is None else np.asarray(ids, np.int64)
    first = _on_support(patch_quadrature(atlas, index, ids, q, rings=rings))
    parts = [replace(first, owner=ids[first.owner])]
    missing = np.zeros(len(atlas), bool)
    missing[ids] = atlas.support_area[ids] > 0
    missing[parts[0].owner] = False
    while np.any(missing) and rings < MAX_RINGS:
        rings *= FINER_RINGS
        where = np.flatnonzero(missing)
        finer = _on_support(patch_quadrature(atlas, index, where, q, rings=rings))
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


def patch_average(atlas, index, per_triangle: np.ndarray, q: int = 4) -> np.ndarray:
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
    quad = support_points(atlas, index, q, max(q // 2, 1), ids)
    w = quad.weights
    np.add.at(out, quad.owner, vals[quad.triangle] * w[:, None])
    area = np.bincount(quad.owner, weights=w, minlength=len(atlas))
    return out / np.maximum(area, 1e-300)[:, None]
