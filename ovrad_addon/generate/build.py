"""Building an atlas: spacing per sheet to the target count, placement on every sheet, clutter balls,
splits at contact lines, then C integrated and patches without support dropped."""

from __future__ import annotations

from dataclasses import fields as dataclass_fields
from dataclasses import replace
from typing import NamedTuple

import numpy as np
from scipy.sparse import csr_matrix, diags

from ..atlas import balls
from ..atlas import clutter as clutter_mod
from ..atlas.index import SurfaceIndex, index_surfaces, sheet_spacing
from ..atlas.patches import Atlas
from ..errors import OvradError
from ..geometry import ranges_flat, start_of
from ..overlap.contacts import contact_flags, contacts, split_at_contacts
from ..overlap.matrix import neighbour_pairs, overlap_matrix
from ..overlap.sight import Contacts
from ..progress import StageCallback, report_stage
from ..scene.surfaces import Surfaces
from ..settings import AtlasSettings
from .curved import SAMPLE_SPLIT, place_curved_many, sample_counts
from .planar import Placed, grid_angle, place_planar_many, place_planar_small

COUNT_TOLERANCE = 0.1  # a patch count this close to the target needs no second correction


def place_all(
    index: SurfaceIndex,
    settings: AtlasSettings,
    spacing: np.ndarray,
    angles: dict[int, float] | None = None,
    count_only: bool = False,
) -> tuple[list[Placed], int]:
    """Place patches sheet by sheet; each Placed's triangle holds global triangle indices. angles:
    planar sheets' grid angles (generate.planar.grid_angle) by sheet, kept across placements (filled here).
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
    for k, fields_k in balls.place_balls(index, spacing, settings.overlap).items():
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
    generate.curved.sample_sheets at spacing / 6, and the corners); a larger sheet alone."""
    if len(sheets) == 0:
        return []
    c = index.sheet_chart[sheets]
    tri = by_chart[ranges_flat(start[c], n_per[c])]
    gap = (spacing[sheets] / SAMPLE_SPLIT)[np.repeat(np.arange(len(sheets)), n_per[c])]
    per_tri = sample_counts(index.charts.areas[tri], gap) + 3
    cost = np.add.reduceat(per_tri, start_of(n_per[c]))
    # batch b takes the sheets whose cumulative cost falls in [b, b + 1) x CURVED_BATCH
    which = np.floor((np.cumsum(cost) - cost) / CURVED_BATCH).astype(np.int64)
    cut = np.flatnonzero(np.diff(which)) + 1
    return np.split(sheets, cut)


# A patch whose alpha averages under this over its support (c_kk / A_k) is dropped: it hangs
# almost wholly off its piece, and where its sliver of support lies other patches hold nearly all
# the light. Its row and column of C are then nearly empty but for their neighbours' terms, and
# the solve leaves its B free to ring: on the production room at 100 k patches (smooth beta), kept,
# a BoomBox patch resting on the floor, c_kk / A_k = 0.014 on 2.6 % of its disk, solves to B = 4.8
# where its neighbours have ~0.01, and lights 8 vertices up to 1.05 where Cycles has 0; the patches
# under 0.03 there (about 30 of 108 600, on the BoomBox and the bent tubes) hold every |B| over 2
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
    patches' contact flags it was integrated with (n,) (overlap.contacts.contact_flags)."""

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
    spacing = sheet_spacing(index, settings)
    estimate = int(round(float(np.sum(index.sheet_area / spacing**2))))
    if estimate > settings.max_patches:  # refuse before allocating anything of that size
        raise _too_many(estimate, settings)
    report_stage(progress, 0.1, "placing patches")
    angles: dict[int, float] = {}  # each planar sheet's grid turn, the same at every spacing
    # with a target count, this first placement only sets the next spacing: its patches are never
    # kept (the loop below keeps the closest of the later ones), so it only counts them
    by_count = settings.patch_size is None
    placed, total = place_all(index, settings, spacing, angles, count_only=by_count)
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
            placed, total = place_all(index, settings, spacing, angles)
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
    # Patches cut by contact lines (a partition standing on the floor): one per side (overlap/contacts.py).
    # split as stored: the split atlas's contacts, found while splitting, are then those of the atlas
    # C is integrated on (as_stored keeps a stored atlas's values)
    atlas, found = split_at_contacts(atlas.as_stored(), index)
    atlas = atlas.as_stored()
    quadrature = settings.rule_order(len(atlas))
    atlas, C, flags = integrate(atlas, index, quadrature, progress, 0.2, found)
    return Built(atlas, C, quadrature, flags)


def integrate(
    atlas: Atlas,
    index: SurfaceIndex,
    quadrature: int,
    progress: StageCallback | None = None,
    start: float = 0.0,
    found: Contacts | None = None,
) -> tuple[Atlas, csr_matrix, np.ndarray]:
    """An atlas's overlap matrix C and areas (support, effective c_kk, overlap counts), its
    patches without support dropped, and the contact flags C was integrated with (n,)
    (overlap.contacts.contact_flags): what Generate stores (build_atlas, and generate/refine.py's children).
    progress runs from `start` to 1. found: the atlas's contacts (split_at_contacts gives them); found
    here when None."""

    n = len(atlas)
    report_stage(progress, start, f"integrating overlaps of {n} patches")
    found = contacts(atlas, index) if found is None else found
    rule = balls.ball_rule(atlas, index)
    C, support = overlap_matrix(
        atlas,
        index,
        quadrature,
        found,
        balls=rule,
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
        atlas, found = atlas.select(keep), found.select(keep)
        rule = balls.ball_rule(atlas, index, rule)
        C = C[keep][:, keep]
        support = support[keep]
        redo = np.flatnonzero(near[keep])
        if len(redo):
            again, area = overlap_matrix(atlas, index, quadrature, found, rows=redo, balls=rule)
            C = (diags((~near[keep]).astype(float)) @ C + again).tocsr()
            support[redo] = area[redo]
        dropped = _to_drop(C, support)
    C.eliminate_zeros()
    nz = (C + C.T).tocsr()
    nz.data[:] = 1
    counts = np.diff(nz.indptr) - (C.diagonal() > 0)
    flags = contact_flags(found)
    atlas = replace(atlas, support_area=support, effective_area=C.diagonal().copy(), overlap_count=counts)
    return atlas, C, flags
