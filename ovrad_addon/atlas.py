"""The atlas of overlapping patches: its arrays, the sheets it lives on, and how it is built."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from dataclasses import fields as dataclass_fields
from functools import cached_property
from typing import NamedTuple

import numpy as np
from scipy.sparse import csr_matrix, diags
from scipy.spatial import cKDTree

from . import clutter as clutter_mod
from . import names
from .contact import carry_over, contact_flags, contacts, split_at_contacts
from .errors import OvradError
from .geometry import ranges_flat, start_of
from .placement import (
    Placed,
    grid_angle,
    place_curved_many,
    place_planar_many,
    place_planar_small,
    sample_counts,
)
from .progress import StageCallback, report_stage
from .rays import EmbreeRays, NumpyRays, make_rays
from .settings import AtlasSettings
from .surfaces import Charts, Surfaces, find_charts


@dataclass(frozen=True, eq=False)
class Atlas:
    """n patches; every array has n rows.

    centers (n, 3), normals (n, 3) unit, tangents (n, 3) unit in-plane axis, radii (n,) (disk
    radius, or half the side of a square), shapes (n,) int8 (0 disk, 1 square), sheet (n,)
    surface sheet index, source_object (n,) index into the surfaces' objects, thickness (n,)
    tolerated distance from the patch plane, min_cos (n,) least normal agreement,
    support_area (n,) area A_h of D_h on the surface, effective_area (n,) c_hh,
    overlap_count (n,) other patches overlapping, random (n,) stable value in [0, 1).
    triangle (n,) int64 and side (n,) int8 (+1 front, -1 back) say which sheet the patch lies on
    without searching: the sheet is (chart of that triangle, side); triangle is counted among the
    source object's own triangles, so it stays valid when other objects change. None (or -1
    entries) for atlases made before they existed: their sheets are found by locating the patch.
    anchor (n, 3): the point of its sheet a patch sees its support from (contact.py); None (or NaN
    rows) where it was not stored: then the rule point nearest the centre.
    """

    centers: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    radii: np.ndarray
    shapes: np.ndarray
    sheet: np.ndarray
    source_object: np.ndarray
    thickness: np.ndarray
    min_cos: np.ndarray
    support_area: np.ndarray
    effective_area: np.ndarray
    overlap_count: np.ndarray
    random: np.ndarray
    beta: str = "smooth"
    triangle: np.ndarray | None = None
    side: np.ndarray | None = None
    anchor: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.centers)

    @cached_property
    def bounding_radii(self) -> np.ndarray:
        """(n,) radius of the smallest ball around the centre holding the whole patch."""
        return self.radii * np.where(self.shapes == names.SHAPE_SQUARE, np.sqrt(2.0), 1.0)

    @cached_property
    def tree(self) -> cKDTree:
        """KD-tree of the patch centres."""
        return cKDTree(self.centers)

    @cached_property
    def grid(self):
        """PatchGrid (lookup.py): the candidate patches of surface points, by sheet and cell."""
        from .lookup import PatchGrid

        return PatchGrid.build(self)

    @cached_property
    def bitangents(self) -> np.ndarray:
        """(n, 3) second in-plane axis, normal x tangent."""
        return np.cross(self.normals, self.tangents)

    def select(self, mask) -> Atlas:
        """The patches where mask is true (or the given indices), same beta."""
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for k, v in kw.items():
            if isinstance(v, np.ndarray):
                kw[k] = v[mask]
        return Atlas(**kw)

    def point_attributes(self) -> dict[str, tuple[np.ndarray, str]]:
        """Blender POINT attributes: name -> (array, attribute type)."""
        located = {}
        if self.triangle is not None and self.side is not None:
            located = {
                names.TRIANGLE: (self.triangle.astype(np.int32), "INT"),
                names.SIDE: (self.side.astype(np.int32), "INT"),
            }
        if self.anchor is not None:
            located[names.ANCHOR] = (self.anchor, "FLOAT_VECTOR")
        return located | {
            names.NORMAL: (self.normals, "FLOAT_VECTOR"),
            names.RADIUS: (self.radii, "FLOAT"),
            names.SHAPE: (self.shapes.astype(np.int32), "INT"),
            names.TANGENT: (self.tangents, "FLOAT_VECTOR"),
            names.AREA: (self.effective_area, "FLOAT"),
            names.OVERLAP: (self.overlap_count.astype(np.int32), "INT"),
            names.SHEET: (self.sheet.astype(np.int32), "INT"),
            names.THICKNESS: (self.thickness, "FLOAT"),
            names.MIN_COS: (self.min_cos, "FLOAT"),
            names.SUPPORT_AREA: (self.support_area, "FLOAT"),
            names.RANDOM: (self.random, "FLOAT"),
        }

    def as_stored(self) -> Atlas:
        """This atlas as a file keeps it (Blender attributes: float32 and int32 values), read back as
        from_point_attributes() reads it; the very same values again when it already is. Build_atlas
        integrates C on it, so the C it gives is the one a solve of the stored atlas integrates."""
        attrs = {
            k: np.asarray(v, np.float32 if kind.startswith("FLOAT") else np.int32)
            for k, (v, kind) in self.point_attributes().items()
        }
        centers = np.asarray(self.centers, np.float32)
        return Atlas.from_point_attributes(centers, attrs, self.beta, self.source_object)

    @staticmethod
    def concatenate(atlases: list[Atlas]) -> Atlas:
        """One atlas holding all patches of several (e.g. one per Blender atlas object); same beta."""
        if not atlases:
            raise OvradError("no atlas: generate an atlas first")
        betas = {a.beta for a in atlases}
        if len(betas) > 1:
            raise OvradError(
                "atlases were generated with different beta profiles: generate them again together"
            )
        kw = {}
        for f in fields(Atlas):
            vals = [getattr(a, f.name) for a in atlases]
            if f.name in ("triangle", "side", "anchor"):
                # an atlas without them (made before they existed) is located by search (-1), its
                # anchors found again (NaN)
                missing = {"anchor": lambda k: np.full((k, 3), np.nan)}.get(
                    f.name, lambda k: np.full(k, -1, np.int64)
                )
                vals = (
                    None
                    if all(v is None for v in vals)
                    else [missing(len(a)) if v is None else v for a, v in zip(atlases, vals, strict=True)]
                )
                kw[f.name] = None if vals is None else np.concatenate(vals)
                continue
            kw[f.name] = np.concatenate(vals) if isinstance(vals[0], np.ndarray) else vals[0]
        return Atlas(**kw)

    @staticmethod
    def from_point_attributes(centers, attributes: dict, beta: str, source_object=None) -> Atlas:
        """Rebuild an atlas from point positions and the attributes point_attributes() wrote.

        Values are taken as they are (a file's float32 values widened, unit vectors unit to that
        rounding, not renormalised): so writing the atlas again keeps exactly the same values."""
        c = np.asarray(centers, np.float64).reshape(-1, 3)

        def get(name, shape=None, dtype=np.float64):
            a = np.asarray(attributes[name], dtype)
            return a.reshape(shape) if shape else a

        n = len(c)
        return Atlas(
            centers=c,
            normals=get(names.NORMAL, (-1, 3)),
            tangents=get(names.TANGENT, (-1, 3)),
            radii=get(names.RADIUS),
            shapes=get(names.SHAPE, dtype=np.int8),
            sheet=get(names.SHEET, dtype=np.int64),
            source_object=np.zeros(n, np.int64)
            if source_object is None
            else np.asarray(source_object, np.int64),
            thickness=get(names.THICKNESS),
            min_cos=get(names.MIN_COS),
            support_area=get(names.SUPPORT_AREA),
            effective_area=get(names.AREA),
            overlap_count=get(names.OVERLAP, dtype=np.int64),
            random=get(names.RANDOM),
            beta=beta,
            triangle=get(names.TRIANGLE, dtype=np.int64) if names.TRIANGLE in attributes else None,
            side=get(names.SIDE, dtype=np.int8) if names.SIDE in attributes else None,
            anchor=get(names.ANCHOR, (-1, 3)) if names.ANCHOR in attributes else None,
        )


@dataclass(frozen=True)
class SurfaceIndex:
    """Surfaces with their charts, sheets and a ray backend: what patches are placed on.

    sheet_table (n_charts, 2): sheet index of each chart's front (column 0) and back (column 1)
    side, -1 where that side has no patches. sheet_chart, sheet_side (n_sheets,). sheet_clutter
    (n_sheets,): the sheet holds the clutter charts of one object on one side (clutter.py), and
    its sheet_chart is one of them. cache: what is derived from the index once (clutter samples).
    """

    surfaces: Surfaces
    charts: Charts
    planar: np.ndarray  # (n_charts,) bool: all triangles coplanar (to rounding)
    flat: np.ndarray  # (n_charts,) bool: close enough to a plane for grid placement
    deviation: np.ndarray  # (n_charts,) largest distance of a corner from the chart's mean plane
    sheet_table: np.ndarray
    sheet_chart: np.ndarray
    sheet_side: np.ndarray
    rays: NumpyRays | EmbreeRays
    sheet_clutter: np.ndarray
    cache: dict = field(init=False, default_factory=dict, compare=False, repr=False)

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
    rays = make_rays(surfaces.vertices, surfaces.triangles, backend)
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
        clutter = _small_charts(index, settings)
    return index.with_clutter(clutter)


def _small_charts(index: SurfaceIndex, settings: AtlasSettings) -> np.ndarray:
    """(n_charts,) bool: receiving charts too small for patches of their own at the spacing the
    settings give (clutter.py)."""
    if len(index.sheet_chart) == 0:
        return np.zeros(index.charts.count, bool)
    spacing = np.full(index.charts.count, np.inf)
    np.minimum.at(spacing, index.sheet_chart, _sheet_spacing(index, settings))
    return clutter_mod.small_charts(index.charts.chart_areas, spacing, index.flat) & np.isfinite(spacing)


COUNT_TOLERANCE = 0.1  # a patch count this close to the target needs no second correction


def _sheet_spacing(index: SurfaceIndex, settings: AtlasSettings) -> np.ndarray:
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


def _place_all(
    index: SurfaceIndex,
    settings: AtlasSettings,
    spacing: np.ndarray,
    angles: dict[int, float] | None = None,
    count_only: bool = False,
) -> tuple[list[Placed], int]:
    """Place patches sheet by sheet; each Placed's triangle holds global triangle indices. angles:
    planar sheets' grid angles (placement.grid_angle) by sheet, kept across placements (filled here).
    count_only: the count is all that is needed (a placement that only sets the next spacing): the
    planar and curved sheets are counted, not placed (the list then lacks them)."""
    angles = {} if angles is None else angles
    s = index.surfaces
    ch = index.charts
    ext = s.extent
    # Triangles grouped by chart once (not a search over all triangles per sheet).
    valid = np.flatnonzero(ch.chart >= 0)
    by_chart = valid[np.argsort(ch.chart[valid], kind="stable")]
    n_per = np.bincount(ch.chart[valid], minlength=ch.count)
    start = start_of(n_per)
    out: list[Placed | None] = [None] * len(index.sheet_chart)
    total = 0
    # Clutter sheets: ball patches on a grid (clutter.py).
    for k, fields_k in clutter_mod.place_balls(index, spacing, settings.overlap).items():
        out[k] = Placed(**fields_k)
        total += len(fields_k["radii"])
    # Small planar sheets (a tiny cube's face) all at once: most fit in one grid cell.
    small = np.flatnonzero(
        index.flat[index.sheet_chart] & (n_per[index.sheet_chart] <= SMALL_SHEET) & ~index.sheet_clutter
    )
    if len(small):
        c = index.sheet_chart[small]
        side = index.sheet_side[small]
        owner = np.repeat(np.arange(len(small)), n_per[c])
        tri = by_chart[ranges_flat(start[c], n_per[c])]
        corners = s.corners[tri]
        corners = np.where((side[owner] < 0)[:, None, None], corners[:, ::-1], corners)
        nrm = side[:, None] * np.add.reduceat(
            ch.normals[tri] * ch.areas[tri, None], start_of(n_per[c]), axis=0
        )
        done, got, p = place_planar_small(
            corners, owner, len(small), nrm, spacing[small], settings.overlap, settings.shapes, ext
        )
        p.thickness = p.thickness + 2.0 * index.deviation[c[got]]
        p.triangle = tri[p.triangle]
        empty = _empty_placed()
        for k in small[done]:
            out[k] = empty
        for j, k in enumerate(small[got]):
            out[k] = Placed(*(getattr(p, f.name)[j : j + 1] for f in dataclass_fields(Placed)))
        total += len(got)
    for k in np.flatnonzero(index.sheet_clutter):  # a clutter sheet no sample landed on (all of it buried)
        if out[k] is None:
            out[k] = _empty_placed()
    # Curved sheets: many at once (most are small pieces of a few triangles), in batches of about
    # CURVED_BATCH samples: larger batches spend more on memory traffic than they save in calls.
    curved = np.array([k for k in range(len(out)) if out[k] is None and not index.flat[index.sheet_chart[k]]])
    for batch in _curved_batches(index, spacing, curved, n_per, start, by_chart):
        if total > settings.max_patches:
            break
        c, side = index.sheet_chart[batch], index.sheet_side[batch]
        tri = by_chart[ranges_flat(start[c], n_per[c])]
        owner = np.repeat(np.arange(len(batch)), n_per[c])
        corners = s.corners[tri]
        corners = np.where((side[owner] < 0)[:, None, None], corners[:, ::-1], corners)
        nrm = side[owner, None] * ch.normals[tri]
        got = place_curved_many(corners, nrm, owner, spacing[batch], settings.overlap, ext, batch, count_only)
        if count_only:
            total += int(got.sum())
            continue
        p, k_per = got
        p.triangle = tri[p.triangle]
        for k, a, b in zip(batch, np.cumsum(k_per) - k_per, np.cumsum(k_per), strict=True):
            out[k] = Placed(*(getattr(p, f.name)[a:b] for f in dataclass_fields(Placed)))
        total += len(p.radii)
    # The other planar sheets: many at once too, in batches of about PLANAR_BATCH cells and triangles.
    planar = np.array(
        [k for k in range(len(out)) if out[k] is None and index.flat[index.sheet_chart[k]]], np.int64
    )
    c, side = index.sheet_chart[planar], index.sheet_side[planar]
    cost = n_per[c] + index.sheet_area[planar] / spacing[planar] ** 2
    which = np.floor((np.cumsum(cost) - cost) / PLANAR_BATCH).astype(np.int64)
    for batch in np.split(np.arange(len(planar)), np.flatnonzero(np.diff(which)) + 1):
        if total > settings.max_patches or len(batch) == 0:
            break
        k, cb, sb = planar[batch], c[batch], side[batch]
        tri = by_chart[ranges_flat(start[cb], n_per[cb])]
        owner = np.repeat(np.arange(len(batch)), n_per[cb])
        corners = s.corners[tri]
        corners = np.where((sb[owner] < 0)[:, None, None], corners[:, ::-1], corners)
        first = start_of(n_per[cb])
        nrm = sb[:, None] * np.add.reduceat(ch.normals[tri] * ch.areas[tri, None], first, axis=0)
        for j in np.flatnonzero([sheet not in angles for sheet in k]):  # once for all placements
            angles[k[j]] = grid_angle(corners[first[j] : first[j] + n_per[cb[j]]], nrm[j])
        angle = np.array([angles[j] for j in k])
        got = place_planar_many(
            corners, owner, nrm, spacing[k], settings.overlap, settings.shapes, ext, angle, count_only
        )
        if count_only:
            total += int(got.sum())
            continue
        p, k_per = got
        p.triangle = tri[p.triangle]
        p.thickness = p.thickness + 2.0 * np.repeat(index.deviation[cb], k_per)
        for j, a, b in zip(k, np.cumsum(k_per) - k_per, np.cumsum(k_per), strict=True):
            out[j] = Placed(*(getattr(p, f.name)[a:b] for f in dataclass_fields(Placed)))
        total += len(p.radii)
    return [p for p in out if p is not None], total


CURVED_BATCH = 1 << 15  # samples per batch of curved sheets placed at once


def _curved_batches(index, spacing, sheets, n_per, start, by_chart) -> list[np.ndarray]:
    """Curved sheets in consecutive batches of about CURVED_BATCH samples each (the samples of
    placement.sample_sheets at spacing / 6, and the corners); a larger sheet alone."""
    if len(sheets) == 0:
        return []
    c = index.sheet_chart[sheets]
    tri = by_chart[ranges_flat(start[c], n_per[c])]
    gap = (spacing[sheets] / 6.0)[np.repeat(np.arange(len(sheets)), n_per[c])]
    per_tri = sample_counts(index.charts.areas[tri], gap) + 3
    cost = np.add.reduceat(per_tri, start_of(n_per[c]))
    # batch b takes the sheets whose cumulative cost falls in [b, b + 1) x CURVED_BATCH
    which = np.floor((np.cumsum(cost) - cost) / CURVED_BATCH).astype(np.int64)
    cut = np.flatnonzero(np.diff(which)) + 1
    return np.split(sheets, cut)


# A patch whose alpha averages under this over its support (c_kk / A_k) is dropped: it hangs
# almost wholly off its piece, and where its sliver of support lies other patches hold nearly all
# the light. Its row and column of C are then nearly empty but for their neighbours' terms, and
# the solve leaves its B free to ring: on the production room at 100 k patches (smooth beta) a
# BoomBox patch resting on the floor, c_kk / A_k = 0.014 on 2.6 % of its disk, solved to B = 4.8
# where its neighbours have ~0.01, and lit 8 vertices up to 1.05 where Cycles has 0; the patches
# under 0.03 there (about 30 of 108 600, on the BoomBox and the bent tubes) held every |B| over 2
# but the lamp's.
MIN_OWN_SHARE = 0.03


def _to_drop(C: csr_matrix, support: np.ndarray) -> np.ndarray:
    """(n,) bool: patches without support, or holding under MIN_OWN_SHARE of it (c_kk / A_k)."""
    return (support <= 0) | (C.diagonal() < MIN_OWN_SHARE * support)


def _empty_placed() -> Placed:
    vectors = (np.zeros((0, 3)) for _ in range(3))
    empty = Placed(*vectors, *(np.zeros(0) for _ in range(4)), np.zeros(0, np.int64))
    empty.shapes = empty.shapes.astype(np.int8)
    return empty


SMALL_SHEET = 4  # planar sheets of at most this many triangles are placed together
PLANAR_BATCH = 1 << 16  # planar sheets placed at once: about this many cells and triangles


def _too_many(count: int, settings: AtlasSettings) -> OvradError:
    return OvradError(
        f"these settings would make about {count:,} patches, "
        f"more than the limit of {settings.max_patches:,}; "
        "use a larger patch size or a smaller patch count/density, or raise the patch limit"
    )


def build_atlas(
    surfaces: Surfaces, settings: AtlasSettings, progress: StageCallback | None = None, backend: str = "auto"
) -> Atlas:
    """Cover the receiving surfaces with overlapping patches and integrate their overlaps (C).

    progress(fraction, message) may return False to cancel (raises OvradError).
    """
    return build_atlas_and_overlaps(surfaces, settings, progress, backend)[0]


class Built(NamedTuple):
    """What Generate makes: the atlas (as a file keeps it), its C (n x n, C[h, i] = c_ih), the
    quadrature C was integrated with (AtlasSettings.rule_order of the patches placed) and the
    patches' contact flags it was integrated with (n,) (contact.contact_flags)."""

    atlas: Atlas
    C: csr_matrix
    quadrature: int
    contacts: np.ndarray


