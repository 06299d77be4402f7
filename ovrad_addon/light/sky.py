"""Light from the world: a constant colour or an equirectangular environment map, infinitely far.

The sky is direct light like a lamp: shot first to the solve's receiver points and computed again
at each bake point. Its irradiance at a point with normal n is E = sum_j w_j max(0, n . d_j) V_j
over ONE fixed set of world directions d_j shared by every point (so neighbouring points see the
same directions and the result has no noise): a spherical Fibonacci set, plus, for a map,
directions picked by systematic sampling on the pixels' power (a sun is a few bright pixels that
uniform directions would miss). The two sets are combined with the balance heuristic, so each
direction's weight is L(d) / (k_u p_u(d) + k_i p_i(d)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..digest import hasher
from ..errors import OvradError
from .lamps import shadow_origin

_CHUNK_RAYS = 1 << 18


@dataclass(frozen=True, eq=False)
class Sky:
    """color: (3,) constant radiance (W m^-2 sr^-1), used where there is no image; image: None or
    (h, w, 3) linear radiance in Cycles' equirectangular layout (row 0 at the bottom, u = 0.5 looking
    along +X), strength already applied; rotation_z: radians the map is turned about +Z (a Mapping
    node's Z rotation)."""

    color: tuple = (0.0, 0.0, 0.0)
    image: np.ndarray | None = field(default=None, repr=False)
    rotation_z: float = 0.0

    def __post_init__(self) -> None:
        c = np.asarray(self.color, float)
        if c.shape != (3,) or not np.all(np.isfinite(c)) or c.min() < 0:
            raise OvradError(f"sky colour must be 3 finite non-negative values, got {self.color}")
        if self.image is not None:
            img = np.asarray(self.image)
            if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 1:
                raise OvradError(f"sky image must be (h, w, 3), got {img.shape}")
            if not np.all(np.isfinite(img)) or img.min() < 0:
                raise OvradError("sky image has negative or invalid values")

    @property
    def emits(self) -> bool:
        return bool(np.max(self.color) > 0) if self.image is None else bool(np.max(self.image) > 0)

    def key(self) -> str:
        """A hash of everything the light depends on (for 'the light changed since the solve')."""
        h = hasher(16)
        h.update(np.asarray(self.color, np.float64).tobytes())
        h.update(np.float64(self.rotation_z).tobytes())
        if self.image is not None:
            img = np.ascontiguousarray(self.image, np.float32)
            h.update(str(img.shape).encode())
            h.update(img.tobytes())
        return h.hexdigest()

    def __repr__(self) -> str:
        return f"Sky({self.key()})"

    def mean_radiance(self) -> np.ndarray:
        """(3,) radiance averaged over the whole sphere of directions (by solid angle)."""
        if self.image is None:
            return np.asarray(self.color, float)
        omega, _ = _pixel_power(self)
        img = np.asarray(self.image, float)
        return np.einsum("hw,hwc->c", omega, img) / omega.sum()

    def radiance(self, directions: np.ndarray) -> np.ndarray:
        """Radiance (k, 3) arriving from unit world directions (k, 3)."""
        d = np.asarray(directions, float).reshape(-1, 3)
        if self.image is None:
            return np.broadcast_to(np.asarray(self.color, float), d.shape).copy()
        h, w = self.image.shape[:2]
        u, v = equirect_uv(d, self.rotation_z)
        col = np.minimum((u * w).astype(np.int64), w - 1) % w
        row = np.clip((v * h).astype(np.int64), 0, h - 1)
        return np.asarray(self.image, float)[row, col]


def equirect_uv(d: np.ndarray, rotation_z: float) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) in [0, 1) of world directions, Cycles' layout, the map turned by rotation_z."""
    phi = np.arctan2(d[:, 1], d[:, 0]) - rotation_z
    u = np.mod(0.5 - phi / (2 * np.pi), 1.0)
    v = 0.5 + np.arcsin(np.clip(d[:, 2], -1.0, 1.0)) / np.pi
    return u, v


