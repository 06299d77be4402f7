"""The surfaces indexed for an atlas: charts, sheets (chart x side), planar flags, clutter charts
and the ray backend (SurfaceIndex), with the spacing of each sheet and points buried in closed objects."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from ..atlas import clutter as clutter_mod
from ..errors import OvradError
from ..geometry import unique_rows
from ..scene.rays import EmbreeRays, NumpyRays, SeeThroughRays, surface_rays
from ..scene.surfaces import Charts, Surfaces, find_charts
from ..settings import AtlasSettings


@dataclass(frozen=True)
class SurfaceIndex:
    """Surfaces with their charts, sheets and a ray backend: what patches are placed on.

    sheet_table (n_charts, 2): sheet index of each chart's front (column 0) and back (column 1)
    side, -1 where that side has no patches. sheet_chart, sheet_side (n_sheets,). sheet_clutter
    (n_sheets,): the sheet holds the clutter charts of one object on one side (clutter.py), and
    its sheet_chart is one of them.
    """

    surfaces: Surfaces
    charts: Charts
    planar: np.ndarray  # (n_charts,) bool: all triangles coplanar (to rounding)
    flat: np.ndarray  # (n_charts,) bool: close enough to a plane for grid placement
    deviation: np.ndarray  # (n_charts,) largest distance of a corner from the chart's mean plane
    sheet_table: np.ndarray
    sheet_chart: np.ndarray
    sheet_side: np.ndarray
    rays: NumpyRays | EmbreeRays | SeeThroughRays
    sheet_clutter: np.ndarray

    def sheet_of(self, triangle: np.ndarray, side: np.ndarray) -> np.ndarray:
        """Sheet index (or -1) of surface points on `triangle` seen from `side` (+1 front, -1 back)."""
        ch = self.charts.chart[triangle]
        out = self.sheet_table[np.maximum(ch, 0), (np.asarray(side) < 0).astype(np.int64)]
        return np.where((ch >= 0) & (triangle >= 0), out, -1)

    def with_clutter(self, clutter: np.ndarray) -> SurfaceIndex:
        """This index with the `clutter` charts (n_charts,) bool of each object joined into one
        sheet per side (clutter.py); the index itself when there are none."""
        if not np.any(clutter):
            return self
        table, sheet_chart, sheet_side, sheet_clutter = clutter_mod.sheet_table_with_clutter(
            self.sheet_table, clutter_mod.chart_objects(self.surfaces, self.charts), np.asarray(clutter, bool)
        )
        return replace(
            self,
            sheet_table=table,
            sheet_chart=sheet_chart,
            sheet_side=sheet_side,
            sheet_clutter=sheet_clutter,
        )

    @cached_property
    def sheet_area(self) -> np.ndarray:
        """(n_sheets,) area of each sheet (a clutter sheet: of all its charts)."""
        has = self.sheet_table >= 0
        rows = np.nonzero(has)[0]
        weights = self.charts.chart_areas[rows]
        return np.bincount(self.sheet_table[has], weights=weights, minlength=len(self.sheet_chart))

    @cached_property
    def chart_borders(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Each chart's border: its edges that only one of its triangles uses (vertices welded as
        find_charts welds them, Surfaces.welded), as (start (n_charts + 1,), a (E, 3), b (E, 3)): chart
        c's edges run from a to b in rows start[c]:start[c + 1] (overlap.cuts.border_crossings)."""
        surfaces, charts = self.surfaces, self.charts
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
        return start, at[border[:, 1]], at[border[:, 2]]


