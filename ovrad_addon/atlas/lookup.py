"""Which patches may contain a surface point: a uniform grid per sheet, hashed into one sorted key table.

alpha at a point needs every patch covering it. A patch can only cover points of its own sheet,
near its plane and within its bounding ball, so each patch is registered in the cells of its
sheet's grid that meet both its ball and the slab |n . (x - c)| <= thickness around its plane.
A point then looks up its sheet's cell (one read of a table from cell to key where the grids
hold at most DIRECT_CELLS cells in all, else one binary search in the sorted keys) and gets a
short list of same-sheet candidates. Cells are half a typical bounding radius wide (per sheet, so a
finely patched object next to a coarse one gets its own cell size): a point meets about three
candidates where a nearest-centres query meets eight, and only same-sheet ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .support import RIM_TOLERANCE

CELLS_PER_RADIUS = 2.0

_MAX_ENTRIES = 1 << 22  # cell-patch tests per build step, bounding temporary memory

# Grids of at most this many cells in all (every sheet's box) also get a table from cell to key
# position (4 bytes a cell): a lookup is then one gather instead of a binary search over the keys
DIRECT_CELLS = 1 << 22


@dataclass(frozen=True)
class PatchGrid:
    """origin (S, 3), cell (S,), dims (S, 3) and key offset (S,) per sheet; sorted unique cell keys
    (K,), start (K + 1,) into patches: the patches registered in each cell (ascending). direct:
    each cell's position in keys (-1: no patch), for grids of at most DIRECT_CELLS cells; else None."""

    origin: np.ndarray
    cell: np.ndarray
    dims: np.ndarray
    offset: np.ndarray
    keys: np.ndarray
    start: np.ndarray
    patches: np.ndarray
    direct: np.ndarray | None = None

    @classmethod
    def build(cls, atlas, cells_per_radius: float = CELLS_PER_RADIUS) -> PatchGrid:
        n = len(atlas)
        sheet = np.asarray(atlas.sheet, np.int64)
        S = int(sheet.max()) + 1 if n else 0
        br = atlas.bounding_radii * (1.0 + 10.0 * RIM_TOLERANCE)  # rim points count as inside
        c = atlas.centers
        # per sheet, without a loop over sheets: the median bounding radius (patches sorted by
        # sheet, then radius) sets the cell size, and the patches' boxes set the grid's extent
        order = np.lexsort((br, sheet))
        count = np.bincount(sheet, minlength=S)
        first = np.concatenate([[0], np.cumsum(count)[:-1]])
        has = count > 0
        mid = br[order][first[has] + (count[has] - 1) // 2] + br[order][first[has] + count[has] // 2]
        cell = np.ones(S)
        cell[has] = np.maximum(0.5 * mid / cells_per_radius, 1e-300)
        lo = np.full((S, 3), np.inf)
        hi = np.full((S, 3), -np.inf)
        np.minimum.at(lo, sheet, c - br[:, None])
        np.maximum.at(hi, sheet, c + br[:, None])
        origin = np.where(has[:, None], lo - 0.5 * cell[:, None], 0.0)
        dims = np.where(has[:, None], np.floor((hi - origin) / cell[:, None]) + 2, 1).astype(np.int64)
        size = np.prod(dims, axis=1)
        offset = np.concatenate([[0], np.cumsum(size)[:-1]]).astype(np.int64)
        keys, owners = [], []
        # cells of each patch's box, tested against its ball and its plane slab. The box holds
        # the disk of radius br in the patch's plane thickened by the slab: along axis a it
        # reaches br sqrt(1 - n_a^2) + thickness |n_a| (at most br: a ball patch's own ball), so a
        # wall's patch spans one or two cells across its plane instead of its diameter's worth
        na = np.abs(atlas.normals)
        reach = np.minimum(
            br[:, None],
            br[:, None] * np.sqrt(np.clip(1.0 - na * na, 0.0, 1.0)) + atlas.thickness[:, None] * na,
        )
        lo = np.floor((c - reach - origin[sheet]) / cell[sheet, None]).astype(np.int64)
        hi = np.floor((c + reach - origin[sheet]) / cell[sheet, None]).astype(np.int64)
        ext = hi - lo + 1
        count = np.prod(ext, axis=1)
        bounds = np.searchsorted(np.cumsum(count), np.arange(0, int(count.sum()), _MAX_ENTRIES), "right")
        for a, b in zip(bounds, list(bounds[1:]) + [n], strict=True):
            if a >= b:
                continue
            ids = np.arange(a, b)
            cnt = count[ids]
            p = np.repeat(ids, cnt)
            local = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
            e = ext[p]
            plane = e[:, 0] * e[:, 1]
            ijk = lo[p] + np.stack([local % e[:, 0], (local // e[:, 0]) % e[:, 1], local // plane], 1)
            s = sheet[p]
            h = cell[s]
            box_lo = origin[s] + ijk * h[:, None]
            near = c[p] - np.clip(c[p], box_lo, box_lo + h[:, None])
            ball = np.einsum("ij,ij->i", near, near) <= br[p] ** 2
            nrm = atlas.normals[p]
            mid = box_lo + 0.5 * h[:, None] - c[p]
            slab = np.abs(np.einsum("ij,ij->i", mid, nrm)) <= atlas.thickness[p] + 0.5 * h * np.abs(nrm).sum(
                axis=1
            )
            keep = ball & slab
            ijk, s = ijk[keep], s[keep]
            d = dims[s]
            keys.append(offset[s] + ijk[:, 0] + d[:, 0] * (ijk[:, 1] + d[:, 1] * ijk[:, 2]))
            owners.append(p[keep])
        key = np.concatenate(keys) if keys else np.zeros(0, np.int64)
        owner = np.concatenate(owners) if owners else np.zeros(0, np.int64)
        order = np.argsort(key, kind="stable")
        key, owner = key[order], owner[order]
        uniq, first = np.unique(key, return_index=True)
        start = np.concatenate([first, [len(key)]]).astype(np.int64)
        total = int(size.sum()) if S else 0
        direct = None
        if total <= DIRECT_CELLS:
            direct = np.full(total, -1, np.int32)
            direct[uniq] = np.arange(len(uniq), dtype=np.int32)
        return cls(origin, cell, dims, offset, uniq, start, owner, direct)

    def cells(self, points: np.ndarray, sheets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integer cell (m, 3) of each point in its sheet's grid (0 where it is not in it), and
        whether it is (m,) bool; sheets (m,) must be valid sheet indices."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        ijk = np.floor((pts - np.take(self.origin, sheets, axis=0)) / np.take(self.cell, sheets)[:, None])
        inside = np.all((ijk >= 0) & (ijk < np.take(self.dims, sheets, axis=0)), axis=1)
        return np.where(inside[:, None], ijk, 0).astype(np.int64), inside

    def candidates(self, points: np.ndarray, sheets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, patch) pairs: the patches of each point's sheet registered in its cell."""
        sheets = np.asarray(sheets, np.int64)
        ok = (sheets >= 0) & (sheets < len(self.cell))
        s = np.where(ok, sheets, 0)
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        ijk = np.floor((pts - np.take(self.origin, s, axis=0)) / np.take(self.cell, s)[:, None])
        d = np.take(self.dims, s, axis=0)
        ok &= np.all((ijk >= 0) & (ijk < d), axis=1)
        ijk = np.where(ok[:, None], ijk, 0).astype(np.int64)  # where not ok: its sheet's first cell
        key = np.take(self.offset, s) + ijk[:, 0] + d[:, 0] * (ijk[:, 1] + d[:, 1] * ijk[:, 2])
        if self.direct is not None:
            pos = np.take(self.direct, key)
            ok &= pos >= 0
        else:
            pos = np.minimum(np.searchsorted(self.keys, key), max(len(self.keys) - 1, 0))
            if len(self.keys):
                ok &= self.keys[pos] == key
            else:
                ok[:] = False
        rows = np.flatnonzero(ok)
        first = self.start[pos[rows]]
        cnt = self.start[pos[rows] + 1] - first
        total = int(cnt.sum())
        r = np.repeat(rows, cnt)
        at = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(first, cnt)
        return r, np.take(self.patches, at)