def build_atlas_and_overlaps(
    surfaces: Surfaces, settings: AtlasSettings, progress: StageCallback | None = None, backend: str = "auto"
) -> Built:
    """build_atlas(), the C it integrated and the quadrature it took (Built).

    The atlas comes as a file keeps it (Atlas.as_stored) and C is integrated on that, so a solve
    of the stored atlas may use this C (overlap.py: a patch's row does not depend on the other
    patches integrated with it) instead of integrating it again, with the same quadrature.
    """
    report_stage(progress, 0.0, "finding charts")
    index = index_surfaces(surfaces, settings, backend)
    if len(index.sheet_chart) == 0:
        raise OvradError("no receiving surface: mark at least one object as a receiver")
    spacing = _sheet_spacing(index, settings)
    estimate = int(round(float(np.sum(index.sheet_area / spacing**2))))
    if estimate > settings.max_patches:  # refuse before allocating anything of that size
        raise _too_many(estimate, settings)
    report_stage(progress, 0.1, "placing patches")
    angles: dict[int, float] = {}  # each planar sheet's grid turn, the same at every spacing
    # with a target count, this first placement only sets the next spacing: its patches are never
    # kept (the loop below keeps the closest of the later ones), so it only counts them
    by_count = settings.patch_size is None
    placed, total = _place_all(index, settings, spacing, angles, count_only=by_count)
    if by_count and total <= settings.max_patches:
        # Boundary cells add to the count; one correction (count ~ 1 / spacing^2) brings it near
        # the target. Where it does not (many small charts, whose border patches make the count
        # go as 1 / spacing: the production room got 33 228 patches for 25 000), up to two more,
        # each with the exponent the last two placements showed; the closest count is kept.
        best, k = None, 2.0
        for step in range(3):
            if step and abs(total / settings.patch_count - 1.0) <= COUNT_TOLERANCE:
                break
            before = (spacing, total)
            spacing = spacing * (total / settings.patch_count) ** (1.0 / k)
            placed, total = _place_all(index, settings, spacing, angles)
            closer = best is None or abs(total - settings.patch_count) < abs(best[1] - settings.patch_count)
            if step == 0 or (closer and total <= settings.max_patches):
                best = (placed, total)
            if total > settings.max_patches or total <= 0:
                break
            ratio = float(np.max(spacing / before[0]))
            if ratio != 1.0 and total != before[1]:
                k = float(np.clip(np.log(before[1] / total) / np.log(ratio), 0.5, 3.0))
        placed, total = best
    if total > settings.max_patches:
        raise _too_many(total, settings)
    sheet = np.concatenate([np.full(len(p.radii), k) for k, p in enumerate(placed)])
    chart_obj = clutter_mod.chart_objects(surfaces, index.charts)
    triangle = np.concatenate([p.triangle for p in placed])
    n = total
    rng = np.random.default_rng(7)
    atlas = Atlas(
        centers=np.concatenate([p.centers for p in placed]),
        normals=np.concatenate([p.normals for p in placed]),
        tangents=np.concatenate([p.tangents for p in placed]),
        radii=np.concatenate([p.radii for p in placed]),
        shapes=np.concatenate([p.shapes for p in placed]),
        sheet=sheet,
        source_object=chart_obj[index.sheet_chart[sheet]],
        thickness=np.concatenate([p.thickness for p in placed]),
        min_cos=np.concatenate([p.min_cos for p in placed]),
        support_area=np.zeros(n),
        effective_area=np.zeros(n),
        overlap_count=np.zeros(n, np.int64),
        random=rng.random(n),
        beta=settings.beta,
        triangle=surfaces.local_triangle[triangle],
        side=index.sheet_side[sheet].astype(np.int8),
    )
    # Patches cut by contact lines (a partition standing on the floor): one per side (contact.py).
    # split as stored: the split atlas's contacts, found while splitting (cached on the index), are
    # then those of the atlas C is integrated on
    atlas = split_at_contacts(atlas.as_stored(), index).as_stored()
    quadrature = settings.rule_order(len(atlas))
    atlas, C, flags = integrate(atlas, index, quadrature, progress, 0.2)
    return Built(atlas, C, quadrature, flags)


