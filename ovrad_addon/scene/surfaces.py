"""Scene surfaces as plain arrays: triangles, materials, charts (smooth pieces) and sheets (sides)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..errors import OvradError
from ..geometry import unique_rows
from .albedo import TextureAlbedo, albedo_at, texel_means, triangle_means
from .coverage import Coverage


@dataclass(frozen=True)
class Surfaces:
    """World-space triangles of every mesh in the scene.

    vertices: (V, 3) float64, triangles: (T, 3) int64 indices into vertices,
    object_index: (T,) int64, which input object each triangle came from,
    reflectance: (T, 3) float64 diffuse RGB albedo in [0, 1],
    emission: (T, 3) float64 emitted radiance L_e (W m^-2 sr^-1, Blender's Emission strength x colour),
    object_names: one name per object (for messages),
    receiver: (n_objects,) bool, whether an object receives patches (False: pure occluder),
    albedo: image textures of the triangles that have one (None: none has); their reflectance is
    then each textured triangle's mean albedo, for code that needs a constant (reflectance_at()
    gives the albedo at points).
    coverage: the materials' alpha where some triangle's is below 1 (None: every surface is
    opaque); light passes a see-through surface in proportion (rays.SeeThroughRays).
    bake_weight: (T,) the share of the light a triangle reflects diffusely that a bake reports
    (a layered material's upper lobes take the rest towards the viewer, who sees a baked point
    along its normal); the solve's transport uses the reflectance alone. None: 1 everywhere.
    emitted: the emitted colour of the triangles whose emission varies over them (an image or a
    colour attribute as Emission Color, its tint the strength x any constant factor), as a
    TextureAlbedo; their `emission` is then each one's mean over its texels (albedo.texel_means,
    computed here whatever `emission` gave them),
    and their light comes from pieces of about a texel (light.emitters.emitting_triangles). None:
    every triangle emits a constant.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    object_index: np.ndarray
    reflectance: np.ndarray
    emission: np.ndarray
    object_names: tuple[str, ...]
    receiver: np.ndarray
    albedo: TextureAlbedo | None = None
    coverage: Coverage | None = None
    bake_weight: np.ndarray | None = None
    emitted: TextureAlbedo | None = None

    @staticmethod
    def from_arrays(
        vertices,
        triangles,
        object_index=None,
        reflectance=None,
        emission=None,
        object_names=None,
        receiver=None,
        albedo=None,
        coverage=None,
        bake_weight=None,
        emitted=None,
    ) -> Surfaces:
        """Validate and normalise input arrays; raise OvradError on unusable input."""
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        if len(t) == 0:
            raise OvradError("no triangles: select at least one mesh with faces")
        if not np.all(np.isfinite(v)):
            raise OvradError("mesh has NaN or infinite vertex coordinates; fix the mesh first")
        if t.min() < 0 or t.max() >= len(v):
            raise OvradError("triangle indices out of range")
        oi = np.zeros(len(t), np.int64) if object_index is None else np.asarray(object_index, np.int64)
        if oi.shape != (len(t),):
            raise OvradError("object_index must give one object per triangle")
        n_obj = int(oi.max()) + 1
        rho = _per_triangle_rgb(reflectance, len(t), 0.8, "reflectance")
        if rho.min() < 0.0 or rho.max() > 1.0:
            raise OvradError("reflectance must lie in [0, 1]: a surface cannot reflect more than it receives")
        em = _per_triangle_rgb(emission, len(t), 0.0, "emission")
        if em.min() < 0.0:
            raise OvradError("emission must be non-negative")
        names = (
            tuple(object_names) if object_names is not None else tuple(f"object {i}" for i in range(n_obj))
        )
        if len(names) < n_obj:
            raise OvradError("one object name per object is needed")
        rec = np.ones(len(names), bool) if receiver is None else np.asarray(receiver, bool)
        if albedo is not None:
            if len(albedo.image_of) != len(t):
                raise OvradError("texture albedo must describe every triangle (image_of -1 where none)")
            if not np.any(albedo.varies):
                albedo = None
            else:
                rho = triangle_means(albedo, rho, v[t])
        if coverage is not None:
            if len(coverage.opacity) != len(t):
                raise OvradError("alpha must describe every triangle (1 where opaque)")
            if not np.any(coverage.see_through):
                coverage = None
        weight = None
        if bake_weight is not None:
            weight = np.asarray(bake_weight, np.float64).reshape(-1)
            if weight.shape != (len(t),) or not np.all((weight >= 0.0) & (weight <= 1.0)):
                raise OvradError("bake_weight must give one share in [0, 1] per triangle")
            if np.all(weight == 1.0):
                weight = None
        if emitted is not None:
            if len(emitted.image_of) != len(t):
                raise OvradError("emitted colour must describe every triangle (image_of -1 where none)")
            # each varying triangle's emission: its mean over its texels (the light's total, the
            # patches' emission), whatever was given for it
            em = np.maximum(texel_means(emitted, em, v[t], clip=False), 0.0)
            if not np.any(emitted.varies & (em.sum(axis=1) > 0)):
                emitted = None
        return Surfaces(v, t, oi, rho, em, names, rec, albedo, coverage, weight, emitted)

    # Computed once per Surfaces (frozen, so the arrays they derive from never change); callers
    # must not write into them.
    @cached_property
    def corners(self) -> np.ndarray:
        """(T, 3, 3) triangle corner positions."""
        return self.vertices[self.triangles]

    def reflectance_at(self, triangles, points) -> np.ndarray:
        """Albedo (m, 3) at surface points (m, 3) on triangles (m,): the texture where a triangle
        has one, else its constant reflectance."""
        tri = np.asarray(triangles, np.int64)
        if self.albedo is None or not np.any(self.albedo.varies[tri]):
            return self.reflectance[tri]
        return albedo_at(self.albedo, self.reflectance, self.corners, tri, points)

    def textured(self, triangles) -> np.ndarray:
        """(m,) bool: which of the triangles (m,) have an albedo texture."""
        if self.albedo is None:
            return np.zeros(len(triangles), bool)
        return self.albedo.varies[triangles]

    def opacity_at(self, triangles, points) -> np.ndarray:
        """Alpha (m,) at surface points (m, 3) on triangles (m,): 1 on opaque surfaces."""
        tri = np.asarray(triangles, np.int64)
        if self.coverage is None:
            return np.ones(len(tri))
        return self.coverage.alpha(self._alpha_frames, tri, points)

    @cached_property
    def _alpha_frames(self):
        """The alpha maps' UV frames (Coverage.frames), made on first use."""
        return self.coverage.frames(self.corners)

    @cached_property
    def extent(self) -> float:
        """Length of the bounding box diagonal (the scene's scale)."""
        used = np.zeros(len(self.vertices), bool)
        used[self.triangles.ravel()] = True
        v = self.vertices[used]
        return float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))

    @cached_property
    def welded(self) -> tuple[np.ndarray, np.ndarray]:
        """Vertices welded by position (to 1e-9 of the extent; meshes often split vertices for sharp
        shading): (first (w,), the first vertex of each welded one; weld (V,), each vertex's)."""
        q = np.round(self.vertices / (max(self.extent, 1e-300) * 1e-9)).astype(np.int64)
        _, first, weld = unique_rows(q, return_index=True, return_inverse=True)
        return first, weld

    @cached_property
    def _by_object(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(triangles sorted by object, stably; first position of each object in it; counts)."""
        order = np.argsort(self.object_index, kind="stable")
        counts = np.bincount(self.object_index, minlength=len(self.object_names))
        return order, np.cumsum(counts) - counts, counts

    @cached_property
    def local_triangle(self) -> np.ndarray:
        """(T,) index of each triangle among its own object's triangles (in their order)."""
        order, start, _ = self._by_object
        local = np.empty(len(order), np.int64)
        local[order] = np.arange(len(order)) - start[self.object_index[order]]
        return local

    def global_triangle(self, obj, local) -> np.ndarray:
        """Triangle indices from (object, index among that object's triangles); -1 where out of range."""
        order, start, counts = self._by_object
        obj = np.asarray(obj, np.int64)
        local = np.asarray(local, np.int64)
        ok = (obj >= 0) & (obj < len(counts)) & (local >= 0)
        ok[ok] &= local[ok] < counts[obj[ok]]
        out = np.full(np.broadcast(obj, local).shape, -1, np.int64)
        out[ok] = order[start[obj[ok]] + local[ok]]
        return out


def _per_triangle_rgb(value, n: int, default: float, what: str) -> np.ndarray:
    if value is None:
        return np.full((n, 3), default)
    a = np.asarray(value, dtype=np.float64)
    if a.ndim == 1 and a.shape == (3,):
        a = np.broadcast_to(a, (n, 3))
    a = a.reshape(-1, 3) if a.size == 3 * n else a
    if a.shape != (n, 3):
        raise OvradError(f"{what} must be one RGB triple per triangle")
    if not np.all(np.isfinite(a)):
        raise OvradError(f"{what} has NaN or infinite values")
    return np.array(a, dtype=np.float64)


def triangle_geometry(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Areas (T,) and unit normals (T, 3) of triangles given as (T, 3, 3); zero normal if degenerate."""
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    twice = np.linalg.norm(cross, axis=1)
    normals = np.zeros_like(cross)
    ok = twice > 0
    normals[ok] = cross[ok] / twice[ok, None]
    return 0.5 * twice, normals


@dataclass(frozen=True)
class Charts:
    """Smooth pieces of the surfaces, found from triangle adjacency.

    chart: (T,) int64 chart of each triangle, -1 for degenerate (zero-area) triangles,
    closed: (n_charts,) bool, whether the chart's object is a closed (watertight) mesh,
    areas: (T,) triangle areas, normals: (T, 3) unit triangle normals.
    """

    chart: np.ndarray
    closed: np.ndarray
    areas: np.ndarray
    normals: np.ndarray

    @property
    def count(self) -> int:
        return len(self.closed)

    @cached_property
    def chart_areas(self) -> np.ndarray:
        """(n_charts,) area of each chart."""
        ok = self.chart >= 0
        return np.bincount(self.chart[ok], weights=self.areas[ok], minlength=self.count)


def find_charts(surfaces: Surfaces, crease_angle_deg: float) -> Charts:
    """Split the surfaces into charts: edge-connected, same object, dihedral angle below the crease.

    Vertices are welded by position first (meshes often split vertices for sharp shading),
    so charts do not depend on how the mesh was indexed. Deterministic for a given input.
    """
    corners = surfaces.corners
    areas, normals = triangle_geometry(corners)
    scale = max(surfaces.extent, 1e-300)
    degenerate = areas <= (1e-12 * scale) ** 2
    # Vertices welded by position; edges are keyed by object below, so touching objects stay apart.
    tri = surfaces.welded[1][surfaces.triangles]
    n_tri = len(tri)
    # Each undirected edge with the triangles using it.
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    owner = np.tile(np.arange(n_tri), 3)
    e = np.sort(e, axis=1)
    obj = surfaces.object_index[owner]
    key = np.stack([obj, e[:, 0], e[:, 1]], axis=1)
    keep = ~degenerate[owner] & (e[:, 0] != e[:, 1])
    key, owner = key[keep], owner[keep]
    _, edge_id, edge_uses = unique_rows(key, return_inverse=True, return_counts=True)
    order = np.argsort(edge_id, kind="stable")
    sid, sown = edge_id[order], owner[order]
    same = sid[1:] == sid[:-1]
    a, b = sown[:-1][same], sown[1:][same]
    cos_limit = np.cos(np.radians(crease_angle_deg))
    smooth = np.einsum("ij,ij->i", normals[a], normals[b]) >= cos_limit
    # Only manifold edges (exactly two users) join charts; a non-manifold fan stays split.
    manifold = edge_uses[sid[:-1][same]] == 2
    join = smooth & manifold
    graph = coo_matrix((np.ones(join.sum()), (a[join], b[join])), shape=(n_tri, n_tri))
    _, labels = connected_components(graph, directed=False)
    labels = np.where(degenerate, -1, labels)
    # Renumber charts 0..n-1 in order of first triangle, skipping degenerate ones.
    valid = labels >= 0
    uniq, first = np.unique(labels[valid], return_index=True)
    rank = np.empty(len(uniq), np.int64)
    rank[np.argsort(first)] = np.arange(len(uniq))
    chart = np.full(n_tri, -1, np.int64)
    chart[valid] = rank[np.searchsorted(uniq, labels[valid])]
    # A closed object: every non-degenerate edge is used exactly twice by that object.
    obj_edges = key[:, 0][np.unique(edge_id, return_index=True)[1]]
    open_obj = np.unique(obj_edges[edge_uses != 2])
    closed_obj = np.ones(len(surfaces.object_names), bool)
    closed_obj[open_obj] = False
    chart_obj = np.zeros(len(uniq), np.int64)
    chart_obj[chart[valid]] = surfaces.object_index[valid]
    return Charts(chart, closed_obj[chart_obj], areas, normals)


def per_albedo(values: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """values / rho where the albedo rho > 0, else 0 (a texture's detail: albedo at a point over its
    triangle's mean)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rho > 0, values / rho, 0.0)
