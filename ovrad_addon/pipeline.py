"""The whole solve on plain arrays: surfaces + atlas + lamps -> per-patch radiosity -> radiance at points.

prepare() does the heavy, light-independent work (sheets, C, transport G); solve() can then be
run again with other lamp powers or emission strengths without recomputing form factors.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse import csc_matrix, csr_matrix, diags, spmatrix

from .atlas import Atlas, SurfaceIndex, index_surfaces
from .clutter import clutter_from_atlas
from .contact import seed_contacts
from .direct import DirectLight, direct_irradiance, picked, triangle_normals
from .errors import OvradError
from .gather import (
    MAX_RAYS,
    NEAR_LIGHT_SAMPLES,
    NEAR_PICKED_SAMPLES,
    NEAR_SKY_SAMPLES,
    NearField,
    gather_axis,
    gather_unique,
    may_see_sky,
    sampled_emission,
)
from .kept_overlaps import KeptOverlaps, fitting, kept_contacts, stacked
from .lights import Lamp, area_side
from .memory import StagePeaks
from .overlap import alpha_at, overlap_matrix, patch_average, patch_quadrature, reconstruct
from .progress import StageCallback, report_stage
from .settings import AtlasSettings, ObjectSettings
from .sky import Sky
from .solver import Progress as SolveProgressCallback
from .solver import SolveState, factorize, inverse_areas, solve_progressive
from .surfaces import Surfaces
from .transport import ReceiverPoints, Transport, gather_transport, thinned_points

GATHER_Q = 4  # polar rule of the receiver points (transport, direct light, patch emission)
# Transport rays cast at most (SolveSettings.max_rays): 32 rays per receiver point reach it at
# about 16 000 box patches; larger atlases cast fewer per point (see gather_transport).
MAX_TRANSPORT_RAYS = 1 << 23
MIN_LIGHT_SAMPLES, MIN_SKY_SAMPLES = 4, 64  # per receiver point, under the ray budget (within_budget)
# The first shot's shadow rays per light source may reach this many times max_rays: the default
# atlas (2 000 smooth patches, 64 000 receiver points) keeps its 256 sky directions per point
# (16 M rays; at 8 M, the sky scenes' error went from 4.0 / 4.6 to 4.0 / 5.2 %)
SHADOW_BUDGET = 4
# ... met for emitters picked on power first by a coarser rule of receiver points, down to this
# share of them (first_shot_points), then by fewer samples
MIN_FIRST_SHOT_SHARE = 0.25
NEE_AREA_FRACTION = 0.1  # emitters covering less of the scene are shot with shadow rays


@dataclass(frozen=True)
class SolveSettings:
    """tolerance: stop when unshot power < tolerance x emitted power; rule: "exact" (eq. 9) or
    "paper" (the published update); rays_per_point: hemisphere rays per receiver point;
    batch: shooters per step at least (solver.solve_progressive); light_samples: emitter samples
    per receiver point (direct light);
    bake_samples: emitter samples per bake point (direct light at vertices and texels);
    smoothing: weight of the overlap-graph Laplacian added to C when solving (see laplacian_smoothed()),
    0 solves equation (9) exactly; min_rays: transport rays cast at least, in all (a small atlas
    gets more receiver points and rays per point, see gather_transport); max_rays: at most (a large
    atlas casts fewer per receiver point, MAX_TRANSPORT_RAYS); gather_rays: final-gather
    rays per bake point for its indirect light (gather.py), 0 reconstructs it from the patches
    (Cornell box, 2 086 patches, every vertex: 5.6 % relative RMS with 0, 3.5 / 2.4 / 1.9 % with
    64 / 128 / 256 rays for +2.9 / 3.9 / 6.1 s over 8 482 vertices; benchmarks/gather_bench.py);
    sky_samples / bake_sky_samples: world directions of the sky's fixed rule (sky.py) at the
    solve's receiver points / at bake points. Their error is aliasing, not noise: a window is
    seen along the few directions of the rule that pass through it. Measured in the real-scenes
    window room (2.4 m, 1 x 1 m window), floor and back wall against 16 384 directions, relative
    RMS per point: 22 / 12 / 6.7 / 3.9 % with 256 / 512 / 1024 / 2048 directions (constant sky;
    HDR sky with a sun 20 / 11 / 5.4 / 3.0 %), about 5 M shadow rays/s, half the directions facing
    a surface. The solve (~10^5 receiver points) takes 256, about 1.3 x 10^7 rays, the transport's
    order; the first shot feeds only the indirect light of bakes. Bake points take 1024."""

    tolerance: float = 1e-3
    rule: str = "exact"
    rays_per_point: int = 32
    batch: int = 64
    light_samples: int = 16
    smoothing: float = 0.1
    bake_samples: int = 64
    min_rays: int = 1 << 20
    max_rays: int = MAX_TRANSPORT_RAYS
    gather_rays: int = 256
    # Gather hits closer than a patch radius get their direct light computed where they land
    # (gather.NearField): Cornell box, 2 000 box patches, 256 rays, every vertex: 1.86 -> 1.65 %
    # relative RMS, vertices within 5 mm of another object +2.7 -> +1.6 % bias; bake time +30 %.
    near_field: bool = True
    sky_samples: int = 256
    bake_sky_samples: int = 1024
    # Far transport hits link to clusters of patches (clusters.py) whose cell diagonal is under
    # this many times the hit's distance; 0: alpha at every hit. Measured at every vertex against
    # Cycles, angle 0 / 0.125 / 0.25: at 100 k patches lamps_doorway 1.76 / 1.74 / 1.83 %, the
    # Cornell box 1.65 / 1.64 / 1.64 %, transport 15.1 / 11.8 / 11.6 s and 16.5 / 11.4 / 11.4 s
    # (scale_bench.py); at 2 000 patches (real_scenes_bench.py) doorway 1.62 / 1.63 / 1.51 %,
    # lamps_doorway 1.76 / 1.77 / 1.68 %, the other seven within 0.03 points. At 0.5 the doorway
    # went to 2.06 %: a large cluster seen near a receiver's horizon, or partly hidden, gives light
    # from where its rays do not land.
    cluster_angle: float = 0.125

    def __post_init__(self) -> None:
        if not (0 < self.tolerance < 1):
            raise OvradError(f"tolerance must be in (0, 1), got {self.tolerance}")
        if self.rule not in ("exact", "paper"):
            raise OvradError(f"rule must be 'exact' or 'paper', got {self.rule!r}")
        if not (0.0 <= self.smoothing <= 10.0):
            raise OvradError(f"smoothing must be in [0, 10], got {self.smoothing}")
        if not (1 <= self.rays_per_point <= 4096) or not (1 <= self.light_samples <= 1024):
            raise OvradError("rays_per_point must be in [1, 4096] and light_samples in [1, 1024]")
        if not (0 <= self.max_rays <= 1 << 30):
            raise OvradError(f"max_rays must be in [0, {1 << 30}], got {self.max_rays}")
        if not (0 <= self.min_rays <= 1 << 28):
            raise OvradError(f"min_rays must be in [0, {1 << 28}], got {self.min_rays}")
        if not (1 <= self.bake_samples <= 4096):
            raise OvradError(f"bake_samples must be in [1, 4096], got {self.bake_samples}")
        if not (2 <= self.sky_samples <= 1 << 16) or not (2 <= self.bake_sky_samples <= 1 << 16):
            raise OvradError("sky_samples and bake_sky_samples must be in [2, 65536]")
        if not (0.0 <= self.cluster_angle <= 2.0):
            raise OvradError(f"cluster_angle must be in [0, 2], got {self.cluster_angle}")
        if not (0 <= self.gather_rays <= MAX_RAYS):
            raise OvradError(f"gather_rays must be in [0, {MAX_RAYS}], got {self.gather_rays}")


@dataclass
class Problem:
    """Everything light-independent: index (sheets, rays), atlas with sheets attached (and its
    effective areas from the fine rule), C and the transport R (transport.py)."""

    surfaces: Surfaces
    atlas: Atlas
    index: SurfaceIndex
    C: csr_matrix
    transport: Transport
    rays: int
    seconds: dict
    kept: int = 0  # patches whose rows and columns of C were kept with the atlas (not integrated)
    memory: dict = field(default_factory=dict)  # peak resident MiB per stage (memory.py)
    # per-patch values every bake chunk needs (patch_emission, own_emission): integrated over every
    # patch once, not once per chunk (Cornell box, 100 k patches: the vertex bake took 136 s, now
    # 12-19 s). Not an init field: dataclasses.replace (other surfaces, another atlas) starts empty.
    cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

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
        sheet[todo] = _located_sheets(atlas.select(todo), index)
    if np.any(sheet < 0):
        raise OvradError(
            f"{int(np.sum(sheet < 0))} patches no longer lie on any surface: the meshes changed "
            "since the atlas was generated; generate the atlas again"
        )
    return replace(atlas, sheet=sheet)


def _located_sheets(atlas: Atlas, index: SurfaceIndex) -> np.ndarray:
    """Sheets found by locating each patch's centre on the surface (-1 where none is found)."""
    n = atlas.normals
    lift = atlas.thickness * 1.0001 + 1e-9 * index.surfaces.extent
    t, tri = index.rays.closest_hit(atlas.centers + lift[:, None] * n, -n, 2.0 * lift)
    side = np.where(np.einsum("ij,ij->i", index.charts.normals[np.maximum(tri, 0)], n) >= 0, 1, -1)
    sheet = index.sheet_of(tri, side)
    missing = np.flatnonzero(sheet < 0)
    if len(missing):
        # centre off the surface (a disk on a border cell): try the patch's rule points
        probe = replace(atlas, sheet=np.zeros(len(atlas), np.int64))
        views = {s: _all_sheets_view(index, s) for s in (1, -1)}
        for k in missing:
            # either side: the centre hit nothing, so it tells neither (the side whose rule
            # points land on the surface facing the patch's way is the patch's)
            best = (0, -1)
            for s, view in views.items():
                q = patch_quadrature(probe, view, np.array([k]), 4, rings=2, visibility=False)
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
    if kept:
        kept_contacts_of(atlas, index, fitting(surfaces, atlas, list(kept)))
    return Problem(surfaces, atlas, index, None, None, 0, {})