def integrate(
    atlas: Atlas,
    index: SurfaceIndex,
    quadrature: int,
    progress: StageCallback | None = None,
    start: float = 0.0,
) -> tuple[Atlas, csr_matrix, np.ndarray]:
    """An atlas's overlap matrix C and areas (support, effective c_kk, overlap counts), its
    patches without support dropped, and the contact flags C was integrated with (n,)
    (contact.contact_flags): what Generate stores (build_atlas, and refine.py's children).
    progress runs from `start` to 1."""
    from .overlap import neighbour_pairs, overlap_matrix

    n = len(atlas)
    report_stage(progress, start, f"integrating overlaps of {n} patches")
    C, support = overlap_matrix(
        atlas,
        index,
        quadrature,
        progress=lambda f: report_stage(progress, start + (1.0 - start) * f, "integrating overlaps"),
    )
    C = C.tocsr()
    dropped = _to_drop(C, support)
    while np.any(dropped):
        # Patches with no support on their sheet: a face lying on another (a box's bottom on
        # the floor) is hidden by it, and light can never reach it; and patches that hold almost
        # none of the light where they lie (_to_drop). Drop them: C loses their rows
        # and columns. The rows of the patches next to them are integrated again without them:
        # a dropped patch still cut their rule's rays at its rim, and where faces coincide it may
        # have held some of their points; so C is the one a solve of the stored atlas integrates.
        h, i = neighbour_pairs(atlas)
        near = np.zeros(len(atlas), bool)
        near[h[dropped[i]]] = True
        keep = np.flatnonzero(~dropped)
        before, atlas = atlas, atlas.select(keep)
        carry_over(before, index, keep, atlas)
        C = C[keep][:, keep]
        support = support[keep]
        redo = np.flatnonzero(near[keep])
        if len(redo):
            again, area = overlap_matrix(atlas, index, quadrature, rows=redo)
            C = (diags((~near[keep]).astype(float)) @ C + again).tocsr()
            support[redo] = area[redo]
        dropped = _to_drop(C, support)
    C.eliminate_zeros()
    nz = (C + C.T).tocsr()
    nz.data[:] = 1
    counts = np.diff(nz.indptr) - (C.diagonal() > 0)
    flags = contact_flags(contacts(atlas, index))  # found while integrating: cached on the index
    atlas = replace(atlas, support_area=support, effective_area=C.diagonal().copy(), overlap_count=counts)
    return atlas, C, flags