def _chart_planarity(surfaces: Surfaces, charts: Charts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per chart: whether it is planar, whether it is flat (a modeller's slightly warped quad
    counts), and its largest deviation from its mean plane."""
    nc = charts.count
    ok = charts.chart >= 0
    ch = charts.chart[ok]
    w = charts.areas[ok]
    ns = np.stack([np.bincount(ch, weights=charts.normals[ok, j] * w, minlength=nc) for j in range(3)], 1)
    mean_n = ns / np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-300)
    cen = surfaces.corners[ok].mean(axis=1)
    csum = np.stack([np.bincount(ch, weights=cen[:, j] * w, minlength=nc) for j in range(3)], 1)
    centroid = csum / np.maximum(charts.chart_areas[:, None], 1e-300)
    dev = np.abs(np.einsum("tvk,tk->tv", surfaces.corners[ok] - centroid[ch][:, None], mean_n[ch])).max(
        axis=1
    )
    worst = np.zeros(nc)
    np.maximum.at(worst, ch, dev)
    tilt = np.ones(nc)
    np.minimum.at(tilt, ch, np.einsum("ij,ij->i", charts.normals[ok], mean_n[ch]))
    planar = (worst <= 1e-6 * max(surfaces.extent, 1e-300)) & (tilt >= 1 - 1e-9)
    size = np.sqrt(charts.chart_areas)
    flat = planar | ((worst <= 5e-3 * size) & (tilt >= np.cos(np.radians(3.0))))
    return planar, flat, worst


def _back_side_sees_something(surfaces: Surfaces, charts: Charts, rays, chart_ids: np.ndarray) -> np.ndarray:
    """For open charts: does any probe ray from the back side hit scene geometry? (bool per chart id).

    Each chart casts the same number of rays from area-weighted random points, all charts at once.
    """
    rng = np.random.default_rng(12345)
    extent = max(surfaces.extent, 1e-300)
    result = np.zeros(len(chart_ids), bool)
    per_chart, per_point = 48, 6
    if len(chart_ids) == 0:
        return result
    slot = np.full(charts.count, -1, np.int64)
    slot[chart_ids] = np.arange(len(chart_ids))
    tri = np.flatnonzero(charts.chart >= 0)
    tri = tri[slot[charts.chart[tri]] >= 0]
    tri = tri[np.argsort(slot[charts.chart[tri]], kind="stable")]  # grouped by chart_ids order
    owner_tri = slot[charts.chart[tri]]
    cum = np.cumsum(charts.areas[tri])
    n_per = np.bincount(owner_tri, minlength=len(chart_ids))
    end = np.cumsum(n_per)
    start = end - n_per
    lo = np.where(start > 0, cum[np.maximum(start - 1, 0)], 0.0)
    hi = cum[end - 1]
    owner = np.repeat(np.arange(len(chart_ids)), per_chart)
    # area-weighted pick of a triangle within each chart: inverse CDF on the running area sum
    target = lo[owner] + rng.random(len(owner)) * (hi - lo)[owner]
    pick = np.searchsorted(cum, target, side="right")
    pick = tri[np.clip(pick, start[owner], end[owner] - 1)]
    m = len(pick)
    u, v = rng.random(m), rng.random(m)
    f = u + v > 1
    u[f], v[f] = 1 - u[f], 1 - v[f]
    cc = surfaces.corners[pick]
    pts = cc[:, 0] + u[:, None] * (cc[:, 1] - cc[:, 0]) + v[:, None] * (cc[:, 2] - cc[:, 0])
    n = -charts.normals[pick]
    d = rng.normal(size=(m, per_point, 3))
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    d = np.where(np.einsum("pkj,pj->pk", d, n)[..., None] < 0, -d, d)
    origins = np.repeat(pts + 1e-6 * extent * n, per_point, axis=0)
    hit = rays.occluded(origins, d.reshape(-1, 3), np.inf)
    return np.bincount(np.repeat(owner, per_point), weights=hit, minlength=len(chart_ids)) > 0


def index_surfaces(
    surfaces: Surfaces, settings: AtlasSettings, backend: str = "auto", clutter: np.ndarray | None = None
) -> SurfaceIndex:
    """Find charts, decide which sides get patches (see ObjectSettings.sides), build the ray backend.

    clutter (n_charts,) bool: the charts that join their object's clutter sheets (clutter.py);
    an empty array: none; None: the charts too small for patches of their own at the settings'
    spacing."""
    charts = find_charts(surfaces, settings.crease_angle)
    if charts.count == 0:
        raise OvradError("every face has zero area: nothing to cover with patches")
    rays = surface_rays(surfaces, backend)
    planar, flat, deviation = _chart_planarity(surfaces, charts)
    nc = charts.count
    chart_obj = clutter_mod.chart_objects(surfaces, charts)
    front = surfaces.receiver[chart_obj].copy()
    modes = np.array([settings.object_settings(o).sides for o in range(len(surfaces.object_names))])
    mode = modes[chart_obj] if nc else np.zeros(0, str)
    auto = mode == "AUTO"
    back = front & ((mode == "BOTH") | (auto & ~charts.closed))
    auto_open = np.flatnonzero(back & auto)
    if len(auto_open):
        back[auto_open] = _back_side_sees_something(surfaces, charts, rays, auto_open)
    table = np.full((nc, 2), -1, np.int64)
    sides = np.stack([front, back], 1)
    table[sides] = np.arange(int(sides.sum()))
    sheet_chart, sheet_col = np.nonzero(sides)
    index = SurfaceIndex(
        surfaces=surfaces,
        charts=charts,
        planar=planar,
        flat=flat,
        deviation=deviation,
        sheet_table=table,
        sheet_chart=sheet_chart,
        sheet_side=np.where(sheet_col == 0, 1, -1),
        rays=rays,
        sheet_clutter=np.zeros(len(sheet_chart), bool),
    )
    if clutter is None:
        clutter = clutter_charts(index, settings)
    return index.with_clutter(clutter)


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


def clutter_charts(index: SurfaceIndex, settings: AtlasSettings) -> np.ndarray:
    """(n_charts,) bool: receiving charts too small for patches of their own at the spacing the
    settings give (clutter.py)."""
    if len(index.sheet_chart) == 0:
        return np.zeros(index.charts.count, bool)
    spacing = np.full(index.charts.count, np.inf)
    np.minimum.at(spacing, index.sheet_chart, sheet_spacing(index, settings))
    return clutter_mod.small_charts(index.charts.chart_areas, spacing, index.flat) & np.isfinite(spacing)


def sheet_spacing(index: SurfaceIndex, settings: AtlasSettings) -> np.ndarray:
    """Grid spacing per sheet: from patch_size, or chosen so the whole scene gets about patch_count."""
    s = index.surfaces
    chart_obj = clutter_mod.chart_objects(s, index.charts)
    per_object = np.array([settings.object_settings(o).density for o in range(len(s.object_names))], float)
    density = per_object[chart_obj][index.sheet_chart]
    area = index.sheet_area
    if settings.patch_size is not None:
        base = settings.patch_size
    else:
        base = float(np.sqrt(np.sum(area * density**2) / settings.patch_count))
    return base / density