def prepare(
    surfaces: Surfaces,
    atlas: Atlas,
    settings: SolveSettings = SolveSettings(),
    quadrature: int | None = None,
    progress: StageCallback | None = None,
    backend: str = "auto",
    kept: Sequence[KeptOverlaps] = (),
    drop_unsupported: bool = False,
) -> Problem:
    """Sheets, the overlap matrix C and the transport R for an atlas (quadrature: see overlaps()).

    kept: blocks of C kept with the atlas (kept_overlaps.py); those whose key still fits are used,
    only the other patches' rows are integrated. drop_unsupported: patches whose support holds no
    surface are removed from the problem's atlas (refine.py's children off a sheet's border); by
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
        C, support, known = overlaps(surfaces, atlas, index, quadrature, kept, progress)
        if drop_unsupported and np.any(support <= 0):
            keep = np.flatnonzero(support > 0)
            atlas, C, support = atlas.select(keep), C.tocsr()[keep][:, keep], support[keep]
        atlas = replace(atlas, support_area=support, effective_area=C.diagonal().copy())
    seconds["overlap"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    with peaks.stage("transport"):
        T = gather_transport(
            atlas,
            index,
            settings.rays_per_point,
            progress=lambda f: report_stage(progress, 0.4 + 0.6 * f, "casting transport rays"),
            min_rays=settings.min_rays,
            max_rays=settings.max_rays,
            far=settings.cluster_angle,
        )
    seconds["transport"] = time.perf_counter() - t0
    return Problem(surfaces, atlas, index, C, T, T.rays, seconds, int(known.sum()), peaks.mb)


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
    if quadrature is None:
        quadrature = max((k.quadrature for k in kept), default=AtlasSettings().rule_order(len(atlas)))
    fit = fitting(surfaces, atlas, list(kept))
    known, C_kept = stacked(fit, len(atlas))
    kept_contacts_of(atlas, index, fit)  # before any row is integrated: the contacts C was integrated with
    todo = np.flatnonzero(~known)
    report_stage(progress, 0.05, "integrating overlaps" if len(todo) else "overlaps kept with the atlas")
    C, support = overlap_matrix(
        atlas,
        index,
        quadrature,
        progress=lambda f: report_stage(progress, 0.05 + 0.35 * f, "integrating overlaps"),
        rows=todo,
    )
    if C_kept is not None:
        C = (C + C_kept).tocsr()
        # exactly the row sums, as integrated C's are (its values come back in float32)
        support[known] = np.asarray(C_kept.sum(axis=1)).ravel()[known]
    return C, support, known


def kept_contacts_of(atlas: Atlas, index: SurfaceIndex, fit: Sequence[KeptOverlaps]) -> None:
    """Cache on `index` the contacts of `atlas` that the kept blocks `fit` (kept_overlaps.fitting)
    hold, the other patches' found again (contact.seed_contacts); nothing where none holds any."""
    flags, flagged = kept_contacts(list(fit), len(atlas))
    if flagged.any():
        seed_contacts(atlas, index, flags, flagged)


