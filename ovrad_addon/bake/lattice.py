"""What gather hits read off the patches: alpha-weighted patch values (and a near hit's direct
light) on a lattice over each triangle, filled on demand and interpolated; the near-field policy."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from ..geometry import tangent_frame
from ..light.direct import DirectLight, direct_irradiance
from ..light.lamps import shadow_origin
from ..overlap.queries import alpha_at, ray_hits

INSIDE = 2e-5  # origins step this far (x scene extent) into their triangle, at most halfway to its centroid

CORNER_ALPHA = 0.25  # hits read the patches from a lattice this x the smallest radius fine (CornerCache)


@dataclass(frozen=True)
class NearField:
    """How hits closer than `reach` x the local patch radius are evaluated: the direct light of
    `light` computed at the hit, plus from the patches (n, 3 each) `indirect` (the solved radiosity
    less its first shot and emission: the light that came by way of other surfaces) and `extra` (the
    emission the far hits count too: emitters the bake points do not sample as direct light).
    sky_seen (n,) bool: the patches whose near hits cast sky rays (radiosity.emission.sky_patches); None:
    every one, if the light has a sky. corner_size: a hit on a triangle whose longest edge is at
    most this x the hit's distance (with 256 gather rays; x sqrt(256 / rays) with others) takes its
    direct light from the triangle's corners (CornerCache); 0: every near hit casts shadow rays.
    second_rays: the light that came by way of other surfaces is, instead of the patches' `indirect`,
    the hit's reflectance x the irradiance a second gather of this many rays finds at the nodes of
    a lattice over the hit's triangle (CornerCache), reading the patches where those rays land: a
    patch's indirect light is its mean over its support, brighter than the light in a concave
    corner or under clutter; 0: the patches' indirect light."""

    light: DirectLight
    indirect: np.ndarray
    extra: np.ndarray
    reach: float = 1.0
    sky_seen: np.ndarray | None = None
    corner_size: float = 0.25
    second_rays: int = 0


def may_see_sky(alpha, seen: np.ndarray | None) -> np.ndarray | None:
    """(k,) bool: the points (alpha (k, n) of the patches there) that may see the sky: a patch
    there is marked in `seen` (n,) (radiosity.emission.sky_patches), or none covers them; None: all of them
    (seen is None)."""
    if seen is None:
        return None
    return (alpha @ np.asarray(seen, np.float64) > 0) | (np.asarray(alpha.sum(axis=1)).ravel() <= 0)


def inside(surfaces, points: np.ndarray, triangles) -> np.ndarray:
    """Points (m, 3) moved towards the centroids of their triangles (m,) by INSIDE x the scene
    extent, at most halfway: off every edge of the triangle, so off the plane of a neighbouring face
    that meets it at a concave edge, by far more than the rays' start offset."""
    c = np.take(surfaces.corners, np.asarray(triangles, np.int64), axis=0).mean(axis=1)
    to = c - points
    dist = np.linalg.norm(to, axis=1, keepdims=True)
    step = np.minimum(INSIDE * surfaces.extent, 0.5 * dist)
    return points + to * (step / np.maximum(dist, 1e-300))


@dataclass(frozen=True)
class HitValues:
    """What the patches give at gather hits (k each): far (k, 3), the reflected radiosity; near
    (k, 3), their indirect light and unsampled emission (NearField); radius (k,), the local patch
    radius (alpha-weighted); sky (k,) bool, may the hit see the sky (None: all may)."""

    far: np.ndarray
    near: np.ndarray
    radius: np.ndarray
    sky: np.ndarray | None


# Hits closer than this many local patch radii to their bake point read alpha where they land when
# their triangle side is cut in more than one cell: there the lattice's linear cells smear the
# patches' steps (a contact line under a box, a visibility edge) over a large solid angle. Cornell
# box, 2 131 patches, every vertex: lattice everywhere 1.70 %, alpha at every hit 1.595 %, with
# this 1.595 % (lamps_doorway 1.94 / 1.762 / 1.762 %).
LATTICE_REACH = 1.5

MAX_DIVISIONS = 256  # a triangle side needing a finer lattice (over 33 k nodes) reads alpha at its hits

SECOND_DIVISIONS = 64  # the second gather's lattice (NearField.second_rays) cuts an edge in at most this
SECOND_CHUNK_RAYS = 1 << 16  # its rays per batch


