"""Direct light at arbitrary surface points: lamps, small emitters and the sky, with shadow rays.

The solver's first shot projects direct light onto the patches, which blurs it to their size:
a shadow edge or the fast fall-off under a lamp cannot be sharper than a patch. A bake point
(vertex, texel) instead gets its direct light computed where it is, and only the indirect part,
which varies slowly, comes from the patches (bake.points.radiance_at). This is the same split as
"direct + indirect from a radiosity mesh" in classical light baking.

Emitters are integrated with one fixed rule of points on their triangles (emitter_samples),
the same for every receiver point, so that baked light has no noise. Emission shaders emit
from both sides of a face (as in Cycles), so both sides count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene.surfaces import Surfaces, triangle_geometry
from .emitters import (
    EmitterSamples,
    emitter_samples,
    emitting_triangles,
    front_cosine,
    polygon_irradiance,
)
from .lamps import Lamp, lamp_irradiance, shadow_origin
from .near import near_picked
from .sky import Sky, sky_irradiance
from .tree import LightTree, second_order

NEAR_EMITTER = 2.0  # a point closer to an emitting triangle's samples than this x their spacing
# gets that triangle's light from its exact form factor (polygon_irradiance), not from the samples

_CHUNK_RAYS = 1 << 20


@dataclass(frozen=True)
class DirectLight:
    """The light shot straight to bake points: lamps, the emitting triangles sampled with shadow
    rays (emitters (T,) bool over surfaces.triangles), their emission scale, samples per point;
    gather_rays: final-gather rays per bake point for the indirect light (bake/gather.py), 0 = off;
    near_field: hits closer than a patch radius computed where they land (bake.lattice.NearField);
    near_gather_rays: their light from other surfaces gathered again with this many rays (0: from
    the patches; NearField.second_rays);
    sky: the world's light (light/sky.py), None = none; sky_samples: its directions (one fixed set);
    sky_patches (n,) bool: the patches where bake points and near gather hits cast sky rays, as
    the solve decided and stored them (radiosity.emission.bake_sky); None: decide from the problem."""

    lamps: tuple[Lamp, ...] = ()
    emitters: np.ndarray | None = None
    emission_scale: float = 1.0
    samples: int = 64
    gather_rays: int = 0
    near_field: bool = False
    near_gather_rays: int = 0
    sky: Sky | None = None
    sky_samples: int = 1024
    sky_patches: np.ndarray | None = None
    emitter_samples: int = 0  # the emitters' samples per point when not `samples` (0: samples)
    # area lamps: each stratum jittered per point (light.lamps.jittered_area_samples)
    area_jittered: bool = False
    gather_seed: int | None = None  # the final gather's pattern seed (None: bake.gather.GATHER_SEED)
    # an image emitter's light from pieces of about a texel of it (light.emitters.emission_pieces),
    # but no smaller than this along a triangle's longest edge (scene units): the first shot and the
    # near gather hits, whose light a patch or a gather's rays average, take pieces of a patch
    emission_piece_size: float = 0.0


def triangle_normals(surfaces: Surfaces, triangles: np.ndarray) -> np.ndarray:
    """Unit geometric normals (m, 3) of triangles (zero for degenerate ones)."""
    return triangle_geometry(surfaces.corners[np.asarray(triangles, np.int64)])[1]


def emitter_irradiance(
    source: Surfaces | EmitterRules,
    rays,
    emitters: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    samples: int = 64,
    scale: float = 1.0,
    piece_size: float = 0.0,
) -> tuple[np.ndarray, int]:
    """Irradiance (m, 3) at points with unit normals (m, 3) from the emitting triangles `emitters`
    ((T,) bool), over a fixed rule of about `samples` emitter points with a shadow ray each; and
    the number of rays cast. Deterministic. source: the surfaces, or the EmitterRules that keep
    their rules. piece_size: an image emitter's least piece size (emitting_triangles)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    H = np.zeros((len(pts), 3))
    rules = rules_of(source)
    surfaces = rules.surfaces
    src, near = rules.rule(emitters, samples, scale, piece_size)
    k = len(src.area)
    if len(pts) == 0 or k == 0:
        return H, 0
    eps = 1e-6 * surfaces.extent
    cast = 0
    step = max(1, _CHUNK_RAYS // k)
    for r0 in range(0, len(pts), step):
        rs = np.arange(r0, min(len(pts), r0 + step))
        P, N = pts[r0 : r0 + step], nrm[r0 : r0 + step]
        v = src.points[None, :, :] - P[:, None]
        d2 = np.einsum("rsk,rsk->rs", v, v)
        d = np.sqrt(np.maximum(d2, 1e-300))
        omega = v / d[..., None]
        cos_r = np.einsum("rsk,rk->rs", omega, N)
        facing = np.einsum("rsk,sk->rs", omega, src.normals)  # its sign: which side of the emitter
        if src.normal_cov is None:
            cos_s = np.abs(facing)
        else:
            along = np.einsum("rsk,sk->rs", omega, src.axis)
            cos_s = front_cosine(along, src.normal_length, src.normal_cov, omega)
        pair = (cos_r > 0) & (cos_s > 0) & (d2 > 0)
        # From just off the receiver to just off the emitter on the receiver's side: a ray aimed
        # at the sample itself would meet the emitter's own face short of it at grazing angles.
        # Built on the whole (points, samples) grid by broadcasting, then taken at the pairs once.
        origin = shadow_origin(P[:, None], N[:, None], omega, eps)
        seg = src.points[None] - (eps * np.sign(facing))[..., None] * src.normals[None] - origin
        origin, seg = origin[pair], seg[pair]
        length = np.sqrt(np.einsum("ij,ij->i", seg, seg))
        seen = np.zeros(pair.shape)  # the share of each sample's light that gets through
        seen[pair] = rays.transmittance(origin, seg / length[:, None], length * (1 - 1e-6))
        cast += len(seg)
        # the unblocked pairs' geometric terms as a dense (points, samples) matrix: one product sums
        # them per point (np.add.at per pair was a fifth of a production room's near-field time)
        g = np.where(seen > 0, cos_r * cos_s / np.maximum(d2, 1e-300) * src.area[None, :] * seen, 0.0)
        if src.moment is not None:
            g *= _extent(src, P, N, g > 0)
        H[rs] += g @ src.radiance
        if src.run_start is not None:
            _near_emitters(H, rs, P, N, src, d, g, pair, seen)
        elif near is not None:
            cast += near_picked(H, rs, P, N, src, near, g, rays, eps)
    return H, cast


def _extent(src: EmitterSamples, P, N, lit) -> np.ndarray:
    """(r, s) the second-order correction of a light tree cut's samples for their nodes' extent
    (light.tree.second_order) where lit, 1 elsewhere."""
    out = np.ones(lit.shape)
    r, k = np.nonzero(lit)
    if len(r) == 0:
        return out
    u = src.centre[k] - P[r]
    axis = src.axis[k] * np.where(np.einsum("ij,ij->i", src.axis[k], u) < 0, -1.0, 1.0)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        fix = second_order(src.moment[k], u, N[r], axis)
    out[r, k] = np.clip(np.nan_to_num(1.0 + fix, nan=1.0), 0.0, 2.0)
    return out


def _near_emitters(H, rs, P, N, src: EmitterSamples, d, g, pair, seen) -> None:
    """Points within NEAR_EMITTER sample spacings of an emitting triangle's samples: its sampled light
    replaced by its exact unoccluded light x the fraction of its samples they see (seen: the share
    of each (point, sample)'s light that gets through). A fixed rule of
    points is singular there: 1 cm over a lamp quad sampled 15 cm apart it gave 0.7 W/m^2 where the
    quad sends 38, and spikes of thousands right over a sample, which projected onto the patches
    rang into negative radiosity across a whole room."""
    start, tri = src.run_start, src.run_triangle
    near = np.minimum.reduceat(d, start, axis=1) < NEAR_EMITTER * src.spacing[tri][None, :]
    if not np.any(near):
        return
    i, e = np.nonzero(near)
    sampled = np.add.reduceat(g, start, axis=1)[i, e]
    through = np.add.reduceat(seen, start, axis=1)[i, e]
    facing = np.add.reduceat(pair.astype(np.int64), start, axis=1)[i, e]
    seen_fraction = np.where(facing > 0, through / np.maximum(facing, 1), 0.0)
    exact = polygon_irradiance(P[i], N[i], src.corners[tri[e]])
    np.add.at(H, rs[i], (exact * seen_fraction - sampled)[:, None] * src.triangle_radiance[tri[e]])


class EmitterRules:
    """The emitters' fixed rules of one Surfaces: emitter_samples(), or for more emitting triangles
    than samples a LightTree and its cut's samples, made once per (emitters, samples, scale) for
    whoever keeps this object (a problem keeps one for its solve and bakes: a final gather asks for
    them at every chunk of its near hits, 408 times in the production room's vertex bake)."""

    def __init__(self, surfaces: Surfaces):
        self.surfaces = surfaces
        self._made: dict = {}

    def rule(
        self, emitters, samples: int, scale: float, piece_size: float = 0.0
    ) -> tuple[EmitterSamples, LightTree | None]:
        flags = np.asarray(emitters, bool)
        key = (len(flags), np.packbits(flags).tobytes(), int(samples), float(scale), float(piece_size))
        if key not in self._made:
            corners, radiance = emitting_triangles(self.surfaces, flags, scale, piece_size)
            if samples >= 1 and len(corners) >= samples:
                # more triangles than samples: the light tree's cut (its far field) and its near field
                tree = LightTree(corners, radiance, samples)
                self._made[key] = (tree.samples, tree)
            else:
                self._made[key] = (emitter_samples(corners, radiance, samples), None)
        return self._made[key]


def rules_of(source: Surfaces | EmitterRules) -> EmitterRules:
    """The emitter rules to use: those given, or a new set for plain surfaces (kept by no one)."""
    return source if isinstance(source, EmitterRules) else EmitterRules(source)


def picked(
    source: Surfaces | EmitterRules,
    emitters: np.ndarray,
    samples: int,
    scale: float = 1.0,
    piece_size: float = 0.0,
) -> bool:
    """Whether the emitters have more triangles than `samples`: their samples are then a light
    tree's cut (light.tree.LightTree), whose near field every point within reach of a cut node
    walks (fewer samples make larger nodes and widen that near field)."""
    return rules_of(source).rule(emitters, samples, scale, piece_size)[0].pick is not None


def direct_irradiance(
    source: Surfaces | EmitterRules,
    rays,
    light: DirectLight,
    points: np.ndarray,
    normals: np.ndarray,
    sky_at: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """Direct irradiance (m, 3) in W/m^2 at points with unit normals: lamps, the sampled
    emitters and the sky of `light`; and the rays cast. sky_at (m,) bool: the points that may see
    the sky (the others get none of it, and cast no sky rays); None: all. source: the surfaces, or
    the EmitterRules that keep their emitters' rules (a problem's: Problem.emitter_rules)."""
    rules = rules_of(source)
    surfaces = rules.surfaces
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    H = np.zeros((len(pts), 3))
    cast = 0
    if light.lamps:
        for c0 in range(0, len(pts), _CHUNK_RAYS):
            sl = slice(c0, c0 + _CHUNK_RAYS)
            h, n = lamp_irradiance(
                light.lamps, pts[sl], nrm[sl], rays, surfaces.extent, light.samples, light.area_jittered
            )
            H[sl] += h
            cast += n
    if light.emitters is not None and np.any(light.emitters):
        samples = light.emitter_samples or light.samples
        h, n = emitter_irradiance(
            rules, rays, light.emitters, pts, nrm, samples, light.emission_scale, light.emission_piece_size
        )
        H += h
        cast += n
    if light.sky is not None and light.sky.emits:
        at = np.arange(len(pts)) if sky_at is None else np.flatnonzero(sky_at)
        h, n = sky_irradiance(light.sky, rays, pts[at], nrm[at], surfaces.extent, light.sky_samples)
        H[at] += h
        cast += n
    return H, cast
