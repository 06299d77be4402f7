"""The solve: the light shot first to the receiver points by shadow rays (lamps, picked emitters,
the sky) within the ray budget, then progressive shooting of (C - R) B = C E (radiosity/solver.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.sparse import csc_matrix, diags, spmatrix

from ..errors import OvradError
from ..light.direct import DirectLight, EmitterRules, direct_irradiance, picked
from ..light.lamps import Lamp, area_side
from ..light.sky import Sky
from ..scene.surfaces import Surfaces
from ..settings import DEFAULT_SOLVE, SolveSettings
from .emission import patch_emission, sampled_emitters, sky_hidden
from .problem import Problem
from .solver import Progress as SolveProgressCallback
from .solver import SolveState, factorize, inverse_areas, solve_progressive
from .transport import ReceiverPoints, thinned_points

MIN_LIGHT_SAMPLES, MIN_SKY_SAMPLES = 4, 64  # per receiver point, under the ray budget (within_budget)

# The first shot's shadow rays per light source may reach this many times max_rays: the default
# atlas (2 000 smooth patches, 64 000 receiver points) keeps its 256 sky directions per point
# (16 M rays; at 8 M, the sky scenes' error is 4.0 / 5.2 % against 4.0 / 4.6 % at 16 M)
SHADOW_BUDGET = 4

# ... met for emitters picked on power first by a coarser rule of receiver points, down to this
# share of them (first_shot_points), then by fewer samples
MIN_FIRST_SHOT_SHARE = 0.25


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


def direct_light(
    problem: Problem,
    lamps: tuple[Lamp, ...] = (),
    settings: SolveSettings = DEFAULT_SOLVE,
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
        near_gather_rays=settings.near_gather_rays,
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
    points: ReceiverPoints,
    light: DirectLight,
    settings: SolveSettings,
    budget: int,
    source: Surfaces | EmitterRules,
):
    """The receiver points the first shot computes its direct light at: all of them, or, where
    emitters whose samples are picked on power would pass the shadow-ray budget (0: none), a
    coarser rule on every patch (radiosity.transport.thinned_points: pairs of points on opposite rule rays,
    at least one pair, at least MIN_FIRST_SHOT_SHARE of them) so that the emitters keep their full
    samples: there fewer samples widen the light tree's near field round every point and cost
    more than they save (emitter_sample_count). Lamps and the sky meet the budget with fewer samples,
    as before: the first shot's light is what the final gather reads off the patches it hits,
    and 2 of about 12 points per patch made the production room's 100 k bake worse (under a
    world: 5.29 -> 5.67 % at every vertex; a share of 0.25, 5.36 %)."""
    m = len(points.owner)
    per_point = settings.light_samples
    if budget <= 0 or m * per_point <= budget or not picked_emitters(source, light, per_point):
        return points
    return thinned_points(points, max(MIN_FIRST_SHOT_SHARE, budget / (m * per_point)))


def patch_piece(problem: Problem) -> float:
    """The least piece of an image emitter (DirectLight.emission_piece_size) for light that patches
    average: the atlas's median patch radius."""
    return float(np.median(problem.atlas.radii)) if len(problem.atlas) else 0.0


def picked_emitters(source: Surfaces | EmitterRules, light: DirectLight, samples: int) -> bool:
    """light has emitters, and `samples` of them are picked on power (light.direct.picked)."""
    emitters = light.emitters
    return (
        emitters is not None
        and bool(np.any(emitters))
        and picked(source, emitters, samples, light.emission_scale, light.emission_piece_size)
    )


def emitter_sample_count(
    source: Surfaces | EmitterRules, light: DirectLight, asked: int, budgeted: int
) -> int:
    """The emitters' samples per point (the first shot's receiver points, a gather's near hits):
    the budget's `budgeted`, but `asked` where they are picked on the power of more triangles than
    samples (light.direct.picked): there fewer samples stand farther apart and the light tree's near
    field around each point grows with them, which costs more rays and time than it saves (20 000
    points of the large interior, 4 / 8 / 16 samples: 27 / 20 / 17 rays per point, 3.3 / 1.8 /
    0.9 s)."""
    return asked if budgeted < asked and picked_emitters(source, light, asked) else budgeted


def solve(
    problem: Problem,
    lamps: tuple[Lamp, ...] = (),
    settings: SolveSettings = DEFAULT_SOLVE,
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
    radiosity.solver.SolveProgress (with the state) after each step; returning False cancels.
    """
    atlas = problem.atlas
    E = patch_emission(problem, emission_scale)
    C_solve = laplacian_smoothed(problem.C, settings.smoothing) if settings.rule == "exact" else problem.C
    lu = factorize(C_solve) if settings.rule == "exact" else None
    if state is None:
        T = problem.transport
        shadow_budget = int(SHADOW_BUDGET * settings.max_rays)
        # an image emitter's pieces no smaller than a patch: it averages finer detail away
        light = replace(
            direct_light(problem, lamps, settings, emission_scale, sky),
            emission_piece_size=patch_piece(problem),
        )
        rp = first_shot_points(T.points, light, settings, shadow_budget, problem.emitter_rules)
        points = len(rp.owner)
        samples = within_budget(settings.light_samples, points, shadow_budget, MIN_LIGHT_SAMPLES)
        if any(lamp.kind == "AREA" for lamp in lamps):
            # an area lamp casts area_side(samples)^2 rays per point (64 at the default 16)
            while samples > MIN_LIGHT_SAMPLES and area_side(samples) ** 2 * points > shadow_budget:
                samples -= 1
        light = replace(
            light,
            samples=samples,
            emitter_samples=emitter_sample_count(
                problem.emitter_rules, light, settings.light_samples, samples
            ),
            sky_samples=within_budget(settings.sky_samples, points, shadow_budget, MIN_SKY_SAMPLES),
        )
        small = bool(np.any(light.emitters))
        seen = None if T.sky_seen is None else T.sky_seen[rp.owner]
        rho = problem.surfaces.reflectance_at(rp.triangle, rp.points)
        # receivers that reflect nothing (an Emission shader's, a metal's) need no light
        lit = np.flatnonzero(np.any(rho > 0, axis=1))
        H = np.zeros((len(rho), 3))
        H[lit], direct_rays = direct_irradiance(
            problem.emitter_rules,
            problem.index.rays,
            light,
            rp.points[lit],
            rp.normals[lit],
            None if seen is None else seen[lit],
        )
        received = T.test(H, rho, rp)
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
