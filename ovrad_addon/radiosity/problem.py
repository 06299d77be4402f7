"""The prepared problem: surfaces indexed, patches re-attached to their sheets, C and the transport R.

prepare() does the heavy, light-independent work (sheets, C, transport G); solve() can then be
run again with other lamp powers or emission strengths without recomputing form factors.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse import csr_matrix

from ..atlas.balls import BallRule, ball_rule
from ..atlas.clutter import clutter_from_atlas
from ..atlas.index import SurfaceIndex, index_surfaces
from ..atlas.patches import Atlas
from ..errors import OvradError
from ..light.direct import EmitterRules
from ..memory import StagePeaks
from ..overlap.contacts import COARSE_Q, COARSE_RINGS, contacts, seed_contacts
from ..overlap.cuts import THICKNESS_LIFT
from ..overlap.kept import KeptOverlaps, fitting, kept_contacts, stacked
from ..overlap.matrix import overlap_matrix
from ..overlap.quadrature import patch_quadrature
from ..overlap.sight import Contacts
from ..progress import StageCallback, report_stage
from ..scene.surfaces import Surfaces
from ..settings import DEFAULT_SOLVE, AtlasSettings, ObjectSettings, SolveSettings
from .transport import Transport, gather_transport


@dataclass
class Problem:
    """Everything light-independent: index (sheets, rays), atlas with sheets attached (and its
    effective areas from the fine rule), its contacts and clutter samples on the index (found once
    here, for every alpha lookup and quadrature after), C and the transport R (radiosity/transport.py)."""

    surfaces: Surfaces
    atlas: Atlas
    index: SurfaceIndex
    contacts: Contacts
    balls: BallRule
    C: csr_matrix
    transport: Transport
    rays: int
    seconds: dict
    kept: int = 0  # patches whose rows and columns of C were kept with the atlas (not integrated)
    memory: dict = field(default_factory=dict)  # peak resident MiB per stage (ovrad_addon/memory.py)
    # per-patch values every bake chunk needs (patch_emission, own_emission): integrated over every
    # patch once, not once per chunk (Cornell box, 100 k patches: the vertex bake takes 12-19 s,
    # against 136 s integrating them per chunk). Not an init field: dataclasses.replace (other
    # surfaces, another atlas) starts empty.
    cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    # the emitters' sample rules and light trees, made once for the solve and every bake of it
    emitter_rules: EmitterRules = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.emitter_rules = EmitterRules(self.surfaces)

    def cached(self, key, compute):
        """compute(), once per key for this problem; the array comes back read-only."""
        if key not in self.cache:
            value = compute()
            value.setflags(write=False)
            self.cache[key] = value
        return self.cache[key]


def _stored_sheets(atlas: Atlas, index: SurfaceIndex) -> np.ndarray:
    """Sheets from the atlas's own triangle and side (-1 where it has none, or they no longer fit).

    The stored triangle must still hold the patch: the patch centre within the patch's thickness
    of the triangle's plane (a border square's centre may lie beyond the triangle, never off its
    plane); otherwise the mesh changed and the patch is located by search instead.
    """
    n = len(atlas)
    if atlas.triangle is None or atlas.side is None:
        return np.full(n, -1, np.int64)
    s = index.surfaces
    tri = s.global_triangle(atlas.source_object, atlas.triangle)
    side = np.where(np.asarray(atlas.side) < 0, -1, 1)
    sheet = np.where(np.asarray(atlas.side) != 0, index.sheet_of(tri, side), -1)
    ok = np.flatnonzero(sheet >= 0)
    t = tri[ok]
    height = np.einsum("ij,ij->i", atlas.centers[ok] - s.corners[t, 0], index.charts.normals[t])
    # float32 attributes: centres carry ~1e-7 relative rounding
    tol = 1.5 * atlas.thickness[ok] + 1e-6 * s.extent
    sheet[ok[np.abs(height) > tol]] = -1
    return sheet


def attach_sheets(atlas: Atlas, index: SurfaceIndex) -> Atlas:
    """Give each patch the sheet index of this index: from the triangle and side the atlas stores,
    else (atlases made before they were stored, or meshes changed) by locating its centre.

    Sheet numbers depend on which meshes were read and in what order; an atlas read back from
    Blender is re-attached this way, so it does not matter how the scene was read when it was made.
    """
    sheet = _stored_sheets(atlas, index)
    todo = np.flatnonzero(sheet < 0)
    if len(todo):
        sheet[todo] = located_sheets(atlas.select(todo), index)
    if np.any(sheet < 0):
        raise OvradError(
            f"{int(np.sum(sheet < 0))} patches no longer lie on any surface: the meshes changed "
            "since the atlas was generated; generate the atlas again"
        )
    return replace(atlas, sheet=sheet)


def located_sheets(atlas: Atlas, index: SurfaceIndex) -> np.ndarray:
    """Sheets found by locating each patch's centre on the surface (-1 where none is found)."""
    n = atlas.normals
    lift = atlas.thickness * THICKNESS_LIFT + 1e-9 * index.surfaces.extent
    t, tri = index.rays.closest_hit(atlas.centers + lift[:, None] * n, -n, 2.0 * lift)
    side = np.where(np.einsum("ij,ij->i", index.charts.normals[np.maximum(tri, 0)], n) >= 0, 1, -1)
    sheet = index.sheet_of(tri, side)
    missing = np.flatnonzero(sheet < 0)
    if len(missing):
        # centre off the surface (a disk on a border cell): try the patch's rule points
        probe = replace(atlas, sheet=np.zeros(len(atlas), np.int64))
        views = {s: _all_sheets_view(index, s) for s in (1, -1)}
        rules = {s: ball_rule(probe, view) for s, view in views.items()}
        for k in missing:
            # either side: the centre hit nothing, so it tells neither (the side whose rule
            # points land on the surface facing the patch's way is the patch's)
            best = (0, -1)
            for s, view in views.items():
                q = patch_quadrature(
                    probe, view, np.array([k]), COARSE_Q, rings=COARSE_RINGS, visibility=None, balls=rules[s]
                )
                hit = q.triangle[q.triangle >= 0]
                if len(hit) > best[0]:
                    best = (len(hit), int(index.sheet_of(hit[:1], np.array([s]))[0]))
            sheet[k] = best[1]
    return sheet


