"""Ray queries against scene triangles: embreex when available, a plain numpy fallback otherwise.

Both backends answer the same two geometric questions on float64 inputs, and tests compare them:
closest_hit (first triangle along each ray within [0, tmax]) and occluded (any hit). Light asks
two more: light_hit (the first surface that stops a ray) and transmittance (the share of light
that gets through); on opaque surfaces they are closest_hit and not occluded. Where materials are
see-through (alpha below 1, scene.coverage), SeeThroughRays answers them: a shadow ray's
transmittance is the product of 1 - alpha over the surfaces it crosses (exact), and a ray that
meets a surface of alpha a stops there when a deterministic hash of the ray and the triangle,
uniform in [0, 1), is below a (exact for alpha-cut masks, 0 or 1; partial alpha averages to
1 - a over the many rays of the transport and the gather).
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..parallel import WORKERS

try:  # embreex ships wheels for the main platforms; elsewhere the numpy backend answers.
    from embreex import mesh_construction as _emb_mesh
    from embreex import rtcore_scene as _emb_scene
except ImportError:  # pragma: no cover - exercised only where embreex is missing
    _emb_scene = None

_BATCH = 1 << 18

_POOL: ThreadPoolExecutor | None = None

_POOL_LOCK = threading.Lock()


def _query_pool() -> ThreadPoolExecutor:
    """The threads every embree scene queries on: one pool for the process, made on first use,
    so an index (one per atlas build, prepare or bake) leaves no threads behind."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="ovrad-rays")
        return _POOL


class _Opaque:
    """light_hit and transmittance where every surface stops light."""

    def light_hit(self, origins, directions, tmax) -> tuple[np.ndarray, np.ndarray]:
        """t (m,) and triangle (m,) of the first surface that stops each ray; (inf, -1): none."""
        return self.closest_hit(origins, directions, tmax)

    def transmittance(self, origins, directions, tmax) -> np.ndarray:
        """(m,) float: the share of light that travels each ray unblocked (0 or 1 here)."""
        return (~self.occluded(origins, directions, tmax)).astype(np.float64)