def laplacian_smoothed(C: spmatrix, weight: float) -> spmatrix:
    """C + weight L, L the Laplacian of the overlap graph (edge weights (c_ij + c_ji) / 2).

    Ray estimates of R carry noise, and C^-1 amplifies the part of it that oscillates between
    overlapping patches (C is ill-conditioned there, most with smooth beta and large overlaps):
    reconstructed light then rings, even below zero. L is zero on constant fields and nearly
    zero on smooth ones, so adding it damps only those oscillations; the solve then finds B with
    (C + wL - R) B = (C + wL) E. Measured on the Cornell box (3 000 smooth patches): the lowest
    reconstructed radiance goes from -0.44 to -0.04 (mean 0.228) with weight 0.1, and the
    lamp-lit plane and furnace tests keep their accuracy.
    """
    if weight <= 0:
        return C
    Cc = csc_matrix(C)
    W = (Cc + Cc.T) * 0.5
    W = W - diags(W.diagonal())
    return (Cc + weight * (diags(np.asarray(W.sum(axis=1)).ravel()) - W)).tocsc()


def patch_emission(problem: Problem, emission_scale: float = 1.0) -> np.ndarray:
    """Exitance E (n, 3) of each patch: pi x emitted radiance averaged over its support (read-only)."""
    return problem.cached(
        ("emission", float(emission_scale)),
        lambda: (
            np.pi
            * emission_scale
            * patch_average(problem.atlas, problem.index, problem.surfaces.emission, GATHER_Q)
        ),
    )


