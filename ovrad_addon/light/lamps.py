"""Blender lamps as light sources, in Cycles' units, and their direct light on receiver points.

Every source is reduced to point samples with a radiant intensity I(omega) (W/sr); the
irradiance at a receiver point M with normal n is sum_j I_j(omega_j) max(0, n . omega_j) / d_j^2,
with a shadow ray per sample. Suns are directions with an irradiance instead.
- Point lamp of power P: I = P / (4 pi) (Cycles divides by 4 pi), colour multiplies.
- Spot lamp: a point lamp times smoothstep((cos t - cos(size/2)) / ((1 - cos(size/2)) blend)),
  t the angle from the spot axis (the cone does not concentrate the power).
- Sun of strength S (W/m^2): irradiance S cos(theta) where unshadowed.
- A point or spot lamp with a radius R is a uniformly bright sphere, and a sun with an angle a
  disk of that angular diameter: soft shadows. Unshadowed, a sphere above the horizon gives
  exactly the point lamp's P cos(theta) / (4 pi d^2), and a sun disk S cos(theta); the shadow
  rays then weigh which part of the source each point sees (soft_irradiance).
- Area lamp of power P and area A: radiance P / (pi A) from its front side; each of its k
  samples carries I(omega) = P / (pi A) * (A / k) * cos(theta_lamp).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OvradError
from ..geometry import tangent_frame

LAMP_KINDS = ("POINT", "SPOT", "SUN", "AREA")

AREA_SHAPES = ("SQUARE", "RECTANGLE", "DISK", "ELLIPSE")


@dataclass(frozen=True)
class Lamp:
    """A Blender lamp in world space.

    kind: POINT, SPOT, SUN or AREA; position (3,); direction (3,) unit vector the lamp points
    along (-Z of the lamp object); tangent (3,) the lamp's local X (area lamp size_x axis);
    power in W (point, spot, area) or strength in W/m^2 (sun); color (3,) linear RGB;
    spot_size (radians, full cone angle) and spot_blend; shape, size_x, size_y for area lamps.
    """

    kind: str
    position: tuple = (0.0, 0.0, 0.0)
    direction: tuple = (0.0, 0.0, -1.0)
    tangent: tuple = (1.0, 0.0, 0.0)
    power: float = 1000.0
    color: tuple = (1.0, 1.0, 1.0)
    spot_size: float = np.pi / 4
    spot_blend: float = 0.15
    shape: str = "SQUARE"
    size_x: float = 1.0
    size_y: float = 1.0
    radius: float = 0.0
    angle: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in LAMP_KINDS:
            raise OvradError(f"lamp kind must be one of {LAMP_KINDS}, got {self.kind!r}")
        if self.kind == "AREA" and self.shape not in AREA_SHAPES:
            raise OvradError(f"area lamp shape must be one of {AREA_SHAPES}, got {self.shape!r}")
        vals = [*self.position, *self.direction, self.power, *self.color, self.size_x, self.size_y]
        if not np.all(np.isfinite(vals)):
            raise OvradError("lamp has NaN or infinite values")
        if self.power < 0 or min(self.color) < 0:
            raise OvradError("lamp power and colour must be non-negative")
        if not (0.0 <= self.radius < np.inf) or not (0.0 <= self.angle <= np.pi):
            raise OvradError("lamp radius must be >= 0 and sun angle within [0, 180] degrees")

    @property
    def soft(self) -> bool:
        """A sphere (point, spot with a radius) or a sun disk (angle): sampled, soft shadows."""
        return (self.kind in ("POINT", "SPOT") and self.radius > 0) or (self.kind == "SUN" and self.angle > 0)


def _lamp_sides(shape: str, size_x: float, size_y: float) -> tuple[float, float]:
    """Lengths of an area lamp along its X and Y axes: a SQUARE or DISK has size_x for both, as in Blender."""
    return size_x, size_x if shape in ("SQUARE", "DISK") else size_y


def lamp_area(shape: str, size_x: float, size_y: float) -> float:
    """Emitting area of an area lamp of Blender shape SQUARE, RECTANGLE, DISK or ELLIPSE."""
    sx, sy = _lamp_sides(shape, size_x, size_y)
    return sx * sy * (np.pi / 4 if shape in ("DISK", "ELLIPSE") else 1.0)


def spot_falloff(cos_angle: np.ndarray, spot_size: float, blend: float) -> np.ndarray:
    """Cycles' spot attenuation: smoothstep over the blend region inside the cone edge."""
    c = np.cos(0.5 * spot_size)
    if blend <= 0:
        return (cos_angle > c).astype(np.float64)
    f = np.clip((cos_angle - c) / ((1.0 - c) * blend), 0.0, 1.0)
    return f * f * (3.0 - 2.0 * f)