class CornerCache:
    """The gather's hits read from values kept at the nodes of a lattice over their triangle.

    Two things are computed once per lattice node (stepped a hair inside the triangle, as bake
    points are) and interpolated linearly across the lattice's cells:
    - alpha-weighted patch values (HitValues), on a lattice over each triangle side whose spacing is
      at most corner_alpha x the smallest patch radius of the side's sheet: alpha varies on the
      patches' scale, and a quarter of the smallest radius is finer than any patch resolves. A
      triangle at most that size is its own cell (its corners); a wall's large triangle at 100 k
      patches is cut in up to a few hundred rows of cells. The production room's vertex bake at
      100 k patches sends 52 M gather rays to 10.5 M nodes, of which about 3 M are ever asked
      (alpha at every hit was 40 % of that bake, py-spy). Hits closer than LATTICE_REACH patch
      radii on a side cut in several cells take alpha where they land;
    - the near field's direct light at the triangle's corners, for hits whose triangle is at most
      NearField.corner_size (0.25) x their distance at 256 rays (x sqrt(256 / rays) at other
      counts): smaller than the spacing of the gather's rays where they land (256 rays: about 0.16
      rad apart), so the gather does not resolve light inside it. (test_gather.py: on a floor in
      4.4 cm triangles beside a 4 cm shadow band, 0.25 x the distance moved the light gathered by
      4 096 rays by under 0.2 %; 0.5 x smeared the band, up to 2.7 %.)
    Other near hits (a large triangle seen close: the floor at an object's foot) cast shadow rays
    where they land; a side whose lattice would be finer than MAX_DIVISIONS takes alpha at each hit.
    Values depend only on the node, never on which thread or bake point asked first: no noise, the
    same result on any number of threads.
    """

    def __init__(
        self,
        problem,
        values: np.ndarray,
        near: NearField | None,
        corner_alpha: float = CORNER_ALPHA,
        rays: int = 256,
        second_pattern: np.ndarray | None = None,
    ):
        self.problem, self.values, self.near = problem, values, near
        index, atlas = problem.index, problem.atlas
        c = index.surfaces.corners
        T = len(c)
        edges = np.stack([c[:, 1] - c[:, 0], c[:, 2] - c[:, 1], c[:, 0] - c[:, 2]], axis=1)
        self.size = np.sqrt(np.einsum("tej,tej->te", edges, edges).max(axis=1))
        smallest = np.full(len(index.sheet_chart) + 1, np.inf)  # last: no sheet (-1)
        np.minimum.at(smallest, atlas.sheet, atlas.radii)
        self.alpha_size = corner_alpha * smallest if corner_alpha > 0 else np.full_like(smallest, -1.0)
        tri = np.arange(T)
        divisions = np.zeros((2, T), np.int64)  # (back, triangle); 0: alpha at each hit
        if corner_alpha > 0:
            for back in (0, 1):
                h = self.alpha_size[index.sheet_of(tri, np.full(T, 1 - 2 * back))]
                n = np.ceil(self.size / h)  # a side without patches (h = inf): one cell
                divisions[back] = np.where(n <= MAX_DIVISIONS, np.maximum(n, 1), 0)
        self.frames = TriangleFrames(c)
        self.patch_nodes = LatticeValues(self.frames, divisions, 8, np.float32, self._values)
        # the spacing of the gather's rays where they land goes as 1 / sqrt(rays)
        self.light_size = 0.0 if near is None else near.corner_size * np.sqrt(256.0 / max(rays, 1))
        self.light_nodes = None
        if near is not None:
            self.light_nodes = LatticeValues(
                self.frames, np.ones((2, T), np.int64), 3, np.float64, self._light
            )
        self.second_nodes, self.second_pattern = None, second_pattern
        if near is not None and near.second_rays > 0:
            if second_pattern is None or len(second_pattern) != near.second_rays:
                raise ValueError("a second gather needs its pattern of second_rays directions")
            # a lattice as fine as the patch values' (at most SECOND_DIVISIONS cells an edge)
            second = np.zeros((2, T), np.int64)
            for back in (0, 1):
                h = CORNER_ALPHA * smallest[index.sheet_of(tri, np.full(T, 1 - 2 * back))]
                second[back] = np.clip(np.ceil(self.size / h), 1, SECOND_DIVISIONS)
            self.second_nodes = LatticeValues(self.frames, second, 3, np.float64, self._second)

    def _values(self, tri, side, pts) -> np.ndarray:
        pts = inside(self.problem.index.surfaces, pts, tri)
        a = alpha_at(self.problem.atlas, self.problem.index, self.problem.contacts, pts, tri, side)
        return _patch_values(self.problem, a, self.values, self.near)

    def _light(self, tri, side, pts) -> np.ndarray:
        problem, near = self.problem, self.near
        index = problem.index
        pts = inside(index.surfaces, pts, tri)
        normals = index.charts.normals[tri] * side[:, None]
        sky_at = None
        if near.light.sky is not None and near.sky_seen is not None:
            sky_at = may_see_sky(
                alpha_at(problem.atlas, index, problem.contacts, pts, tri, side), near.sky_seen
            )
        return direct_irradiance(problem.emitter_rules, index.rays, near.light, pts, normals, sky_at)[0]

    def _second(self, tri, side, pts) -> np.ndarray:
        """Irradiance (k, 3) at nodes from a second gather: the far values (patches' reflected
        radiosity and the emission the bake points do not sample) where its rays land, no near field."""
        index = self.problem.index
        pts = inside(index.surfaces, pts, tri)
        nrm = index.charts.normals[tri] * side[:, None]
        local = self.second_pattern
        k = len(local)
        eps = 1e-6 * index.surfaces.extent
        out = np.empty((len(pts), 3))
        step = max(1, SECOND_CHUNK_RAYS // k)
        for s in range(0, len(pts), step):
            sl = slice(s, s + step)
            n = nrm[sl]
            t_axis, b_axis = tangent_frame(n)
            dirs = (
                local[None, :, :1] * t_axis[:, None]
                + local[None, :, 1:2] * b_axis[:, None]
                + local[None, :, 2:] * n[:, None]
            ).reshape(-1, 3)
            origins = shadow_origin(np.repeat(pts[sl], k, axis=0), np.repeat(n, k, axis=0), dirs, eps)
            hits = ray_hits(index, origins, dirs)
            got = np.zeros((len(dirs), 3))
            far = self.values_at(hits.points, hits.triangle, hits.side, hits.t).far
            surfaces = index.surfaces
            if surfaces.albedo is not None:
                # a patch holds its mean albedo x its light: on a textured triangle the light it
                # reflects takes the texture's detail, albedo(hit) / the triangle's mean (the second
                # gather's rays land close, where a floor's checker cells are seen one by one)
                tex = np.flatnonzero(surfaces.albedo.varies[hits.triangle])
                if len(tex):
                    t_tri = hits.triangle[tex]
                    here = surfaces.reflectance_at(t_tri, np.take(hits.points, tex, axis=0))
                    mean = surfaces.reflectance[t_tri]
                    with np.errstate(divide="ignore", invalid="ignore"):
                        far[tex] *= np.where(mean > 0, here / mean, 0.0)
            got[hits.ray] = far
            out[sl] = got.reshape(-1, k, 3).mean(axis=1)
        return out

    def indirect_at(self, points, triangles, sides) -> np.ndarray:
        """The second gather's irradiance (k, 3) at points on triangles (k,), seen from sides (k,)."""
        return self.second_nodes.at(points, triangles, sides)

    def light_at(self, points, triangles, sides) -> np.ndarray:
        """Near-field direct irradiance (k, 3) at points on triangles (k,), seen from sides (k,)."""
        return self.light_nodes.at(points, triangles, sides)

    def values_at(self, points, triangles, sides, t=None) -> HitValues:
        """HitValues at hits: from the lattice where their side has one, from alpha at the others
        and, given the hits' distances t (k,), at hits closer than LATTICE_REACH local patch radii
        on a side cut in more than one cell."""
        problem = self.problem
        n = np.take(self.patch_nodes.divisions, self.patch_nodes.side_index(triangles, sides))
        s = np.flatnonzero(n > 0)
        if len(s) == len(n):
            out = self.patch_nodes.at(points, triangles, sides)
        else:
            out = np.empty((len(points), 8))
            if len(s):
                out[s] = self.patch_nodes.at(np.take(points, s, axis=0), triangles[s], sides[s])
        exact = n == 0
        if t is not None:
            exact |= (n > 1) & (t < LATTICE_REACH * out[:, 6])
        e = np.flatnonzero(exact)
        if len(e):
            a = alpha_at(
                problem.atlas,
                problem.index,
                problem.contacts,
                np.take(points, e, axis=0),
                triangles[e],
                sides[e],
            )
            out[e] = _patch_values(problem, a, self.values, self.near)
        sky = None
        if self.near is not None and self.near.light.sky is not None and self.near.sky_seen is not None:
            sky = out[:, 7] > 0
        return HitValues(out[:, :3], out[:, 3:6], out[:, 6], sky)


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


def _patch_values(problem, alpha, values, near: NearField | None) -> np.ndarray:
    """(k, 8) at points with alpha (k, n): alpha @ values, alpha @ (near.indirect + near.extra),
    alpha @ radii, and 1 where the point may see the sky (may_see_sky), else 0."""
    out = np.zeros((alpha.shape[0], 8))
    out[:, :3] = alpha @ values
    out[:, 6] = alpha @ problem.atlas.radii
    if near is not None:
        # with a second gather the near hits take the light of other surfaces from it, not the patches
        out[:, 3:6] = alpha @ (near.extra if near.second_rays > 0 else near.indirect + near.extra)
        if near.light.sky is not None and near.sky_seen is not None:
            out[:, 7] = may_see_sky(alpha, near.sky_seen)
    return out


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
