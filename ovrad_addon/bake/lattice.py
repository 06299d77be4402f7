"""What gather hits read off the patches: alpha-weighted patch values, a near hit's direct light and
the light a second gather finds there, each on a lattice over each triangle (nodes.py), filled on
demand and interpolated; the near-field policy."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..geometry import tangent_frame
from ..light.direct import DirectLight, direct_irradiance
from ..light.lamps import shadow_origin
from ..overlap.queries import alpha_at, ray_hits
from ..scene.surfaces import per_albedo
from .nodes import LatticeValues, TriangleFrames

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
    corner or under clutter; 0: the patches' indirect light. sky_nodes: with a second gather, the
    near hits take the sky's direct light from its lattice (CornerCache); False: cast where they land."""

    light: DirectLight
    indirect: np.ndarray
    extra: np.ndarray
    reach: float = 1.0
    sky_seen: np.ndarray | None = None
    corner_size: float = 0.25
    second_rays: int = 0
    sky_nodes: bool = True


def pattern_rays(points, normals, local, eps: float, frames=None) -> tuple[np.ndarray, np.ndarray]:
    """Origins and directions (m k, 3) of the k rays of a gather pattern (local (k, 3), z the normal)
    from each of m points with unit normals (m, 3), point by point: the pattern turned into each
    point's tangent frame (frames: its (tangent, bitangent) (m, 3) each, when already known), the
    origins just off the surface along the rays (shadow_origin)."""
    n = np.asarray(normals, np.float64)
    t_axis, b_axis = tangent_frame(n) if frames is None else frames
    k = len(local)
    dirs = (
        local[None, :, :1] * t_axis[:, None]
        + local[None, :, 1:2] * b_axis[:, None]
        + local[None, :, 2:] * n[:, None]
    ).reshape(-1, 3)
    return shadow_origin(np.repeat(points, k, axis=0), np.repeat(n, k, axis=0), dirs, eps), dirs


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

    Three things are computed once per lattice node (stepped a hair inside the triangle, as bake
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
    - with NearField.second_rays, the irradiance a second gather finds at the node (far values only,
      second_pattern's directions in the node's tangent frame), on a lattice as fine as the patch
      values' but at most SECOND_DIVISIONS cuts an edge: the near hits' light from other surfaces;
      and on the same lattice the sky's direct light at the node (the near field's sky rule): a
      near hit on a large triangle then casts shadow rays to the lamps and emitters only. The sky
      is soft, lit by every direction, and its rule casts a hundred or more rays a point: at every
      near hit that was most of a sky-lit bake's rays (foliage's lightmaps: 268 of 471 M).
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
        # (back, triangle) sheets of each triangle side, and the cuts a lattice spaced at most `h`
        # per sheet needs along the triangle's longest edge (a side without patches, h = inf: 0)
        tri = np.arange(T)
        sheets = np.stack([index.sheet_of(tri, np.full(T, 1 - 2 * back)) for back in (0, 1)])

        def cuts(h: np.ndarray) -> np.ndarray:
            return np.ceil(self.size[None, :] / h[sheets])

        divisions = np.zeros((2, T), np.int64)  # (back, triangle); 0: alpha at each hit
        if corner_alpha > 0:
            n = cuts(self.alpha_size)
            divisions[:] = np.where(n <= MAX_DIVISIONS, np.maximum(n, 1), 0)
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
        second_gather = near is not None and near.second_rays > 0
        # the near hits' sky from the second gather's lattice; their other direct light where they land
        self.sky_nodes = (
            second_gather and near.sky_nodes and near.light.sky is not None and near.light.sky.emits
        )
        if second_gather:
            if second_pattern is None or len(second_pattern) != near.second_rays:
                raise ValueError("a second gather needs its pattern of second_rays directions")
            # a lattice as fine as the patch values' (at most SECOND_DIVISIONS cells an edge); its
            # nodes hold the sky's light too when the near hits take it from there
            second = np.clip(cuts(CORNER_ALPHA * smallest), 1, SECOND_DIVISIONS).astype(np.int64)
            channels = 6 if self.sky_nodes else 3
            self.second_nodes = LatticeValues(self.frames, second, channels, np.float64, self._second)
        # with sky_nodes, the near hits' rule without the sky and the nodes' rule of the sky alone
        self.hit_light = None if near is None else near.light
        self.sky_light = None
        if self.sky_nodes:
            self.hit_light = replace(near.light, sky=None)
            self.sky_light = replace(near.light, lamps=(), emitters=None)

    def _values(self, tri, side, pts) -> np.ndarray:
        pts = inside(self.problem.index.surfaces, pts, tri)
        a = alpha_at(self.problem.atlas, self.problem.index, self.problem.contacts, pts, tri, side)
        return _patch_values(self.problem, a, self.values, self.near)

    def _light(self, tri, side, pts, light: DirectLight | None = None) -> np.ndarray:
        """The near field's direct irradiance (k, 3) at nodes (light: another rule than its own)."""
        problem, near = self.problem, self.near
        light = near.light if light is None else light
        index = problem.index
        pts = inside(index.surfaces, pts, tri)
        normals = index.charts.normals[tri] * side[:, None]
        sky_at = None
        if light.sky is not None and near.sky_seen is not None:
            sky_at = may_see_sky(
                alpha_at(problem.atlas, index, problem.contacts, pts, tri, side), near.sky_seen
            )
        return direct_irradiance(problem.emitter_rules, index.rays, light, pts, normals, sky_at)[0]

    def _second(self, tri, side, pts) -> np.ndarray:
        """(k, 3) at nodes: the irradiance from a second gather, the far values (patches' reflected
        radiosity and the emission the bake points do not sample) where its rays land, no near
        field; with sky_nodes (k, 6): then the sky's direct irradiance."""
        index = self.problem.index
        surfaces = index.surfaces
        out = np.zeros((len(pts), 6 if self.sky_nodes else 3))
        if self.sky_nodes:
            out[:, 3:] = self._light(tri, side, pts, self.sky_light)
        pts = inside(surfaces, pts, tri)
        nrm = index.charts.normals[tri] * side[:, None]
        local = self.second_pattern
        k = len(local)
        eps = 1e-6 * surfaces.extent
        step = max(1, SECOND_CHUNK_RAYS // k)
        for s in range(0, len(pts), step):
            sl = slice(s, s + step)
            origins, dirs = pattern_rays(pts[sl], nrm[sl], local, eps)
            hits = ray_hits(index, origins, dirs)
            got = np.zeros((len(dirs), 3))
            far = self.values_at(hits.points, hits.triangle, hits.side, hits.t).far
            # a patch holds its mean albedo x its light: on a textured triangle the light it reflects
            # takes the texture's detail, albedo(hit) / the triangle's mean (the second gather's rays
            # land close, where a floor's checker cells are seen one by one)
            tex = np.flatnonzero(surfaces.textured(hits.triangle))
            if len(tex):
                t_tri = hits.triangle[tex]
                here = surfaces.reflectance_at(t_tri, np.take(hits.points, tex, axis=0))
                far[tex] *= per_albedo(here, surfaces.reflectance[t_tri])
            got[hits.ray] = far
            out[sl, :3] = got.reshape(-1, k, 3).mean(axis=1)
        return out

    def second_at(self, points, triangles, sides) -> tuple[np.ndarray, np.ndarray]:
        """The second gather's irradiance and the sky's direct irradiance (k, 3 each; the sky 0 unless
        sky_nodes) at points on triangles (k,), seen from sides (k,)."""
        v = self.second_nodes.at(points, triangles, sides)
        return v[:, :3], (v[:, 3:] if self.sky_nodes else np.zeros((len(v), 3)))

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