def _all_sheets_view(index: SurfaceIndex, side: int) -> SurfaceIndex:
    """An index whose every sheet is 0, on `side`, so rule points are accepted on any sheet's
    that side (for locating)."""
    return replace(
        index,
        sheet_table=np.zeros_like(index.sheet_table),
        sheet_side=np.full_like(index.sheet_side, side),
    )


def both_sides_index(surfaces: Surfaces, backend: str = "auto", atlas: Atlas | None = None) -> SurfaceIndex:
    """The surfaces indexed with both sides of every chart as a sheet (sides=BOTH on every object):
    the index a solve and a reconstruction use, whatever sides the atlas was generated with (its
    patches only occupy the sheets they lie on). The clutter charts are those `atlas` was
    generated with (clutter.py), none without an atlas."""
    sides = AtlasSettings(objects=tuple(ObjectSettings(sides="BOTH") for _ in surfaces.object_names))
    index = index_surfaces(surfaces, sides, backend, clutter=np.zeros(0, bool))
    return index if atlas is None else index.with_clutter(clutter_from_atlas(index, atlas))


def locate(
    surfaces: Surfaces, atlas: Atlas, backend: str = "auto", kept: Sequence[KeptOverlaps] = ()
) -> Problem:
    """A problem for reconstruction only (no C, no transport): the surfaces indexed as prepare()
    indexes them and the patches re-attached to their sheets. Much cheaper than prepare(). kept:
    blocks of C kept with the atlas; the contacts of those that fit are taken from them."""
    index = both_sides_index(surfaces, backend, atlas)
    atlas = attach_sheets(atlas, index)
    found = contacts_of(atlas, index, fitting(surfaces, atlas, list(kept)) if kept else [])
    return Problem(surfaces, atlas, index, found, ball_rule(atlas, index), None, None, 0, {})