class NumpyRays(_Opaque):
    """Brute-force Moller-Trumbore in chunks: exact reference, fine for a few hundred triangles."""

    name = "numpy"

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        c = np.asarray(vertices, np.float64)[np.asarray(triangles, np.int64)]
        self._p0 = c[:, 0]
        self._e1 = c[:, 1] - c[:, 0]
        self._e2 = c[:, 2] - c[:, 0]

    def closest_hit(self, origins, directions, tmax) -> tuple[np.ndarray, np.ndarray]:
        """t (m,) and triangle index (m,) of the first hit with t in [0, tmax]; (inf, -1) for a miss."""
        o = np.asarray(origins, np.float64)
        d = np.asarray(directions, np.float64)
        tm = np.broadcast_to(np.asarray(tmax, np.float64), (len(o),))
        best_t = np.full(len(o), np.inf)
        best_i = np.full(len(o), -1, np.int64)
        n_tri = len(self._p0)
        step = max(1, 4_000_000 // max(n_tri, 1))
        for s in range(0, len(o), step):
            oo, dd = o[s : s + step, None, :], d[s : s + step, None, :]
            pvec = np.cross(dd, self._e2[None])
            det = np.einsum("rtk,tk->rt", pvec, self._e1)
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / det
                tvec = oo - self._p0[None]
                u = np.einsum("rtk,rtk->rt", tvec, pvec) * inv
                qvec = np.cross(tvec, self._e1[None])
                v = np.einsum("rtk,rk->rt", qvec, dd[:, 0]) * inv
                t = np.einsum("rtk,tk->rt", qvec, self._e2) * inv
            ok = (det != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= tm[s : s + step, None])
            t = np.where(ok, t, np.inf)
            i = np.argmin(t, axis=1)
            tt = t[np.arange(len(i)), i]
            hit = np.isfinite(tt)
            best_t[s : s + step][hit] = tt[hit]
            best_i[s : s + step][hit] = i[hit]
        return best_t, best_i

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        """(m,) bool: any triangle hit with t in [0, tmax]."""
        return self.closest_hit(origins, directions, tmax)[1] >= 0


class EmbreeRays(_Opaque):
    """embreex scene over the triangles, queried in large batches on the shared query threads.

    Coordinates are shifted to the scene's centre and divided by its size before the float32
    conversion, so that precision does not depend on where the scene sits or on its scale: a
    scene scaled by 1e-3 or 1e3 gives the same float32 geometry, hence the same hits.
    """

    name = "embree"

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray) -> None:
        v = np.asarray(vertices, np.float64)
        self._shift = 0.5 * (v.min(axis=0) + v.max(axis=0)) if len(v) else np.zeros(3)
        size = float(np.max(v.max(axis=0) - v.min(axis=0))) if len(v) else 1.0
        self._scale = size if size > 0 else 1.0
        self._scene = _emb_scene.EmbreeScene()
        self._mesh = _emb_mesh.TriangleMesh(
            self._scene,
            np.ascontiguousarray((v - self._shift) / self._scale, np.float32),
            np.ascontiguousarray(triangles, np.int32),
        )

    def _run(self, origins, directions, tmax, query: str):
        o = np.ascontiguousarray((np.asarray(origins, np.float64) - self._shift) / self._scale, np.float32)
        d = np.ascontiguousarray(directions, np.float32)
        tm = np.broadcast_to(np.asarray(tmax, np.float64) / self._scale, (len(o),))
        tm = np.ascontiguousarray(np.minimum(tm, 3.0e38), np.float32)
        chunks = [slice(s, s + _BATCH) for s in range(0, len(o), _BATCH)]

        def one(sl):
            if query == "OCCLUDED":
                return self._scene.run(o[sl], d[sl], dists=tm[sl].copy(), query="OCCLUDED")
            return self._scene.run(o[sl], d[sl], dists=tm[sl].copy(), output=1)

        return list(_query_pool().map(one, chunks))

    def closest_hit(self, origins, directions, tmax) -> tuple[np.ndarray, np.ndarray]:
        if len(origins) == 0:
            return np.zeros(0), np.zeros(0, np.int64)
        parts = self._run(origins, directions, tmax, "INTERSECT")
        prim = np.concatenate([p["primID"] for p in parts]).astype(np.int64)
        t = np.concatenate([p["tfar"] for p in parts]).astype(np.float64) * self._scale
        t[prim < 0] = np.inf
        return t, prim

    def occluded(self, origins, directions, tmax) -> np.ndarray:
        if len(origins) == 0:
            return np.zeros(0, bool)
        parts = self._run(origins, directions, tmax, "OCCLUDED")
        return np.concatenate(parts) >= 0


MAX_LAYERS = 64  # see-through surfaces a ray crosses at most; beyond, the next one stops it
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _mix64(z: np.ndarray) -> np.ndarray:
    """splitmix64's finaliser on uint64 (wrapping arithmetic)."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def ray_uniform(origins: np.ndarray, directions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(m,) numbers uniform in [0, 1), a function of each ray's float64 origin and direction bits
    and the triangle it met only (splitmix64 over those words): the same ray gives the same number
    in any batch and on any thread."""
    o = np.ascontiguousarray(origins, np.float64).view(np.uint64)
    d = np.ascontiguousarray(directions, np.float64).view(np.uint64)
    words = np.concatenate([o, d, np.asarray(triangles, np.int64).astype(np.uint64)[:, None]], axis=1)
    h = np.full(len(words), _GOLDEN, np.uint64)
    with np.errstate(over="ignore"):
        for k in range(words.shape[1]):
            h = _mix64(h ^ (words[:, k] + _GOLDEN))
    return (h >> np.uint64(11)).astype(np.float64) * 2.0**-53


