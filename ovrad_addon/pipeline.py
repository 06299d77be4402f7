"""The whole solve on plain arrays: surfaces + atlas + lamps -> per-patch radiosity -> radiance at points.

prepare() does the heavy, light-independent work (sheets, C, transport G); solve() can then be
run again with other lamp powers or emission strengths without recomputing form factors.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.sparse import csc_matrix, diags

from .atlas import Atlas, SurfaceIndex, index_surfaces
from .errors import OvradError
from .lights import Lamp, lamp_irradiance
from .overlap import alpha_at, overlap_matrix, patch_average, patch_quadrature, reconstruct
from .settings import AtlasSettings, ObjectSettings
from .solver import SolveState, _factor, solve_progressive
from .surfaces import Surfaces
from .transport import Transport, gather_transport

GATHER_Q = 4  # polar rule of the receiver points (transport, direct light, patch emission)
NEE_AREA_FRACTION = 0.1  # emitters covering less of the scene are shot with shadow rays


@dataclass(frozen=True)
class SolveSettings:
    """tolerance: stop when unshot power < tolerance x emitted power; rule: "exact" (eq. 9) or
    "paper" (the published update); rays_per_point: hemisphere rays per receiver point;
    batch: shooters per step; light_samples: emitter samples per receiver point (direct light);
    smoothing: weight of the overlap-graph Laplacian added to C when solving (see regularised()),
    0 solves equation (9) exactly."""

    tolerance: float = 1e-3
    rule: str = "exact"
    rays_per_point: int = 32
    batch: int = 64
    light_samples: int = 16
    smoothing: float = 0.1

    def __post_init__(self) -> None:
        if not (0 < self.tolerance < 1):
            raise OvradError(f"tolerance must be in (0, 1), got {self.tolerance}")
        if self.rule not in ("exact", "paper"):
            raise OvradError(f"rule must be 'exact' or 'paper', got {self.rule!r}")
        if not (0.0 <= self.smoothing <= 10.0):
            raise OvradError(f"smoothing must be in [0, 10], got {self.smoothing}")
        if not (1 <= self.rays_per_point <= 4096) or not (1 <= self.light_samples <= 1024):
            raise OvradError("rays_per_point must be in [1, 4096] and light_samples in [1, 1024]")


@dataclass
class Problem:
    """Everything light-independent: index (sheets, rays), atlas with sheets attached (and its
    effective areas from the fine rule), C and the transport R (transport.py)."""

    surfaces: Surfaces
    atlas: Atlas
    index: SurfaceIndex
    C: object
    transport: Transport
    rays: int
    seconds: dict


Progress = Callable[[float, str], bool] | None


def _report(progress: Progress, f: float, msg: str) -> None:
    if progress is not None and progress(f, msg) is False:
        raise OvradError("cancelled")


def attach_sheets(atlas: Atlas, index: SurfaceIndex) -> Atlas:
    """Give each patch the sheet index of this index, found by locating its centre on the surface.

    Sheet numbers depend on which meshes were read and in what order; an atlas read back from
    Blender is re-attached this way, so it does not matter how the scene was read when it was made.
    """
    n = atlas.normals
    lift = atlas.thickness * 1.0001 + 1e-9 * index.surfaces.extent
    t, tri = index.rays.closest_hit(atlas.centers + lift[:, None] * n, -n, 2.0 * lift)
    side = np.where(np.einsum("ij,ij->i", index.charts.normals[np.maximum(tri, 0)], n) >= 0, 1, -1)
    sheet = index.sheet_of(tri, side)
    missing = np.flatnonzero(sheet < 0)
    if len(missing):
        # centre off the surface (a disk on a border cell): try the patch's rule points
        probe = replace(atlas, sheet=np.zeros(len(atlas), np.int64))
        for k in missing:
            q = patch_quadrature(probe, _all_sheets_view(index), np.array([k]), 4, rings=2)
            hit = q.triangle[q.triangle >= 0]
            if len(hit):
                s = index.sheet_of(hit[:1], np.array([side[k]]))
                sheet[k] = s[0]
    if np.any(sheet < 0):
        raise OvradError(
            f"{int(np.sum(sheet < 0))} patches no longer lie on any surface: the meshes changed "
            "since the atlas was generated; generate the atlas again"
        )
    return replace(atlas, sheet=sheet)


def _all_sheets_view(index: SurfaceIndex) -> SurfaceIndex:
    """An index whose every sheet is 0, so rule points are accepted on any sheet (for locating)."""
    return replace(index, sheet_table=np.zeros_like(index.sheet_table))


def prepare(
    surfaces: Surfaces,
    atlas: Atlas,
    settings: SolveSettings = SolveSettings(),
    quadrature: int = 12,
    progress: Progress = None,
    backend: str = "auto",
) -> Problem:
    """Sheets, the overlap matrix C (fine rule of `quadrature`) and the transport R for an atlas."""
    if len(atlas) == 0:
        raise OvradError("the atlas has no patches: generate an atlas first")
    seconds = {}
    t0 = time.perf_counter()
    _report(progress, 0.0, "indexing surfaces")
    n_obj = len(surfaces.object_names)
    index = index_surfaces(
        surfaces, AtlasSettings(objects=tuple(ObjectSettings(sides="BOTH") for _ in range(n_obj))), backend
    )
    atlas = attach_sheets(atlas, index)
    seconds["index"] = time.perf_counter() - t0
    _report(progress, 0.05, "integrating overlaps")
    t0 = time.perf_counter()
    C, support = overlap_matrix(
        atlas,
        index,
        quadrature,
        progress=lambda f: _report(progress, 0.05 + 0.35 * f, "integrating overlaps"),
    )
    atlas = replace(atlas, support_area=support, effective_area=C.diagonal().copy())
    seconds["overlap"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    T = gather_transport(
        atlas,
        index,
        settings.rays_per_point,
        progress=lambda f: _report(progress, 0.4 + 0.6 * f, "casting transport rays"),
    )
    seconds["transport"] = time.perf_counter() - t0
    return Problem(surfaces, atlas, index, C, T, T.rays, seconds)


def regularised(C, weight: float):
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
    """Exitance E (n, 3) of each patch: pi x emitted radiance averaged over its support."""
    return (
        np.pi
        * emission_scale
        * patch_average(problem.atlas, problem.index, problem.surfaces.emission, GATHER_Q)
    )


def _emitter_direct(problem: Problem, E: np.ndarray, samples: int, seed: int = 1) -> tuple[np.ndarray, int]:
    """Irradiance (m, 3) at every receiver point straight from emissive patches (next-event
    estimation: `samples` stratified picks among the emitters' points, one shadow ray each),
    and the rays cast. An emitter point of patch k carries its basis share alpha_k E_k / pi."""
    atlas, index, rp = problem.atlas, problem.index, problem.transport.points
    m = len(rp.owner)
    H = np.zeros((m, 3))
    src_patch = np.flatnonzero(np.abs(E).sum(axis=1) > 0)
    if len(src_patch) == 0:
        return H, 0
    sel = np.flatnonzero(np.isin(rp.owner, src_patch))
    a = alpha_at(atlas, index, rp.points[sel], rp.triangle[sel], index.sheet_side[atlas.sheet[rp.owner[sel]]])
    own = np.asarray(a[np.arange(len(sel)), rp.owner[sel]]).ravel()
    radiance = own[:, None] * E[rp.owner[sel]] / np.pi
    power = rp.weight[sel] * radiance.sum(axis=1)
    keep = power > 0
    sel, radiance, power = sel[keep], radiance[keep], power[keep]
    if len(sel) == 0:
        return H, 0
    total = power.sum()
    cdf = np.cumsum(power) / total
    rng = np.random.default_rng(seed)
    eps = 1e-6 * problem.surfaces.extent
    cast = 0
    step = max(1, (1 << 20) // samples)
    for r0 in range(0, m, step):
        rs = np.arange(r0, min(m, r0 + step))
        pts, nrm = rp.points[rs], rp.normals[rs]
        u = (np.arange(samples)[None, :] + rng.random((len(rs), 1))) / samples  # stratified
        j = np.minimum(np.searchsorted(cdf, u), len(sel) - 1)  # (r, S) into sel
        src = sel[j]
        v = rp.points[src] - pts[:, None]
        d2 = np.einsum("rsk,rsk->rs", v, v)
        d = np.sqrt(np.maximum(d2, 1e-300))
        omega = v / d[..., None]
        cos_r = np.einsum("rsk,rk->rs", omega, nrm)
        cos_s = -np.einsum("rsk,rsk->rs", omega, rp.normals[src])
        r_i, s_i = np.nonzero((cos_r > 0) & (cos_s > 0))
        blocked = index.rays.occluded(
            pts[r_i] + eps * nrm[r_i], omega[r_i, s_i], d[r_i, s_i] * (1 - 1e-6) - 2 * eps
        )
        cast += len(r_i)
        r_i, s_i = r_i[~blocked], s_i[~blocked]
        jj = j[r_i, s_i]
        pdf = power[jj] / total
        g = rp.weight[sel[jj]] * cos_r[r_i, s_i] * cos_s[r_i, s_i] / d2[r_i, s_i] / (pdf * samples)
        np.add.at(H, rs[r_i], g[:, None] * radiance[jj])
    return H, cast


def solve(
    problem: Problem,
    lamps: tuple[Lamp, ...] = (),
    settings: SolveSettings = SolveSettings(),
    emission_scale: float = 1.0,
    progress: Callable[[float, float, float, int], bool] | None = None,
    state: SolveState | None = None,
) -> SolveState:
    """Progressive solve of (C - R) B = C E, with lamps and emitters shot first explicitly.

    The first shot sends the lamps' and the emitters' light straight to every receiver point
    (shadow rays), which is far more accurate for small bright sources than hemisphere rays.
    Radiosity B (n, 3) is exitance in W/m^2; radiance is B / pi.
    """
    atlas = problem.atlas
    E = patch_emission(problem, emission_scale)
    C_solve = regularised(problem.C, settings.smoothing) if settings.rule == "exact" else problem.C
    if state is None:
        T = problem.transport
        rp = T.points
        H, lamp_rays = lamp_irradiance(
            lamps, rp.points, rp.normals, problem.index.rays, problem.surfaces.extent
        )
        # Small bright emitters (a light fixture) are shot with shadow rays: hemisphere rays would
        # find them too rarely. Large emitters (a glowing wall, a furnace) are left to the rays,
        # whose sums close exactly, where sampling them point to point would meet 1/d^2 near fields.
        emitting = np.abs(E).sum(axis=1) > 0
        small = atlas.effective_area[emitting].sum() <= NEE_AREA_FRACTION * atlas.effective_area.sum()
        direct, emit_rays = _emitter_direct(problem, E, settings.light_samples) if small else (0.0, 0)
        received = T.test(H + direct, problem.surfaces.reflectance[rp.triangle])
        if not np.any(received > 0) and not np.any(E > 0):
            raise OvradError("no light: nothing in the scene emits (add a lamp or an emissive material)")
        if settings.rule == "exact":
            dB = _factor(C_solve).solve(received)
        else:
            A = atlas.support_area
            dB = (problem.C.T @ (received / A[:, None])) / A[:, None]
        unshot = dB if small else dB + E
        state = SolveState(radiosity=E + dB, unshot=unshot, rays=problem.rays + lamp_rays + emit_rays)
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
    )


def radiance_at(problem: Problem, radiosity: np.ndarray, points, triangles, sides=1) -> np.ndarray:
    """Outgoing radiance L = B / pi (m, 3) reconstructed at surface points; 0 where no patch covers."""
    tri = np.asarray(triangles, np.int64)
    a = alpha_at(problem.atlas, problem.index, points, tri, np.broadcast_to(np.asarray(sides), tri.shape))
    return reconstruct(a, radiosity) / np.pi


def irradiance_at(problem: Problem, radiosity: np.ndarray, points, triangles, sides=1) -> np.ndarray:
    """Light arriving at surface points without the surface's albedo: H / pi (m, 3), in the units
    of radiance (a white surface's radiance), from B(M) - E(M) = rho(M) H(M); 0 where rho is 0."""
    tri = np.asarray(triangles, np.int64)
    a = alpha_at(problem.atlas, problem.index, points, tri, np.broadcast_to(np.asarray(sides), tri.shape))
    E = patch_emission(problem)
    reflected = reconstruct(a, radiosity - E)
    rho = problem.surfaces.reflectance[tri]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(rho > 0, reflected / rho, 0.0) / np.pi