def prepare(
    surfaces: Surfaces,
    atlas: Atlas,
    settings: SolveSettings = DEFAULT_SOLVE,
    quadrature: int | None = None,
    progress: StageCallback | None = None,
    backend: str = "auto",
    kept: Sequence[KeptOverlaps] = (),
    drop_unsupported: bool = False,
) -> Problem:
    """Sheets, the overlap matrix C and the transport R for an atlas (quadrature: see overlaps()).

    kept: blocks of C kept with the atlas (overlap/kept.py); those whose key still fits are used,
    only the other patches' rows are integrated. drop_unsupported: patches whose support holds no
    surface are removed from the problem's atlas (generate/refine.py's children off a sheet's border); by
    default the atlas is kept as given, patch for patch (the operators write results back to it)."""
    if len(atlas) == 0:
        raise OvradError("the atlas has no patches: generate an atlas first")
    seconds = {}
    peaks = StagePeaks()
    t0 = time.perf_counter()
    report_stage(progress, 0.0, "indexing surfaces")
    with peaks.stage("index"):
        index = both_sides_index(surfaces, backend, atlas)
        atlas = attach_sheets(atlas, index)
    seconds["index"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with peaks.stage("overlap"):
        fit = fitting(surfaces, atlas, list(kept))
        found = contacts_of(atlas, index, fit)  # before any row is integrated: those C was integrated with
        balls = ball_rule(atlas, index)
        C, support, known = _overlaps(
            atlas, index, _rule_order(quadrature, atlas, kept), fit, found, balls, progress
        )
        if drop_unsupported and np.any(support <= 0):
            keep = np.flatnonzero(support > 0)
            atlas, C, support = atlas.select(keep), C.tocsr()[keep][:, keep], support[keep]
            found, balls = found.select(keep), ball_rule(atlas, index, balls)
        atlas = replace(atlas, support_area=support, effective_area=C.diagonal().copy())
    seconds["overlap"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with peaks.stage("transport"):
        T = gather_transport(
            atlas,
            index,
            found,
            settings.rays_per_point,
            progress=lambda f: report_stage(progress, 0.4 + 0.6 * f, "casting transport rays"),
            min_rays=settings.min_rays,
            max_rays=settings.max_rays,
            far=settings.cluster_angle,
            balls=balls,
        )
    seconds["transport"] = time.perf_counter() - t0
    return Problem(surfaces, atlas, index, found, balls, C, T, T.rays, seconds, int(known.sum()), peaks.mb)


def overlaps(
    surfaces: Surfaces,
    atlas: Atlas,
    index: SurfaceIndex,
    quadrature: int | None = None,
    kept: Sequence[KeptOverlaps] = (),
    progress: StageCallback | None = None,
) -> tuple[csr_matrix, np.ndarray, np.ndarray]:
    """C and the support areas of an atlas (sheets attached to index), from the kept blocks that
    still fit and integration of the other rows; and known (n,) bool, the rows the kept blocks gave.
    quadrature: the rule of the rows integrated here; None: the kept blocks' (the finest of them),
    else AtlasSettings.rule_order of the atlas's size (what Generate would choose)."""
    fit = fitting(surfaces, atlas, list(kept))
    found = contacts_of(atlas, index, fit)  # before any row is integrated: those C was integrated with
    return _overlaps(atlas, index, _rule_order(quadrature, atlas, kept), fit, found, None, progress)


def _rule_order(quadrature: int | None, atlas: Atlas, kept: Sequence[KeptOverlaps]) -> int:
    """The rule of the rows integrated (overlaps())."""
    if quadrature is None:
        return max((k.quadrature for k in kept), default=AtlasSettings().rule_order(len(atlas)))
    return quadrature


def _overlaps(
    atlas: Atlas,
    index: SurfaceIndex,
    quadrature: int,
    fit: Sequence[KeptOverlaps],
    found: Contacts,
    balls: BallRule | None,
    progress: StageCallback | None,
) -> tuple[csr_matrix, np.ndarray, np.ndarray]:
    """overlaps() with the fitting kept blocks, the atlas's contacts and clutter samples found."""
    known, C_kept = stacked(list(fit), len(atlas))
    todo = np.flatnonzero(~known)
    report_stage(progress, 0.05, "integrating overlaps" if len(todo) else "overlaps kept with the atlas")
    C, support = overlap_matrix(
        atlas,
        index,
        quadrature,
        found,
        progress=lambda f: report_stage(progress, 0.05 + 0.35 * f, "integrating overlaps"),
        rows=todo,
        balls=balls,
    )
    if C_kept is not None:
        C = (C + C_kept).tocsr()
        # exactly the row sums, as integrated C's are (its values come back in float32)
        support[known] = np.asarray(C_kept.sum(axis=1)).ravel()[known]
    return C, support, known


def contacts_of(atlas: Atlas, index: SurfaceIndex, fit: Sequence[KeptOverlaps]) -> Contacts:
    """The contacts of `atlas` on `index`: those the kept blocks `fit` (overlap.kept.fitting) hold,
    the other patches' found again (overlap.contacts.seed_contacts); all found
    (overlap.contacts.contacts) where none holds any."""
    flags, flagged = kept_contacts(list(fit), len(atlas))
    seeded = seed_contacts(atlas, index, flags, flagged) if flagged.any() else None
    return contacts(atlas, index) if seeded is None else seeded
