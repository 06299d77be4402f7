"""Values kept at the nodes of a regular lattice over each triangle side, filled on demand and read
by linear interpolation (LatticeValues), and the barycentric frames they are read in (TriangleFrames)."""

from __future__ import annotations

import threading

import numpy as np


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
        side = self.side_index(triangles, sides)
        n = np.take(self.divisions, side)
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
        base = self._base(side)
        first = base + i0 * (2 * n + 3 - i0) // 2 + j0  # (i0, j0)
        node = np.empty((len(n), 3), np.int64)
        node[:, 1] = base + (i0 + 1) * (2 * n + 2 - i0) // 2 + j0  # (i0 + 1, j0)
        node[:, 2] = first + 1  # (i0, j0 + 1)
        node[:, 0] = np.where(upper, node[:, 1] + 1, first)  # (i0 + 1, j0 + 1) or (i0, j0)
        rows = self._rows(node, triangles, sides, i0, j0, upper, n)
        return np.matmul(weight[:, None, :], rows)[:, 0]

    def side_index(self, triangles, sides) -> np.ndarray:
        """(k,) the flat index of each (back, triangle) side into divisions and base (2, T)."""
        return np.asarray(triangles, np.int64) + self.divisions.shape[1] * (np.asarray(sides) < 0)

    def _base(self, side) -> np.ndarray:
        """First slot of each side's nodes (k,) (side: side_index()), given out when a side is first
        asked: only the sides hits land on hold slots (a wall's lattice at 100 k patches has
        thousands of nodes)."""
        base = np.take(self.base, side)
        if np.any(base < 0):
            with self.lock:
                new = np.unique(side[base < 0])
                new = new[np.take(self.base, new) < 0]
                n = np.take(self.divisions, new)
                count = (n + 1) * (n + 2) // 2
                if self.used + count.sum() > len(self.slot):
                    grown = np.full(max(2 * len(self.slot), self.used + int(count.sum())), -1, np.int64)
                    grown[: len(self.slot)] = self.slot
                    self.slot = grown
                self.base.flat[new] = self.used + np.cumsum(count) - count
                self.used += int(count.sum())
            base = np.take(self.base, side)
        return base

    def _rows(self, node, triangles, sides, i0, j0, upper, n) -> np.ndarray:
        slot = np.take(self.slot, node)
        need = slot < 0
        if np.any(need):
            # each node once, asked by any of its hits: they all give it the same (i, j), so an
            # unstable sort serves (np.unique's return_index sorts stably, at twice the cost)
            asked = node[need]
            order = np.argsort(asked)
            asked = asked[order]
            head = np.flatnonzero(np.r_[True, asked[1:] != asked[:-1]])
            new = asked[head]
            k, c = np.nonzero(need)
            first = order[head]
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
            slot = np.take(self.slot, node)
        return np.take(self.rows, slot, axis=0).astype(np.float64, copy=False)


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
