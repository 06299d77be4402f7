"""Small geometric rules shared across the engine: tangent frames around unit normals (patch
placement, direction sampling) and a triangle's midpoint rule (emitter samples, texture means)."""

from __future__ import annotations

import numpy as np


def tangent_frame(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents and bitangents completing unit normals to right-handed frames (t, b, n).

    normals: (m, 3), or one normal (3,); the results have the same shape. The tangent is built
    from the coordinate axis least aligned with the normal, so it is well defined for any normal.
    """
    helper = np.eye(3)[np.argmin(np.abs(normals), axis=-1)]
    t = np.cross(helper, normals)
    t /= np.linalg.norm(t) if t.ndim == 1 else np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(normals, t)


def subtriangle_centroids(k: int) -> np.ndarray:
    """Barycentric (u, v) of the centroids of the k^2 congruent triangles a triangle splits into."""
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    up = (i + j) <= k - 1
    down = (i + j) <= k - 2
    uv_up = np.column_stack([(i[up] + 1 / 3) / k, (j[up] + 1 / 3) / k])
    uv_down = np.column_stack([(i[down] + 2 / 3) / k, (j[down] + 2 / 3) / k])
    return np.vstack([uv_up, uv_down])
