"""Clusters of patches for the far transport: a ray that lands far away links to a cell of patches.

A transport ray from a receiver point that lands at distance t on surface inside a cell of side L,
with sqrt(3) L <= far t, sees that cell under a small angle: the rays landing in it are spread
over it nearly as its area is (the density varies by O(far) across it). The light they bring
back is then the cell's mean radiosity, sum_k P[c, k] B_k with P[c, k] the share of alpha_k's
integral that lies in the cell, instead of alpha_k at every hit. That is hierarchical
radiosity's link to a cluster (Hanrahan, Salzman, Aupperle 1991) on the ray-cast transport: the
hit needs a cell key, not the alpha lookup (candidates, membership, beta, normalisation), and a
row of G holds one entry per cluster it sees far away instead of one per patch.

Cells are the sheets' own lookup grids (atlas.lookup.PatchGrid) coarsened by powers of two, from
FIRST_LEVEL (cells about two patch radii wide) up to one cell per sheet, and split by the
direction of the surface normal (NORMAL_BINS per cube face), so a cluster never mixes the two
faces of a crease or both sides of a thin object, whose light differs and which rays see at
different angles; and by cover (overlap.sight.Contacts.covered): the ceiling over a lamp hung
under it, ~30 times brighter than the ceiling beside it, is a cluster of its own, else every far
ray landing next to the lamp would bring back a share of the light trapped over it (the
production room at 100 000 patches: +7 % on its walls). Each hit takes the coarsest level that is far enough.

Energy is conserved exactly: every row of P sums to 1, so a row of G closes as with alpha (the
furnace stays exact), and a uniform radiosity is reproduced exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csc_matrix, diags, vstack

from ..atlas.lookup import PatchGrid
from ..geometry import unique_rows
from ..overlap.sight import COVER, geometry_over

FIRST_LEVEL = 2  # 4 lookup cells: about two patch radii (atlas.lookup.CELLS_PER_RADIUS)

NORMAL_BINS = 3  # per cube face: normals within one cluster differ by at most ~40 degrees

SQRT3 = np.sqrt(3.0)


def normal_bin(normals: np.ndarray) -> np.ndarray:
    """(m,) bin of each unit normal: its cube face (6) and a NORMAL_BINS^2 grid on that face."""
    a = np.abs(normals)
    axis = np.argmax(a, axis=1)
    rows = np.arange(len(normals))
    major = np.maximum(a[rows, axis], 1e-300)
    face = 2 * axis + (normals[rows, axis] < 0)
    u = normals[rows, (axis + 1) % 3] / major
    v = normals[rows, (axis + 2) % 3] / major
    iu = np.clip(np.floor((u + 1.0) * 0.5 * NORMAL_BINS), 0, NORMAL_BINS - 1).astype(np.int64)
    iv = np.clip(np.floor((v + 1.0) * 0.5 * NORMAL_BINS), 0, NORMAL_BINS - 1).astype(np.int64)
    return (face * NORMAL_BINS + iu) * NORMAL_BINS + iv


BINS = 6 * NORMAL_BINS * NORMAL_BINS


@dataclass(frozen=True)
class Clusters:
    """grid: the patch lookup's (atlas.lookup.PatchGrid), whose cells are the finest level; top (S,)
    the level at which a sheet is one cell; keys[l] the sorted cell keys of level FIRST_LEVEL + l
    that hold surface, first (levels + 1,) their column offsets; push (clusters x n, csc) the
    mean-radiosity weights P; far the link criterion (cell diagonal over distance)."""

    grid: PatchGrid
    top: np.ndarray
    keys: list
    first: np.ndarray
    push: csc_matrix
    far: float
    reach: np.ndarray | None = None  # per sheet: how close a cover over a hit must be (its patches' radius)

    @classmethod
    def build(cls, atlas, points, far: float, covered: np.ndarray | None = None) -> Clusters:
        """Clusters over an atlas from its receiver points (radiosity.transport.ReceiverPoints: owner,
        points, normals on the patch's side, area weights summing to each support area);
        covered (n,) bool: the patches under a cover (overlap.sight.Contacts.covered), clustered apart.

        P[c, k] is c_kk (alpha_k's integral, the atlas's effective area) times the share of D_k's
        area that lies in cell c, normalised so each row sums to 1."""
        grid = atlas.grid
        dims = grid.dims
        # the level at which (dims - 1) >> level is 0 on every axis: one cell holds the sheet
        top = np.ceil(np.log2(np.max(dims - 1, axis=1) + 1.0)).astype(np.int64)
        top = np.maximum(top, FIRST_LEVEL)
        n = len(atlas)
        mass = np.asarray(atlas.effective_area, np.float64)
        if not np.all(mass > 0):
            mass = np.asarray(atlas.support_area, np.float64)
        area = np.bincount(points.owner, weights=points.weight, minlength=n)
        w = points.weight * (mass / np.maximum(area, 1e-300))[points.owner]
        sheets = np.asarray(atlas.sheet, np.int64)[points.owner]
        ijk, ok = grid.cells(points.points, sheets)
        cov = np.zeros(n, bool) if covered is None else np.asarray(covered, bool)
        bins = 2 * normal_bin(points.normals) + cov[points.owner]
        # the first level from the points; each coarser one from the cells of the level below
        # (one representative point per cell: cells nest), so every level after the first
        # costs what its cells do, not what the points do
        use = np.flatnonzero(ok)
        key = _key(dims, sheets[use], ijk[use], bins[use], FIRST_LEVEL)
        uniq, rep, col = np.unique(key, return_index=True, return_inverse=True)
        mass_of = coo_matrix((w[use], (col.ravel(), points.owner[use])), shape=(len(uniq), n)).tocsr()
        at = use[rep]  # a point of each cell: its sheet, finest cell and normal bin
        keys, blocks, first = [], [], [0]
        for level in range(FIRST_LEVEL, int(top.max(initial=FIRST_LEVEL)) + 1):
            if level > FIRST_LEVEL:
                alive = top[sheets[at]] >= level  # sheets already one cell stop at their top
                key = _key(dims, sheets[at[alive]], ijk[at[alive]], bins[at[alive]], level)
                uniq, rep, col = np.unique(key, return_index=True, return_inverse=True)
                k = len(col)
                parent = coo_matrix((np.ones(k), (col.ravel(), np.arange(k))), (len(uniq), k))
                mass_of = (parent @ mass_of[alive]).tocsr()
                at = at[alive][rep]
            mass_of.sum_duplicates()
            total = np.asarray(mass_of.sum(axis=1)).ravel()
            keys.append(uniq)
            blocks.append(diags(1.0 / np.maximum(total, 1e-300)) @ mass_of)
            first.append(first[-1] + len(uniq))
        push = vstack(blocks).tocsc() if blocks else csc_matrix((0, n))
        reach = None
        if cov.any():
            reach = np.zeros(len(grid.cell))
            radii = np.asarray(atlas.radii, np.float64)
            np.maximum.at(reach, np.asarray(atlas.sheet, np.int64), COVER * radii)
        return cls(grid, top, keys, np.asarray(first, np.int64), push, float(far), reach)

    @property
    def count(self) -> int:
        return int(self.first[-1])

    def columns(self, points, sheets, normals, distance, rays=None) -> tuple[np.ndarray, np.ndarray]:
        """(far (k,) hit rows that link to a cluster, their cluster columns (k,)): hits at
        points (m, 3) on sheets (m,), normals (m, 3) facing the ray, at distance (m,) from where
        it left. A hit too near for the first level, off every grid, or on a cell no receiver
        point lies in stays with alpha (not in far). A hit in a cell that holds both covered and
        open patches is told which it is by a short ray along its normal (rays); without rays it
        stays with alpha."""
        sheets = np.asarray(sheets, np.int64)
        ok = (sheets >= 0) & (sheets < len(self.grid.cell))
        s = np.where(ok, sheets, 0)
        with np.errstate(divide="ignore"):
            want = np.floor(np.log2(self.far * np.asarray(distance) / (SQRT3 * self.grid.cell[s])))
        at = np.flatnonzero(ok & (want >= FIRST_LEVEL))  # far enough for some level
        s = s[at]
        ijk, inside = self.grid.cells(np.take(points, at, axis=0), s)
        at, s, ijk = at[inside], s[inside], ijk[inside]
        bins = 2 * normal_bin(np.take(normals, at, axis=0))
        level = np.minimum(want[at], self.top[s]).astype(np.int64)
        pts = np.take(points, at, axis=0)
        # one pass per level present, the hits sorted by level (stable: in their order within it)
        order = np.argsort(level, kind="stable")
        lev = level[order]
        starts = np.concatenate([[0], np.flatnonzero(np.diff(lev)) + 1])
        rows, cols = [], []
        for a, b in zip(starts, [*starts[1:], len(lev)], strict=True):
            if a == b:
                continue  # no hit far enough
            group, lv = order[a:b], int(lev[a])
            table = self.keys[lv - FIRST_LEVEL]
            open_key = _key(self.grid.dims, s[group], ijk[group], bins[group], lv)
            has_open, has_covered = _has(table, open_key), _has(table, open_key + 1)
            # a cell of covered patches only, or of open ones only, is what a hit there reads
            key = np.where(has_covered & ~has_open, open_key + 1, open_key)
            both = np.flatnonzero(has_open & has_covered)
            if len(both):
                if rays is None or self.reach is None:
                    key[both] = -1
                else:
                    g, reach = group[both], self.reach[s[group[both]]]
                    key[both] += geometry_over(rays, pts[g], np.asarray(normals)[at[g]], 1e-3 * reach, reach)
            pos = np.minimum(np.searchsorted(table, key), max(len(table) - 1, 0))
            found = table[pos] == key if len(table) else np.zeros(len(group), bool)
            rows.append(at[group[found]])
            cols.append(self.first[lv - FIRST_LEVEL] + pos[found])
        if not rows:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        return np.concatenate(rows), np.concatenate(cols)


def _has(table: np.ndarray, key: np.ndarray) -> np.ndarray:
    """(m,) bool: each key is in the sorted table."""
    if len(table) == 0:
        return np.zeros(len(key), bool)
    pos = np.minimum(np.searchsorted(table, key), len(table) - 1)
    return table[pos] == key


def _key(dims, sheets, ijk, bins, level: int) -> np.ndarray:
    """Keys of cells at `level` (the finest grid's cells merged 2^level to a side) with the normal
    bin: unique over sheets, since each sheet's cells get their own range."""
    d = ((dims - 1) >> level) + 1
    size = np.prod(d, axis=1)
    offset = np.concatenate([[0], np.cumsum(size)[:-1]])
    c = ijk >> level
    dd = d[sheets]
    lin = offset[sheets] + c[:, 0] + dd[:, 0] * (c[:, 1] + dd[:, 1] * c[:, 2])
    return lin * (2 * BINS) + bins  # bins: 2 x the normal's bin + covered


def pooled_fraction(atlas, escaped: np.ndarray, cast: np.ndarray, want: int) -> np.ndarray:
    """(n,) each patch's escaped share of its rays, pooled over the cell of patches around it
    where it cast fewer than `want` rays itself: the smallest cube of a grid over the scene
    (side twice the smallest such patch's radius, doubled level by level) that holds its centre
    and, among patches facing its way (normal_bin), cast at least `want` rays between them. NaN
    where even the whole scene's patches facing its way cast fewer.

    At 100 000 patches each casts some 70 transport rays: too few to tell whether it sees the
    sky, and a test of SKY_TEST_RAYS rays from each would cost more than the transport
    (radiosity.transport._sky_test). Its neighbours facing the same way share most of its view; a patch
    none of whose cell's `want` rays escaped sees, on the cell's average, under about 1 / want of
    sky. A patch whose own rays escaped is in a cell whose did: it keeps the sky. The grid is the
    scene's, not each sheet's: clutter of many small pieces (a sheet each) casts too few rays per
    sheet to tell."""
    n = len(escaped)
    cast = np.asarray(cast, np.float64)
    escaped = np.asarray(escaped, np.float64)
    fraction = np.where(cast >= want, escaped / np.maximum(cast, 1.0), np.nan)
    use = np.flatnonzero(cast > 0)
    if n == 0 or not np.isnan(fraction[use]).any():
        return fraction
    centers = np.asarray(atlas.centers, np.float64)[use]
    lo = centers.min(axis=0)
    extent = float(np.max(centers.max(axis=0) - lo))
    radii = np.asarray(atlas.radii, np.float64)[use]
    short = np.isnan(fraction[use])
    h = max(2.0 * float(radii[short].min()), extent * 2.0**-20, 1e-12)
    bins = normal_bin(np.asarray(atlas.normals, np.float64)[use])
    while True:
        ijk = np.floor((centers - lo) / h).astype(np.int64)
        uniq, col = unique_rows(np.column_stack([ijk, bins]), return_inverse=True)
        col = col.ravel()
        rays = np.bincount(col, weights=cast[use], minlength=len(uniq))
        out = np.bincount(col, weights=escaped[use], minlength=len(uniq))
        fill = short & (rays[col] >= want)
        fraction[use[fill]] = out[col[fill]] / rays[col[fill]]
        short &= ~fill
        if not short.any() or not ijk.any():  # one cell holds them all
            return fraction
        h *= 2.0