def _lamp_axes(lamp: Lamp) -> tuple[np.ndarray, np.ndarray]:
    """An area lamp's unit X and Y axes in world space (its tangent made orthogonal to its
    direction, and direction x tangent)."""
    d = np.asarray(lamp.direction, float)
    d = d / np.linalg.norm(d)
    t = np.asarray(lamp.tangent, float)
    t = t - d * (t @ d)
    t /= np.linalg.norm(t)
    return t, np.cross(d, t)


def area_samples(lamp: Lamp, per_side: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Stratified points on an area lamp's surface: (points (k, 3), area weights (k,))."""
    t, b = _lamp_axes(lamp)
    sx, sy = _lamp_sides(lamp.shape, lamp.size_x, lamp.size_y)
    g = (np.arange(per_side) + 0.5) / per_side - 0.5
    if lamp.shape in ("SQUARE", "RECTANGLE"):
        u, v = np.meshgrid(g * sx, g * sy, indexing="ij")
        u, v = u.ravel(), v.ravel()
    else:  # disk or ellipse: equal-area rings
        n_r = per_side
        s = (np.arange(n_r) + 0.5) / n_r
        r = np.sqrt(s)[:, None]
        th = 2 * np.pi * (np.arange(2 * per_side) + 0.5 * (np.arange(n_r)[:, None] % 2)) / (2 * per_side)
        u = (0.5 * sx * r * np.cos(th)).ravel()
        v = (0.5 * sy * r * np.sin(th)).ravel()
    p = np.asarray(lamp.position, float)
    return p + u[:, None] * t + v[:, None] * b, np.full(u.size, lamp_area(lamp.shape, sx, sy) / u.size)


def point_hash(points: np.ndarray, salt: int = 0) -> np.ndarray:
    """(m, 2) numbers in [0, 1) that depend only on each point's coordinates (their float64 bits,
    mixed) and on salt: the same point gets the same pair on any thread, in any chunk."""
    bits = np.ascontiguousarray(points, np.float64).reshape(-1, 3).view(np.uint64)
    h = bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)
    h ^= bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= bits[:, 2] * np.uint64(0x165667B19E3779F9)
    h ^= np.uint64((salt * 0xD6E8FEB86659FD93) & 0xFFFFFFFFFFFFFFFF)
    for shift, mult in ((30, 0xBF58476D1CE4E5B9), (27, 0x94D049BB133111EB)):  # splitmix64's finaliser
        h ^= h >> np.uint64(shift)
        h *= np.uint64(mult)
    h ^= h >> np.uint64(31)
    scale = 1.0 / (1 << 32)
    return np.column_stack([(h >> np.uint64(32)) * scale, (h & np.uint64(0xFFFFFFFF)) * scale])


def jittered_area_samples(lamp: Lamp, per_side: int, points: np.ndarray):
    """The stratified rule of area_samples with each stratum's point placed anywhere in its
    stratum, by a hash of the receiver point and the stratum (point_hash): yields (points (m, 3),
    area weight) per stratum. A fixed rule puts every receiver's penumbra on the same few steps;
    jittered, the steps fall elsewhere at each receiver and average out over many of them (a final
    gather's near hits), and each receiver's own estimate stays stratified."""
    t, b = _lamp_axes(lamp)
    sx, sy = _lamp_sides(lamp.shape, lamp.size_x, lamp.size_y)
    p = np.asarray(lamp.position, float)
    square = lamp.shape in ("SQUARE", "RECTANGLE")
    cols = per_side if square else 2 * per_side
    weight = lamp_area(lamp.shape, sx, sy) / (per_side * cols)
    for i in range(per_side):
        for j in range(cols):
            su, sv = point_hash(points, i * cols + j).T
            if square:
                u = ((i + su) / per_side - 0.5) * sx
                v = ((j + sv) / per_side - 0.5) * sy
            else:  # disk or ellipse: equal-area rings, as area_samples
                r = np.sqrt((i + su) / per_side)
                th = 2 * np.pi * (j + sv - 0.5 + 0.5 * (i % 2)) / cols
                u, v = 0.5 * sx * r * np.cos(th), 0.5 * sy * r * np.sin(th)
            yield p + u[:, None] * t + v[:, None] * b, weight


def shadow_origin(points: np.ndarray, normals: np.ndarray, directions: np.ndarray, eps: float) -> np.ndarray:
    """Where a shadow ray from surface points starts: off the surface along the normal and along
    the ray. A point on a concave edge (a wall's foot) lies in the neighbouring face's plane too;
    stepping along the normal alone would leave it there and the ray would hit that face at t = 0."""
    return points + eps * normals + 2.0 * eps * directions