class SeeThroughRays:
    """A backend over triangles some of which light passes in part (see the module docstring).

    base: the opaque backend over the same triangles; alpha(triangles, points) -> (m,) the alpha
    at surface points; see_through: (T,) bool, the triangles whose alpha may be below 1; step: how
    far past a crossed surface the ray goes on (a distance in scene units)."""

    def __init__(self, base, alpha, see_through: np.ndarray, step: float) -> None:
        self.base = base
        self.name = base.name
        self._alpha = alpha
        self._see = np.asarray(see_through, bool)
        self._step = float(step)

    def closest_hit(self, origins, directions, tmax):
        return self.base.closest_hit(origins, directions, tmax)

    def occluded(self, origins, directions, tmax):
        return self.base.occluded(origins, directions, tmax)

    def _walk(self, origins, directions, tmax, stochastic: bool):
        """Each ray through the see-through surfaces it meets: (t, triangle, w), where it stopped
        ((inf, -1): past everything) and the product of 1 - alpha over what it crossed. stochastic:
        a surface stops a ray where ray_uniform (of the ray's first origin) is below its alpha;
        else only where its alpha is 1 (transmittance)."""
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        tm = np.broadcast_to(np.asarray(tmax, np.float64), (len(o),))
        t, tri = self.base.closest_hit(o, d, tm)
        w = np.ones(len(o))
        travelled = np.zeros(len(o))
        at = o.copy()
        live = np.flatnonzero(tri >= 0)
        live = live[self._see[tri[live]]]
        for _ in range(MAX_LAYERS):
            if len(live) == 0:
                break
            a = self._alpha(tri[live], at[live] + t[live, None] * d[live])
            if stochastic:
                on = ray_uniform(o[live], d[live], tri[live]) >= a
            else:
                on = a < 1.0
                w[live] *= 1.0 - a
            live = live[on]
            if len(live) == 0:
                break
            ahead = t[live] + self._step
            travelled[live] += ahead
            at[live] += ahead[:, None] * d[live]
            t2, tri2 = self.base.closest_hit(at[live], d[live], np.maximum(tm[live] - travelled[live], 0.0))
            t[live], tri[live] = t2, tri2
            live = live[(tri2 >= 0) & self._see[np.maximum(tri2, 0)]]
        return t + travelled, tri, w

    def light_hit(self, origins, directions, tmax):
        """t (m,) and triangle (m,) of the first surface that stops each ray: a see-through one
        stops it where ray_uniform is below its alpha there."""
        if len(origins) == 0:
            return self.base.closest_hit(origins, directions, tmax)
        t, tri, _ = self._walk(origins, directions, tmax, stochastic=True)
        return t, tri

    def transmittance(self, origins, directions, tmax):
        """(m,) float: the product of 1 - alpha over the see-through surfaces each ray crosses,
        0 where an opaque surface blocks it."""
        o = np.asarray(origins, np.float64).reshape(-1, 3)
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        out = (~self.base.occluded(o, d, tmax)).astype(np.float64)
        blocked = np.flatnonzero(out == 0.0)
        if len(blocked) == 0:
            return out
        tm = np.broadcast_to(np.asarray(tmax, np.float64), (len(o),))[blocked]
        _, tri, w = self._walk(o[blocked], d[blocked], tm, stochastic=False)
        out[blocked] = np.where(tri < 0, w, 0.0)
        return out


def make_rays(vertices: np.ndarray, triangles: np.ndarray, backend: str = "auto"):
    """A ray backend over the triangles: "embree", "numpy", or "auto" (embree when installed)."""
    if backend == "numpy" or (backend == "auto" and _emb_scene is None):
        return NumpyRays(vertices, triangles)
    if _emb_scene is None:
        raise ImportError("embreex is not installed")
    return EmbreeRays(vertices, triangles)


def has_embree() -> bool:
    return _emb_scene is not None


def surface_rays(surfaces, backend: str = "auto"):
    """The ray backend over a Surfaces' triangles: see-through where its materials' alpha is below
    1 (surfaces.coverage), else the opaque backend itself."""
    base = make_rays(surfaces.vertices, surfaces.triangles, backend)
    if surfaces.coverage is None:
        return base
    return SeeThroughRays(base, surfaces.opacity_at, surfaces.coverage.see_through, 1e-6 * surfaces.extent)
