"""Radiance and irradiance at bake points (vertices, texels): direct light computed where they are,
the indirect light from the final gather, or from the patches when the gather is off."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import OvradError
from ..light.direct import DirectLight, direct_irradiance, triangle_normals
from ..overlap.queries import alpha_at, reconstruct
from ..radiosity.emission import bake_sky, own_emission, patch_emission
from ..radiosity.first_shot import emitter_sample_count, patch_piece
from ..radiosity.problem import Problem
from ..scene.surfaces import per_albedo
from .gather import (
    GATHER_SEED,
    NEAR_LIGHT_SAMPLES,
    NEAR_PICKED_SAMPLES,
    NEAR_SKY_SAMPLES,
    Gather,
    gather_axis,
    gather_unique,
)
from .lattice import NearField, may_see_sky

NUDGE = 1e-3  # bake points on a chart's border are moved this many patch radii into their triangle


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


def nudge(problem: Problem, points: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """points (k, 3) moved NUDGE x the median patch radius towards centres (k, 3) (their triangles'
    centroids), at most half way: a point on a chart's border lies on the rim of the patches placed
    along it."""
    to_centre = centres - points
    dist = np.linalg.norm(to_centre, axis=1, keepdims=True)
    step = np.minimum(NUDGE * float(np.median(problem.atlas.radii)), 0.5 * dist)
    return points + to_centre * (step / np.maximum(dist, 1e-300))


@dataclass(frozen=True)
class BakeRequest:
    """What a bake asks at its points: the solved radiosity (n, 3); the solve's first shot (n, 3) and
    its light (DirectLight): with both, the points get their direct light computed where they are
    and only the rest from the patches (else all of it from the patches). For the final gather
    (light.gather_rays > 0): gather_points (m, 3) where it casts its rays from (default: the points),
    gathered once per distinct position and normal; indirect (m, 3) the gathered irradiance itself,
    computed by the caller (e.g. at fewer points and interpolated), used instead of gathering;
    gather_normals (m, k, 3) the weighted normals each point's gather stands for
    (bake.gather.shared_normals; default: the point's own normal); corner_cache: a dict kept over one
    bake's calls (bake.gather.gather_indirect). The per-point fields go with the points of one call."""

    radiosity: np.ndarray
    first_shot: np.ndarray | None = None
    light: DirectLight | None = None
    gather_points: np.ndarray | None = None
    indirect: np.ndarray | None = None
    gather_normals: np.ndarray | None = None
    corner_cache: dict | None = None


def _at_points(problem: Problem, request: BakeRequest, points, triangles, sides, lit=None, alpha=None):
    """What both reconstructions need at surface points: triangles (m,), alpha (m, n), the
    coefficients the patches reconstruct, and the direct irradiance (m, 3) computed at the points
    where the solve's first shot is split off (else None). lit (m,) bool: the points whose
    irradiance is asked; the others get 0 and cast no rays (None: all). alpha: the points' alpha
    when the caller has it."""
    radiosity, first_shot, light = request.radiosity, request.first_shot, request.light
    tri = np.asarray(triangles, np.int64)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    side = np.broadcast_to(np.asarray(sides), tri.shape)
    a = alpha_at(problem.atlas, problem.index, problem.contacts, pts, tri, side) if alpha is None else alpha
    if first_shot is None or light is None:
        return tri, a, radiosity, None
    if first_shot.shape != radiosity.shape:
        raise OvradError("the first shot does not match the radiosity: solve again")
    if light.gather_rays > 0:
        # final gather (bake/gather.py): the indirect light comes from rays cast at the points, the
        # patches give only the points' own emission; a point needs no patch, only a lit side (sheet)
        coeffs = patch_emission(problem, light.emission_scale)
        covered = (problem.index.sheet_of(tri, side) >= 0) | without_area(problem, tri)  # see bake_normals
    else:
        coeffs = radiosity - first_shot
        covered = np.asarray(a.sum(axis=1)).ravel() > 0
    m = len(pts)
    ask = np.arange(m) if lit is None else np.flatnonzero(np.asarray(lit, bool) & covered)
    if len(ask) == m:  # every point: no copies of the points' arrays
        H = _irradiance(problem, request, pts, tri, side, a, ask, m)
    else:
        H = np.zeros((m, 3))
        if len(ask):
            H[ask] = _irradiance(problem, request, pts[ask], tri[ask], side[ask], a[ask], ask, m)
    return tri, a, coeffs, np.where(covered[:, None], H, 0.0)


def _rows(values, rows: np.ndarray, m: int):
    """Rows `rows` of a request's per-point field of m points: (m, 3), or (m, k, 3) normals (None
    stays None)."""
    if values is None:
        return None
    v = np.asarray(values, np.float64)
    return v.reshape(m, -1, 3)[rows] if v.ndim == 3 else v.reshape(m, 3)[rows]


def _irradiance(problem: Problem, request: BakeRequest, pts, tri, side, a, rows, m) -> np.ndarray:
    """The irradiance (k, 3) at k bake points (rows of the request's m points): the direct light
    computed there, plus the final gather's indirect light when the gather is on."""
    radiosity, first_shot, light = request.radiosity, request.first_shot, request.light
    normals = bake_normals(problem, tri, side)
    seen = bake_sky(problem, light, radiosity)
    sky_at = may_see_sky(a, seen)
    H = direct_irradiance(problem.emitter_rules, problem.index.rays, light, pts, normals, sky_at)[0]
    if light.gather_rays <= 0:
        return H
    indirect = _rows(request.indirect, rows, m)
    if indirect is not None:
        return H + indirect
    near = None
    own = own_emission(problem, light.emitters, light.emission_scale)
    if light.near_field:
        few = min(light.samples, NEAR_LIGHT_SAMPLES)
        # an image emitter's pieces no smaller than a patch: a near hit's light reaches the bake
        # point reflected, averaged over the gather's rays
        coarse = replace(light, emission_piece_size=patch_piece(problem))
        near_light = replace(
            coarse,
            samples=few,
            emitter_samples=emitter_sample_count(
                problem.emitter_rules, coarse, min(light.samples, NEAR_PICKED_SAMPLES), few
            ),
            sky_samples=min(light.sky_samples, NEAR_SKY_SAMPLES),
            area_jittered=True,
        )
        near = NearField(
            near_light,
            radiosity - first_shot - patch_emission(problem, light.emission_scale),
            patch_emission(problem, light.emission_scale) - own,
            sky_seen=seen,
            second_rays=light.near_gather_rays,
        )
    at = _rows(request.gather_points, rows, m)
    at = pts if at is None else at
    axis, spread = normals, _rows(request.gather_normals, rows, m)
    if spread is not None:
        axis = gather_axis(spread)
    gather = Gather(
        radiosity,
        own,
        light.gather_rays,
        near=near,
        corner_cache=request.corner_cache,
        seed=GATHER_SEED if light.gather_seed is None else light.gather_seed,
    )
    return H + gather_unique(problem, gather, at, axis, tri, spread=spread)


def radiance_at(problem: Problem, request: BakeRequest, points, triangles, sides=1) -> np.ndarray:
    """Outgoing radiance L = B / pi (m, 3) reconstructed at surface points (m, 3) on triangles (m,),
    seen from sides (m,) +-1; 0 where no patch covers.

    With the solve's first shot and its direct light (request), the points get their direct light
    computed where they are (shadow rays) and only the rest of the radiosity from the patches. The
    light a point reflects is its own albedo (surfaces.reflectance_at: a texture's where there is
    one) times the irradiance there.
    """
    surfaces = problem.surfaces
    tri = np.asarray(triangles, np.int64)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    side = np.broadcast_to(np.asarray(sides), tri.shape)
    a = alpha_at(problem.atlas, problem.index, problem.contacts, pts, tri, side)
    albedo = surfaces.reflectance_at(tri, pts)
    # a surface that reflects nothing (an Emission shader, a black texel, a metal) needs no light
    tri, a, coeffs, H = _at_points(problem, request, pts, tri, side, np.any(albedo > 0, axis=1), a)
    out = reconstruct(a, coeffs)
    textured = surfaces.textured(tri)
    if np.any(textured):
        # a patch holds its mean albedo x its light: the reflected light the patches reconstruct
        # on a textured triangle takes the texture's detail, as albedo(M) / the triangle's mean
        reflected = _reflected(problem, request.light, a[textured], coeffs)
        gain = per_albedo(albedo[textured], surfaces.reflectance[tri[textured]])
        out[textured] += reflected * (gain - 1.0)
    if H is not None:
        out += albedo * H
    if surfaces.bake_weight is not None:
        # a layered material's bake reports only its diffuse lobe's share of the reflected light
        scale = request.light.emission_scale if request.light is not None else 1.0
        emitted = reconstruct(a, patch_emission(problem, scale))
        out = emitted + surfaces.bake_weight[tri, None] * (out - emitted)
    return out / np.pi


def _reflected(problem: Problem, light: DirectLight | None, a, coeffs: np.ndarray) -> np.ndarray:
    """The light the patches reconstruct with alpha `a` that their surfaces reflect: coeffs less the
    patches' emission."""
    return reconstruct(
        a, coeffs - patch_emission(problem, light.emission_scale if light is not None else 1.0)
    )


def irradiance_at(problem: Problem, request: BakeRequest, points, triangles, sides=1) -> np.ndarray:
    """Light arriving at surface points without the surface's albedo: H / pi (m, 3), in the units
    of radiance (a white surface's radiance), from B(M) - E(M) = rho(M) H(M); 0 where rho is 0
    (direct light at the points where it is split off, as in radiance_at). On a textured triangle
    the patches' reflected light is divided by the triangle's mean albedo, what they hold."""
    tri, a, coeffs, H = _at_points(problem, request, points, triangles, sides)
    out = per_albedo(_reflected(problem, request.light, a, coeffs), problem.surfaces.reflectance[tri])
    if H is not None:
        out += H
    return out / np.pi
