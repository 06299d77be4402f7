"""Tangent frames around unit normals, shared by patch placement and direction sampling."""

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
