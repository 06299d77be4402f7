"""Ray queries against scene triangles: embreex when available, a plain numpy fallback otherwise.

Both backends answer the same two questions on float64 inputs, and tests compare them:
closest_hit (first triangle along each ray within [0, tmax]) and occluded (any hit).
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


class NumpyRays:
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


class EmbreeRays:
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


def make_rays(vertices: np.ndarray, triangles: np.ndarray, backend: str = "auto"):
    """A ray backend over the triangles: "embree", "numpy", or "auto" (embree when installed)."""
    if backend == "numpy" or (backend == "auto" and _emb_scene is None):
        return NumpyRays(vertices, triangles)
    if _emb_scene is None:
        raise ImportError("embreex is not installed")
    return EmbreeRays(vertices, triangles)


def has_embree() -> bool:
    return _emb_scene is not None
