"""Rule points moved onto the patch's own sheet, and rule rays split where the support ends: at a
planar chart's border edges exactly (border_crossings), elsewhere by sampling and bisection."""

from __future__ import annotations

import numpy as np

from ..atlas.index import buried
from ..geometry import ranges_flat
from .rule import Quadrature, polar_rule, rule_rays
from .sight import visible

BISECTION_STEPS = 4  # a cut along a rule ray found to 1/16 of the distance between two points

# Points per q along a cut rule ray, where support_cuts looks for its changes (strips and gaps
# narrower than their spacing can be missed). Production room at 100 k patches: 1 point per q
# generates in 81.0 s against 89.6 s with 2, at the same error (4.937 against 4.940 % at every vertex).
CUT_SAMPLES = 1

# Points are cast onto a patch's sheet from this many times its thickness above its plane, across twice that
THICKNESS_LIFT = 1.0001

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
    theta, _, _, _, rmax = rule_rays(atlas, ids, q)
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
                atlas, index, ids[k[a]], x[a], y[a], planar[k[a]], visibility if tests else None, tests
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
    start, _, _ = index.chart_borders
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


def border_crossings(atlas, index, ids, theta, rmax, kk, tt) -> tuple[np.ndarray, ...]:
    """Where the rule rays tt of patches ids[kk] (planar; theta, rmax (k, 4q) from rule_rays) cross
    a border edge of their chart, in the patch's plane: (patch, ray, distance from the centre) per
    crossing in (0, rmax). On a planar sheet the support ends only there (or where a contact, a
    footprint or a cover hides it: those rays are sampled, support_cuts), so this is the exact set of
    changes sampling would look for. An edge inside the sheet that one triangle alone uses (a
    T-junction, a crack) adds a crossing where nothing changes: a break in a ray's rule, harmless."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    if len(kk) == 0:
        return empty
    start, pa, pb = index.chart_borders
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


def surface_rule(
    atlas, index, ids: np.ndarray, q: int, nb: np.ndarray, rings: int, visibility, rays=None, cuts=None
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
    lift = atlas.thickness[g] * THICKNESS_LIFT
    origins = plane + lift[:, None] * n
    hit_t, tri = index.rays.closest_hit(origins, -n, 2.0 * THICKNESS_LIFT * atlas.thickness[g])
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
    if visibility is not None:
        ok[ok] = visible(visibility, atlas, index, g[ok], pts[ok])
    return pts, tri_n, tri, jac, ok, flat