def fibonacci_sphere(count: int) -> np.ndarray:
    """count unit directions (count, 3) spread evenly over the sphere (equal-area spiral)."""
    i = np.arange(count) + 0.5
    z = 1.0 - 2.0 * i / count
    phi = i * np.pi * (3.0 - np.sqrt(5.0))
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def _pixel_power(sky: Sky) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel of the map: solid angle (h, w) and luminance x solid angle (h, w)."""
    h, w = sky.image.shape[:2]
    el_lo = (np.arange(h) / h - 0.5) * np.pi
    el_hi = ((np.arange(h) + 1) / h - 0.5) * np.pi
    omega = np.repeat(((np.sin(el_hi) - np.sin(el_lo)) * 2 * np.pi / w)[:, None], w, axis=1)
    lum = np.asarray(sky.image, float) @ np.array([0.2126, 0.7152, 0.0722])
    return omega, lum * omega


def sky_directions(sky: Sky, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The fixed rule: directions (k, 3) and weights (k, 3) with E(n) = sum_j w_j max(0, n . d_j) V_j.

    A constant sky gets `count` Fibonacci directions of weight 4 pi L / count; a map gets half of
    them uniform and half on its pixels' power, combined with the balance heuristic.
    """
    if count < 2:
        raise OvradError(f"sky samples must be at least 2, got {count}")
    if sky.image is None:
        d = fibonacci_sphere(count)
        return d, np.broadcast_to(np.asarray(sky.color, float) * (4 * np.pi / count), d.shape).copy()
    k_u = count // 2
    k_i = count - k_u
    omega, power = _pixel_power(sky)
    h, w = omega.shape
    total = power.sum()
    uniform = fibonacci_sphere(k_u)
    if total <= 0:
        return uniform, sky.radiance(uniform) * (4 * np.pi / k_u)
    cdf = np.cumsum(power.ravel()) / total
    pick = np.minimum(np.searchsorted(cdf, (np.arange(k_i) + 0.5) / k_i), h * w - 1)
    row, col = np.divmod(pick, w)
    el = ((row + 0.5) / h - 0.5) * np.pi
    phi = (0.5 - (col + 0.5) / w) * 2 * np.pi + sky.rotation_z
    picked = np.column_stack([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)])
    d = np.vstack([uniform, picked])
    # densities per steradian of both strategies at every direction
    u, v = equirect_uv(d, sky.rotation_z)
    cc = np.minimum((u * w).astype(np.int64), w - 1)
    rr = np.clip((v * h).astype(np.int64), 0, h - 1)
    p_img = power[rr, cc] / total / omega[rr, cc]
    denom = k_u / (4 * np.pi) + k_i * p_img
    return d, sky.radiance(d) / denom[:, None]


def sky_irradiance(
    sky: Sky, rays, points: np.ndarray, normals: np.ndarray, extent: float, samples: int = 512
) -> tuple[np.ndarray, int]:
    """Irradiance (m, 3) from the sky at points with unit normals (m, 3), shadowed; and rays cast.

    Deterministic: every point uses the same world directions (sky_directions)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, np.float64).reshape(-1, 3)
    H = np.zeros((len(pts), 3))
    if len(pts) == 0 or not sky.emits:
        return H, 0
    dirs, weights = sky_directions(sky, samples)
    eps = 1e-6 * max(extent, 1e-300)
    cast = 0
    step = max(1, _CHUNK_RAYS // len(dirs))
    for c0 in range(0, len(pts), step):
        rs = np.arange(c0, min(len(pts), c0 + step))
        # (r, k) elementwise, not a matrix product: a BLAS product's rounding may depend on a
        # row's place in the block, so a point's cosines would depend on the points around it
        cos = nrm[rs, 0:1] * dirs[:, 0] + nrm[rs, 1:2] * dirs[:, 1] + nrm[rs, 2:3] * dirs[:, 2]
        r_i, k_i = np.nonzero(cos > 0)
        if len(r_i) == 0:
            continue
        w = dirs[k_i]
        through = rays.transmittance(
            shadow_origin(pts[rs[r_i]], nrm[rs[r_i]], w, eps), w, np.full(len(r_i), np.inf)
        )
        cast += len(r_i)
        # cos x the share of light that gets through, as a dense (points, directions) matrix
        seen = np.zeros(cos.shape)
        open_ = through > 0
        seen[r_i[open_], k_i[open_]] = cos[r_i[open_], k_i[open_]] * through[open_]
        # a running sum over the directions adds each point's terms in one order whatever points
        # share its chunk (a matrix product or a sum over a 3-d axis may not), so a point gets the
        # same bits with a mask of points or without (direct_irradiance's sky_at), on every CPU
        H[rs] += np.cumsum(seen[:, None, :] * weights.T, axis=2)[:, :, -1]
    return H, cast