def own_emission(problem: Problem, emitters, emission_scale: float = 1.0) -> np.ndarray:
    """gather.sampled_emission of the problem's patches (read-only): their exitance from the
    emitting triangles that bake points light themselves with."""
    flags = None if emitters is None else np.asarray(emitters, bool)
    key = ("own", float(emission_scale), None if flags is None else hash(np.packbits(flags).tobytes()))
    return problem.cached(key, lambda: sampled_emission(problem.atlas, problem.index, flags, emission_scale))


def sampled_emitters(problem: Problem, emission_scale: float = 1.0) -> np.ndarray:
    """(T,) bool: the emitting triangles whose light is shot with shadow rays (the first shot).

    Small bright emitters (a light fixture) are: hemisphere rays would find them too rarely.
    Large emitters (a glowing wall, a furnace) are left to the rays, whose sums close exactly,
    where sampling them point to point would meet 1/d^2 near fields.
    """
    atlas = problem.atlas
    E = patch_emission(problem, emission_scale)
    emitting = np.abs(E).sum(axis=1) > 0
    small = atlas.effective_area[emitting].sum() <= NEE_AREA_FRACTION * atlas.effective_area.sum()
    surfaces = problem.surfaces
    # only emitters with patches: their light is what E holds (an emitter without an atlas is
    # ignored, and the operators say so)
    on = (surfaces.emission.sum(axis=1) > 0) & surfaces.receiver[surfaces.object_index]
    return on if small and emission_scale > 0 else np.zeros_like(on)


def sky_hidden(problem: Problem, escaped: int | None = None) -> bool:
    """No transport ray escaped the scene: no receiver sees out of it (a closed room), so a sky
    lights nothing. Its share of the hemisphere, averaged over the receivers, is below about one
    over the rays cast; leaving it out saves every sky ray of the first shot and the bakes (1 024
    per baked point and 256 per near gather hit: minutes on a production room under a world).
    escaped: the count a solve stored, for a problem without its transport (a reopened file)."""
    t = problem.transport
    if t is not None:
        return t.escaped == 0
    return escaped == 0


SKY_SHARE = 0.01  # a patch whose sky light is estimated below this share of all it receives


