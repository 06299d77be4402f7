"""Small geometric rules shared across the engine: tangent frames around unit normals (patch
placement, direction sampling) and a triangle's midpoint rule (emitter samples, texture means); and
index helpers over flat arrays of groups (unique rows, group starts, concatenated ranges)."""

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


def subtriangle_corners(k: int) -> np.ndarray:
    """(k^2, 3, 3): the barycentric weights of the corners of the k^2 congruent triangles a
    triangle splits into (row a of piece p: corner a's weights on the triangle's corners 0, 1, 2),
    each wound as the triangle is; their centroids are subtriangle_centroids(k), in its order."""
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    up = (i + j) <= k - 1
    down = (i + j) <= k - 2
    iu, ju, idn, jdn = i[up], j[up], i[down], j[down]
    # (u, v): the weights on corners 1 and 2
    u = np.vstack([np.column_stack([iu, iu + 1, iu]), np.column_stack([idn + 1, idn + 1, idn])]) / k
    v = np.vstack([np.column_stack([ju, ju, ju + 1]), np.column_stack([jdn, jdn + 1, jdn + 1])]) / k
    return np.stack([1.0 - u - v, u, v], axis=2)


def unique_rows(rows: np.ndarray, return_index=False, return_inverse=False, return_counts=False):
    """np.unique(rows, axis=0, ...) for integer rows (m, k), with the same results in the same
    (lexicographic) order: each row folded into one int64 key, column 0 the most significant, where
    the columns' ranges allow (numpy's unique over rows sorts a structured view, ~15x slower on a
    million voxel keys); np.unique over rows otherwise. The inverse is flat."""
    flags = dict(return_index=return_index, return_inverse=return_inverse, return_counts=return_counts)
    a = np.asarray(rows)
    if a.ndim != 2 or a.shape[1] == 0 or len(a) == 0 or not np.issubdtype(a.dtype, np.integer):
        return _flat_inverse(np.unique(a, axis=0, **flags), return_index, return_inverse)
    a = a.astype(np.int64, copy=False)
    lo = a.min(axis=0)
    span = a.max(axis=0) - lo + 1
    if float(np.sum(np.log2(span.astype(np.float64)))) >= 62.0:  # the key would overflow int64
        return _flat_inverse(np.unique(a, axis=0, **flags), return_index, return_inverse)
    key = a[:, 0] - lo[0]
    for j in range(1, a.shape[1]):
        key = key * span[j] + (a[:, j] - lo[j])
    out = np.unique(key, return_index=True, return_inverse=return_inverse, return_counts=return_counts)
    first = out[1]
    result = [a[first]]
    if return_index:
        result.append(first)
    result.extend(out[2:])
    return tuple(result) if len(result) > 1 else result[0]


def _flat_inverse(out, return_index: bool, return_inverse: bool):
    if not return_inverse:
        return out
    out = list(out)
    k = 1 + int(return_index)
    out[k] = np.asarray(out[k]).ravel()
    return tuple(out)


def start_of(counts: np.ndarray) -> np.ndarray:
    """First position of each group in a flat array of groups of these sizes."""
    return np.cumsum(counts) - counts


def ranges_flat(first: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenated ranges first[i] .. first[i] + counts[i] - 1."""
    return np.repeat(first - start_of(counts), counts) + np.arange(int(counts.sum()))
