"""What the patches emit (their mean exitance, and the part bake points light themselves with),
which emitters are shot with shadow rays, and where the sky is worth casting rays to."""

import numpy as np

from ..light.direct import DirectLight
from ..overlap.queries import patch_average
from .problem import Problem

GATHER_Q = 4  # polar rule of the receiver points (transport, direct light, patch emission)

NEE_AREA_FRACTION = 0.1  # emitters covering less of the scene are shot with shadow rays


def patch_emission(problem: Problem, emission_scale: float = 1.0) -> np.ndarray:
    """Exitance E (n, 3) of each patch: pi x emitted radiance averaged over its support (read-only)."""
    return problem.cached(
        ("emission", float(emission_scale)),
        lambda: (
            np.pi
            * emission_scale
            * patch_average(
                problem.atlas,
                problem.index,
                problem.contacts,
                problem.surfaces.emission,
                GATHER_Q,
                problem.balls,
            )
        ),
    )


def own_emission(problem: Problem, emitters, emission_scale: float = 1.0) -> np.ndarray:
    """sampled_emission of the problem's patches (read-only): their exitance from the
    emitting triangles that bake points light themselves with."""
    flags = None if emitters is None else np.asarray(emitters, bool)
    key = ("own", float(emission_scale), None if flags is None else hash(np.packbits(flags).tobytes()))
    return problem.cached(key, lambda: sampled_emission(problem, flags, emission_scale))


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


def sampled_emission(
    problem: Problem, emitters: np.ndarray | None, scale: float = 1.0, q: int = 4
) -> np.ndarray:
    """(n, 3) exitance of each patch from the emitting triangles `emitters` ((T,) bool) only: the
    emission a bake point computes as direct light, which a gather must not count again."""
    atlas, index = problem.atlas, problem.index
    if emitters is None or not np.any(emitters) or scale == 0:
        return np.zeros((len(atlas), 3))
    em = index.surfaces.emission * np.asarray(emitters, bool)[:, None]
    return np.pi * scale * patch_average(atlas, index, problem.contacts, em, q, problem.balls)