def sky_patches(
    problem: Problem, light: DirectLight, reflected: np.ndarray | None = None
) -> np.ndarray | None:
    """(n,) bool: the patches where bake points and near gather hits cast sky rays; None: all of
    them (or the light has no sky: then no point casts any).

    A patch none of whose transport rays escaped sees no sky (Transport.sky_seen). Given the solved
    light the patches reflect (n, 3) (radiosity less emission), neither does one whose sky light is
    under SKY_SHARE of all the light it receives: its share of the sky (the fraction of its
    cosine-distributed rays that escaped) x pi x the sky's mean radiance, against what it reflects
    over its albedo. A patch that cast too few rays to tell keeps the sky (Transport.sky_fraction
    NaN: following the patches overlapping it instead dropped the sky of border slivers that saw
    it, 0.9 % of the light of the production room's bake points under a grey world).

    A closed room under Blender's default grey world sees the sky through the cracks between its
    walls only (0.04 % of the production room's transport rays escaped); there 15 % of the near
    gather hits cast 256 sky rays each, 70 % of their shadow rays, for light a thousand times
    fainter than the lamp's. The estimate takes the sky's mean: a crack that looks at the sun of a
    map is underestimated.
    """
    t = problem.transport
    if light.sky is None or t is None or t.sky_seen is None:
        return None
    seen = np.asarray(t.sky_seen, bool)
    if reflected is None or t.sky_fraction is None:
        return seen
    fraction = np.asarray(t.sky_fraction, np.float64)
    known = np.isfinite(fraction)
    sky = np.pi * np.where(known, fraction, 0.0) * float(np.sum(light.sky.mean_radiance()))
    rho = np.sum(t.rho, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        received = np.maximum(np.sum(reflected, axis=1), 0.0) / rho
    # a black patch (no albedo) tells nothing of its light: it keeps the sky
    return seen & (~known | (rho <= 1e-6) | ~(sky < SKY_SHARE * received))


def bake_sky(problem: Problem, light: DirectLight, radiosity: np.ndarray) -> np.ndarray | None:
    """(n,) bool: the patches where bake points and near gather hits cast sky rays, given the
    solved radiosity (n, 3); None: all of them, or the light has no sky (then none casts any).

    The solve decides it (sky_patches: which patches' transport rays escaped, and how much sky light
    that is against the light they reflect) and stores it with the atlas (DirectLight.sky_patches):
    a bake after the file is reopened has no transport to ask, and would otherwise cast sky rays
    everywhere (3.6 times the bake time of the production room under a grey world)."""
    if light.sky is None:
        return None
    if light.sky_patches is not None:
        return np.asarray(light.sky_patches, bool)
    return sky_patches(problem, light, radiosity - patch_emission(problem, light.emission_scale))


def direct_light(
    problem: Problem,
    lamps: tuple[Lamp, ...] = (),
    settings: SolveSettings = SolveSettings(),
    emission_scale: float = 1.0,
    sky: Sky | None = None,
    escaped: int | None = None,
    sky_patches: np.ndarray | None = None,
) -> DirectLight:
    """The light a solve shoots first, as bake points compute it for themselves (a sky only
    where it can reach: sky_hidden). escaped, sky_patches: what a solve stored of the sky, for a
    problem without its transport (sky_hidden; DirectLight.sky_patches, bake_sky)."""
    if sky is not None and sky_hidden(problem, escaped):
        sky = None
    return DirectLight(
        tuple(lamps),
        sampled_emitters(problem, emission_scale),
        emission_scale,
        settings.bake_samples,
        settings.gather_rays,
        near_field=settings.near_field,
        sky=sky if sky is not None and sky.emits else None,
        sky_samples=settings.bake_sky_samples,
        sky_patches=sky_patches,
    )


def within_budget(samples: int, points: int, budget: int, floor: int) -> int:
    """Samples per receiver point for the first shot: `samples`, or fewer (never below floor)
    when points x samples would pass the transport's ray budget (0: none). A large atlas has
    small patches with many receiver points: each patch still gets about samples x its points."""
    if budget <= 0 or points * samples <= budget:
        return samples
    return max(min(floor, samples), budget // max(points, 1))


def first_shot_points(
    points: ReceiverPoints, light: DirectLight, settings: SolveSettings, budget: int, surfaces: Surfaces
):
    """The receiver points the first shot computes its direct light at: all of them, or, where
    emitters whose samples are picked on power would pass the shadow-ray budget (0: none), a
    coarser rule on every patch (transport.thinned_points: pairs of points on opposite rule rays,
    at least one pair, at least MIN_FIRST_SHOT_SHARE of them) so that the emitters keep their full
    samples: there fewer samples widen the light tree's near field round every point and cost
    more than they save (emitter_samples). Lamps and the sky meet the budget with fewer samples,
    as before: the first shot's light is what the final gather reads off the patches it hits,
    and 2 of about 12 points per patch made the production room's 100 k bake worse (under a
    world: 5.29 -> 5.67 % at every vertex; a share of 0.25, 5.36 %)."""
    m = len(points.owner)
    per_point = settings.light_samples
    if budget <= 0 or m * per_point <= budget or not picked_emitters(surfaces, light, per_point):
        return points
    return thinned_points(points, max(MIN_FIRST_SHOT_SHARE, budget / (m * per_point)))


def picked_emitters(surfaces: Surfaces, light: DirectLight, samples: int) -> bool:
    """light has emitters, and `samples` of them are picked on power (direct.picked)."""
    emitters = light.emitters
    return (
        emitters is not None
        and bool(np.any(emitters))
        and picked(surfaces, emitters, samples, light.emission_scale)
    )


def emitter_samples(surfaces: Surfaces, light: DirectLight, asked: int, budgeted: int) -> int:
    """The emitters' samples per point (the first shot's receiver points, a gather's near hits):
    the budget's `budgeted`, but `asked` where they are picked on the power of more triangles than
    samples (direct.picked): there fewer samples stand farther apart and the light tree's near
    field around each point grows with them, which costs more rays and time than it saves (20 000
    points of the large interior, 4 / 8 / 16 samples: 27 / 20 / 17 rays per point, 3.3 / 1.8 /
    0.9 s)."""
    return asked if budgeted < asked and picked_emitters(surfaces, light, asked) else budgeted


def solve(
    problem: Problem,
    lamps: tuple[Lamp, ...] = (),
    settings: SolveSettings = SolveSettings(),
    emission_scale: float = 1.0,
    progress: SolveProgressCallback = None,
    state: SolveState | None = None,
    sky: Sky | None = None,
) -> SolveState:
    """Progressive solve of (C - R) B = C E, with lamps, emitters and the sky shot first explicitly.

    The first shot sends the lamps', the emitters' and the sky's light straight to the receiver
    points (shadow rays; a coarser rule of them under the ray budget for emitters picked on power:
    first_shot_points), which is far more accurate for small bright sources than hemisphere rays.
    The sky enters only there: transport rays that escape the scene still bring nothing.
    Radiosity B (n, 3) is exitance in W/m^2; radiance is B / pi. progress receives a
    solver.SolveProgress (with the state) after each step; returning False cancels.
    """
    atlas = problem.atlas
    E = patch_emission(problem, emission_scale)
    C_solve = laplacian_smoothed(problem.C, settings.smoothing) if settings.rule == "exact" else problem.C
    lu = factorize(C_solve) if settings.rule == "exact" else None
    if state is None:
        T = problem.transport
        shadow_budget = int(SHADOW_BUDGET * settings.max_rays)
        light = direct_light(problem, lamps, settings, emission_scale, sky)
        rp = first_shot_points(T.points, light, settings, shadow_budget, problem.surfaces)
        points = len(rp.owner)
        samples = within_budget(settings.light_samples, points, shadow_budget, MIN_LIGHT_SAMPLES)
        if any(lamp.kind == "AREA" for lamp in lamps):
            # an area lamp casts area_side(samples)^2 rays per point (64 at the default 16)
            while samples > MIN_LIGHT_SAMPLES and area_side(samples) ** 2 * points > shadow_budget:
                samples -= 1
        light = replace(
            light,
            samples=samples,
            emitter_samples=emitter_samples(problem.surfaces, light, settings.light_samples, samples),
            sky_samples=within_budget(settings.sky_samples, points, shadow_budget, MIN_SKY_SAMPLES),
        )
        small = bool(np.any(light.emitters))
        seen = None if T.sky_seen is None else T.sky_seen[rp.owner]
        H, direct_rays = direct_irradiance(
            problem.surfaces, problem.index.rays, light, rp.points, rp.normals, seen
        )
        received = T.test(H, problem.surfaces.reflectance_at(rp.triangle, rp.points), rp)
        if not np.any(received > 0) and not np.any(E > 0):
            if sky is not None and sky.emits:
                raise OvradError(
                    "no light: only the world emits, and its light reaches no surface with an atlas "
                    "(open the scene to the sky, or add a lamp or an emissive material)"
                )
            raise OvradError(
                "no light: nothing in the scene emits (add a lamp, an emissive material or world light)"
            )
        if settings.rule == "exact":
            dB = lu.solve(received)
        else:
            inv = inverse_areas(atlas.support_area)[:, None]
            dB = (problem.C.T @ (received * inv)) * inv
        unshot = dB if small else dB + E
        state = SolveState(radiosity=E + dB, unshot=unshot, rays=problem.rays + direct_rays, first_shot=dB)
        if not np.any(np.abs(state.unshot) > 0):
            state.converged = True
            return state
    return solve_progressive(
        C_solve,
        problem.transport,
        E,
        tolerance=settings.tolerance,
        batch=settings.batch,
        rule=settings.rule,
        support_area=atlas.support_area,
        progress=progress,
        state=state,
        reference_power=float(np.sum(atlas.effective_area[:, None] * np.abs(state.radiosity))),
        lu=lu,
    )


def without_area(problem: Problem, triangles) -> np.ndarray:
    """(m,) bool: triangles (m,) without area (no chart: three points on a line; see bake_normals)."""
    return problem.index.charts.chart[np.asarray(triangles, np.int64)] < 0


def bake_sides(problem: Problem, triangles) -> np.ndarray:
    """(m,) int64 +1 or -1: the side of each triangle a bake reconstructs, the front where the
    front sheet of its chart holds patches, else the back (an open mesh whose patches lie on its
    back only); the front of a triangle without area (bake_normals). One rule for every bake point
    of a triangle, so vertices and texels agree."""
    tri = np.asarray(triangles, np.int64)
    index = problem.index
    occupied = np.bincount(problem.atlas.sheet, minlength=len(index.sheet_chart)) > 0
    front = index.sheet_of(tri, np.ones(len(tri), np.int64))
    lit_front = ((front >= 0) & occupied[np.maximum(front, 0)]) | without_area(problem, tri)
    return np.where(lit_front, 1, -1).astype(np.int64)


def bake_normals(problem: Problem, triangles, sides) -> np.ndarray:
    """(m, 3) unit normals a bake sees triangles (m,) by, from their sides (m,) (bake_sides). A
    triangle without area (three points on a line) has no normal of its own: like Blender, which
    shades such a face as facing +Z, its points are lit as a point facing +Z (not left black: a
    vertex of zero-area triangles only is still a vertex of the mesh, and Cycles bakes it lit)."""
    tri = np.asarray(triangles, np.int64)
    normals = triangle_normals(problem.surfaces, tri) * np.asarray(sides)[:, None]
    normals[without_area(problem, tri)] = (0.0, 0.0, 1.0)
    return normals


def _at_points(
    problem: Problem,
    radiosity,
    points,
    triangles,
    sides,
    first_shot,
    light,
    gather_points=None,
    indirect=None,
    gather_normals=None,
    corner_cache=None,
):
    """What both reconstructions need at surface points: triangles (m,), alpha (m, n), the
    coefficients the patches reconstruct, and the direct irradiance (m, 3) computed at the points
    where the solve's first shot is split off (else None). gather_points (m, 3): where the final
    gather casts its rays from (default: the points), gathered once per distinct position and normal;
    indirect (m, 3): the gathered irradiance itself, computed by the caller (e.g. at fewer points
    and interpolated), used instead of gathering; gather_normals (m, k, 3): the weighted normals each
    point's gather stands for (gather.shared_normals; default: the point's own normal). corner_cache:
    see gather.gather_indirect (a dict kept over one bake's calls)."""
    tri = np.asarray(triangles, np.int64)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    side = np.broadcast_to(np.asarray(sides), tri.shape)
    a = alpha_at(problem.atlas, problem.index, pts, tri, side)
    if first_shot is None or light is None:
        return tri, a, radiosity, None
    if first_shot.shape != radiosity.shape:
        raise OvradError("the first shot does not match the radiosity: solve again")
    normals = bake_normals(problem, tri, side)
    seen = bake_sky(problem, light, radiosity)
    sky_at = may_see_sky(a, seen)
    H = direct_irradiance(problem.surfaces, problem.index.rays, light, pts, normals, sky_at)[0]
    covered = np.asarray(a.sum(axis=1)).ravel() > 0
    coeffs = radiosity - first_shot
    # --- final gather (gather.py): the indirect light comes from rays cast at the points, the
    # patches give only the points' own emission; a point needs no patch, only a lit side (sheet)
    if light.gather_rays > 0:
        index = problem.index
        own = own_emission(problem, light.emitters, light.emission_scale)
        coeffs = patch_emission(problem, light.emission_scale)
        if indirect is not None:
            H = H + np.asarray(indirect, np.float64).reshape(-1, 3)
        else:
            near = None
            if light.near_field:
                few = min(light.samples, NEAR_LIGHT_SAMPLES)
                near_light = replace(
                    light,
                    samples=few,
                    emitter_samples=emitter_samples(
                        problem.surfaces, light, min(light.samples, NEAR_PICKED_SAMPLES), few
                    ),
                    sky_samples=min(light.sky_samples, NEAR_SKY_SAMPLES),
                    area_jittered=True,
                )
                near = NearField(near_light, radiosity - first_shot - coeffs, coeffs - own, sky_seen=seen)
            at = pts if gather_points is None else np.asarray(gather_points, np.float64).reshape(-1, 3)
            if gather_normals is None:
                H = H + gather_unique(
                    problem,
                    radiosity,
                    own,
                    at,
                    normals,
                    light.gather_rays,
                    tri,
                    near=near,
                    corner_cache=corner_cache,
                )
            else:
                spread = np.asarray(gather_normals, np.float64)
                spread = spread.reshape(len(pts), spread.shape[-2], 3)
                axis = gather_axis(spread)
                rays = light.gather_rays
                H = H + gather_unique(
                    problem,
                    radiosity,
                    own,
                    at,
                    axis,
                    rays,
                    tri,
                    near=near,
                    spread=spread,
                    corner_cache=corner_cache,
                )
        covered = (index.sheet_of(tri, side) >= 0) | without_area(problem, tri)  # see bake_normals
    # --- end of final gather
    return tri, a, coeffs, np.where(covered[:, None], H, 0.0)


def radiance_at(
    problem: Problem,
    radiosity: np.ndarray,
    points,
    triangles,
    sides=1,
    first_shot: np.ndarray | None = None,
    light: DirectLight | None = None,
    gather_points=None,
    indirect=None,
    gather_normals=None,
    corner_cache=None,
) -> np.ndarray:
    """Outgoing radiance L = B / pi (m, 3) reconstructed at surface points; 0 where no patch covers.

    With the solve's first shot and its direct light, the points get their direct light computed
    where they are (shadow rays) and only the rest of the radiosity from the patches. The light a
    point reflects is its own albedo (surfaces.reflectance_at: a texture's where there is one)
    times the irradiance there. gather_points, indirect, gather_normals: where and about what the
    final gather casts, or its result; corner_cache: a dict kept over one bake's calls (see
    _at_points).
    """
    gather = (gather_points, indirect, gather_normals, corner_cache)
    tri, a, coeffs, H = _at_points(problem, radiosity, points, triangles, sides, first_shot, light, *gather)
    surfaces = problem.surfaces
    albedo = surfaces.reflectance_at(tri, np.asarray(points, np.float64).reshape(-1, 3))
    out = reconstruct(a, coeffs)
    textured = _textured(surfaces, tri)
    if np.any(textured):
        # a patch holds its mean albedo x its light: the reflected light the patches reconstruct
        # on a textured triangle takes the texture's detail, as albedo(M) / the triangle's mean
        E = patch_emission(problem, light.emission_scale if light is not None else 1.0)
        reflected = reconstruct(a[textured], coeffs - E)
        rho = surfaces.reflectance[tri[textured]]
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = np.where(rho > 0, albedo[textured] / rho, 0.0)
        out[textured] += reflected * (gain - 1.0)
    if H is not None:
        out += albedo * H
    return out / np.pi


def _textured(surfaces: Surfaces, triangles: np.ndarray) -> np.ndarray:
    """(m,) bool: which of the triangles have an albedo texture."""
    if surfaces.albedo is None:
        return np.zeros(len(triangles), bool)
    return surfaces.albedo.image_of[triangles] >= 0


def irradiance_at(
    problem: Problem,
    radiosity: np.ndarray,
    points,
    triangles,
    sides=1,
    first_shot: np.ndarray | None = None,
    light: DirectLight | None = None,
    gather_points=None,
    indirect=None,
    gather_normals=None,
    corner_cache=None,
) -> np.ndarray:
    """Light arriving at surface points without the surface's albedo: H / pi (m, 3), in the units
    of radiance (a white surface's radiance), from B(M) - E(M) = rho(M) H(M); 0 where rho is 0
    (direct light at the points where it is split off, as in radiance_at). On a textured triangle
    the patches' reflected light is divided by the triangle's mean albedo, what they hold."""
    gather = (gather_points, indirect, gather_normals, corner_cache)
    tri, a, coeffs, H = _at_points(problem, radiosity, points, triangles, sides, first_shot, light, *gather)
    E = patch_emission(problem, light.emission_scale if light is not None else 1.0)
    reflected = reconstruct(a, coeffs - E)
    rho = problem.surfaces.reflectance[tri]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.where(rho > 0, reflected / rho, 0.0)
    if H is not None:
        out += H
    return out / np.pi