def cone_directions(axis: np.ndarray, cos_a: np.ndarray, count: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Directions (m, k, 3) within the cones of half-angle a around unit axes (m, 3), and the sum
    over each point's directions of their cosine to the axis (m,).

    Rings of equal solid angle (midpoints in cos), each with equally spaced azimuths turned by a
    random offset per point and ring: the components across the axis cancel exactly, so the
    directions' mean is parallel to the axis, which soft_irradiance relies on.
    """
    m = len(axis)
    n_r = max(1, int(np.sqrt(count)))
    n_az = max(2, count // n_r)
    cos_psi = 1.0 - (1.0 - cos_a)[:, None] * ((np.arange(n_r) + 0.5) / n_r)[None, :]  # (m, n_r)
    sin_psi = np.sqrt(np.maximum(1.0 - cos_psi**2, 0.0))
    phi = 2.0 * np.pi * (np.arange(n_az)[None, None, :] + rng.random((m, n_r, 1))) / n_az
    t, b = tangent_frame(axis)
    cp, sp = cos_psi[..., None, None], sin_psi[..., None, None]
    d = (
        cp * axis[:, None, None]
        + sp * np.cos(phi)[..., None] * t[:, None, None]
        + sp * np.sin(phi)[..., None] * b[:, None, None]
    )
    return d.reshape(m, n_r * n_az, 3), n_az * cos_psi.sum(axis=1)


def soft_irradiance(lamp: Lamp, pts, nrm, rays, eps: float, samples: int) -> tuple[np.ndarray, int]:
    """Irradiance (m,) of a sphere lamp or a sun disk at points, with soft shadows; and rays cast.

    With directions w_j spread evenly over the source's cone (cone_directions), the irradiance is
    E_n sum_j max(0, n . w_j) V_j / sum_j (axis . w_j), E_n the irradiance at normal incidence
    (P / (4 pi d^2) times the spot fall-off towards the centre, or the sun's strength). Unshadowed
    and above the horizon this is exactly E_n cos(theta), the closed form; a source that sinks
    below the horizon is cut by the max, one partly hidden is weighed by its visible directions.
    Points go in chunks, each with its own seeded azimuth offsets.
    """
    out = np.zeros(len(pts))
    cast = 0
    step = max(1, (1 << 18) // max(samples, 1))
    for c0 in range(0, len(pts), step):
        sl = slice(c0, c0 + step)
        out[sl], n = _soft_chunk(lamp, pts[sl], nrm[sl], rays, eps, samples, c0)
        cast += n
    return out, cast


def _soft_chunk(lamp: Lamp, pts, nrm, rays, eps: float, samples: int, seed: int) -> tuple[np.ndarray, int]:
    m = len(pts)
    rng = np.random.default_rng(seed)
    if lamp.kind == "SUN":
        axis = np.broadcast_to(-np.asarray(lamp.direction, float) / np.linalg.norm(lamp.direction), pts.shape)
        cos_a = np.full(m, np.cos(0.5 * lamp.angle))
        e_n = np.full(m, lamp.power)
        dist = None
    else:
        v = np.asarray(lamp.position, float) - pts
        dist = np.sqrt(np.maximum(np.einsum("ij,ij->i", v, v), 1e-300))
        axis = v / dist[:, None]
        sin_a = np.minimum(lamp.radius / dist, 0.9999)  # inside the sphere: nearly the whole hemisphere
        cos_a = np.sqrt(1.0 - sin_a**2)
        e_n = lamp.power / (4.0 * np.pi * dist**2)
        if lamp.kind == "SPOT":
            spot = np.asarray(lamp.direction, float) / np.linalg.norm(lamp.direction)
            e_n = e_n * spot_falloff(-(axis @ spot), lamp.spot_size, lamp.spot_blend)
    dirs, norm = cone_directions(np.ascontiguousarray(axis), cos_a, samples, rng)
    k = dirs.shape[1]
    cos = np.einsum("mkj,mj->mk", dirs, nrm)
    lit = (cos > 0) & (e_n[:, None] > 0)
    r, j = np.nonzero(lit)
    w = dirs[r, j]
    if dist is None:
        tmax = np.full(len(r), np.inf)
    else:  # to the near side of the sphere along each direction
        along = np.einsum("ij,ij->i", w, axis[r]) * dist[r]
        tmax = along - np.sqrt(np.maximum(lamp.radius**2 - dist[r] ** 2 + along**2, 0.0))
        tmax = tmax * (1 - 1e-6) - 3 * eps
    through = rays.transmittance(shadow_origin(pts[r], nrm[r], w, eps), w, tmax)
    seen = np.zeros((m, k))
    open_ = through > 0
    seen[r[open_], j[open_]] = cos[r[open_], j[open_]] * through[open_]
    return e_n * seen.sum(axis=1) / norm, len(r)


def area_side(samples: int) -> int:
    """Points per side of an area lamp's rule for `samples` shadow rays per point: 8 (64 points)
    from 16 samples up, as many as a smaller budget allows below that (at least 2 x 2)."""
    return int(np.clip(round(2.0 * np.sqrt(max(samples, 1))), 2, 8))


def jittered_area_side(samples: int) -> int:
    """Points per side of a jittered area lamp rule for `samples` shadow rays per point: about
    sqrt(samples) (3 x 3 for 8), at least 2 x 2. The fixed rule (area_side) takes four times as
    many to keep its steps small; jittered, they average out instead. A final gather's near hits
    under a 4 m area lamp (16 808 vertices of 300 bevelled boxes on a floor; each bake against the
    same bake with a jittered 12 x 12 rule): fixed 6 x 6 (the rule before) 0.26 % in 45 s, fixed
    8 x 8 0.16 % in 66 s, fixed 3 x 3 0.83 %, jittered 3 x 3 0.16 % in 23 s, 4 x 4 0.11 % in 30 s."""
    return int(np.clip(round(np.sqrt(max(samples, 1))), 2, 8))


def lamp_irradiance(
    lamps,
    points: np.ndarray,
    normals: np.ndarray,
    rays,
    extent: float,
    samples: int = 16,
    jittered: bool = False,
) -> tuple[np.ndarray, int]:
    """Direct irradiance (m, 3) in W/m^2 at points with unit normals, shadowed; and rays cast.
    samples: shadow rays per point for a lamp with a radius or a sun with an angle; an area lamp
    takes area_side(samples)^2 (64 at the defaults, fewer only under a ray budget). jittered: an
    area lamp's strata are jittered per point (jittered_area_samples), for points whose light is
    averaged over many of them; jittered_area_side(samples)^2 points then."""
    pts = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    total = np.zeros((len(pts), 3))
    eps = 1e-6 * max(extent, 1e-300)
    cast = 0
    for lamp in lamps:
        color = np.asarray(lamp.color, float)
        axis = np.asarray(lamp.direction, float)
        axis = axis / np.linalg.norm(axis)
        if lamp.soft:
            e, n = soft_irradiance(lamp, pts, nrm, rays, eps, samples)
            total += e[:, None] * color
            cast += n
            continue
        if lamp.kind == "SUN":
            to_light = np.broadcast_to(-axis, pts.shape)
            cos = np.einsum("ij,ij->i", nrm, to_light)
            lit = cos > 0
            through = rays.transmittance(
                shadow_origin(pts[lit], nrm[lit], to_light[lit], eps), to_light[lit], np.inf
            )
            cast += int(lit.sum())
            e = np.zeros(len(pts))
            e[lit] = np.where(through > 0, lamp.power * cos[lit] * through, 0.0)
            total += e[:, None] * color
            continue
        if lamp.kind == "AREA" and jittered:
            rule = jittered_area_samples(lamp, jittered_area_side(samples), pts)
        elif lamp.kind == "AREA":
            rule = zip(*area_samples(lamp, area_side(samples)), strict=True)
        else:
            rule = [(np.asarray(lamp.position, float), 1.0)]
        for s, ws in rule:
            v = s - pts
            d2 = np.einsum("ij,ij->i", v, v)
            d = np.sqrt(np.maximum(d2, 1e-300))
            omega = v / d[:, None]
            cos = np.einsum("ij,ij->i", nrm, omega)
            if lamp.kind == "AREA":
                cos_l = np.einsum("ij,j->i", -omega, axis)
                intensity = (
                    lamp.power
                    / (np.pi * lamp_area(lamp.shape, lamp.size_x, lamp.size_y))
                    * ws
                    * np.clip(cos_l, 0, None)
                )
            else:
                intensity = np.full(len(pts), lamp.power / (4 * np.pi))
                if lamp.kind == "SPOT":
                    intensity = intensity * spot_falloff(
                        np.einsum("ij,j->i", -omega, axis), lamp.spot_size, lamp.spot_blend
                    )
            lit = (cos > 0) & (intensity > 0)
            idx = np.flatnonzero(lit)
            origin = shadow_origin(pts[idx], nrm[idx], omega[idx], eps)
            through = rays.transmittance(origin, omega[idx], d[idx] * (1 - 1e-6) - 3 * eps)
            cast += len(idx)
            e = np.zeros(len(pts))
            keep = idx[through > 0]
            e[keep] = intensity[keep] * cos[keep] / d2[keep] * through[through > 0]
            total += e[:, None] * color
    return total, cast
