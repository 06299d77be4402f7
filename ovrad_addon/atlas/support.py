"""Where a patch lives on the surface: membership, beta and alpha at points.

A surface point M (with its sheet: chart and side) is in patch D_i when it lies on the patch's
sheet, its normal agrees with n_i (cosine >= min_cos_i), it is within thickness_i of the patch
plane, and its projection M_i onto the plane falls inside the disk or square. This is the
paper's association M -> M_i, and it is what stops a patch leaking across a crease, a gap, a
thin wall or onto a surface facing away. A ball patch (clutter.py) holds the points of its sheet
within its radius of its centre, whatever their normals (its min_cos is below -1 and its
thickness its radius).
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix

from ..names import SHAPE_BALL, SHAPE_SQUARE

RIM_TOLERANCE = 1e-5  # relative to the patch radius


# Columns of patch_table(): what the membership test reads of a patch, one row per patch, so that
# a (point, patch) pair gathers all of it with one np.take of its row instead of one take per
# field. The shape code is exact as float64.
CENTER, TANGENT, BITANGENT, NORMAL = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
RADIUS, THICKNESS, MIN_COS, SHAPE = 12, 13, 14, 15
TABLE_WIDTH = 16


def patch_table(patches) -> np.ndarray:
    """(n, TABLE_WIDTH) float64: each patch's centre, tangent, bitangent, normal, radius,
    thickness, min_cos and shape, in the columns above. Atlas.table keeps it."""
    t = np.empty((len(patches.centers), TABLE_WIDTH))
    t[:, CENTER] = patches.centers
    t[:, TANGENT] = patches.tangents
    t[:, BITANGENT] = patches.bitangents
    t[:, NORMAL] = patches.normals
    t[:, RADIUS] = patches.radii
    t[:, THICKNESS] = patches.thickness
    t[:, MIN_COS] = patches.min_cos
    t[:, SHAPE] = patches.shapes
    return t


def beta_of(
    patches, idx: np.ndarray, x: np.ndarray, y: np.ndarray, beta: str, h: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """(inside, beta) for points at in-plane coords (x, y) of patches idx, h their height above
    the plane (read by ball patches only; None: 0); beta is 0 outside."""
    p = np.take(patches.table, idx, axis=0)
    return _inside_beta(p[:, RADIUS], p[:, SHAPE], x, y, beta, h)


def _inside_beta(r, shape, x, y, beta: str, h=None, member=None) -> tuple[np.ndarray, np.ndarray]:
    """beta_of on gathered radii and shapes; member (m,) bool: the pairs the other tests keep, the
    only ones whose beta is computed (None: all); beta is 0 outside and off member."""
    u, v = x / r, y / r
    d2 = u * u + v * v
    square = shape == SHAPE_SQUARE
    if h is not None:
        ball = np.flatnonzero(shape == SHAPE_BALL)
        if len(ball):
            d2[ball] += np.square(np.take(h, ball) / np.take(r, ball))
    # A hair of tolerance: points exactly on a patch's rim (mesh vertices on a chart border,
    # stored in float32 by Blender) must still count as covered.
    inside = d2 <= (1.0 + RIM_TOLERANCE) ** 2
    sq = np.flatnonzero(square)
    if len(sq):
        inside[sq] = np.maximum(np.abs(np.take(u, sq)), np.abs(np.take(v, sq))) <= 1.0 + RIM_TOLERANCE
    keep = inside if member is None else inside & member
    if beta == "box":
        return inside, keep.astype(np.float64)
    b = np.zeros(len(d2))
    k = np.flatnonzero(keep)
    d2k = np.take(d2, k)
    bk = np.square(np.clip(1.0 - d2k, 0.0, None))
    s = np.flatnonzero(np.take(square, k))
    if len(s):
        ks = np.take(k, s)
        uk, vk = np.take(u, ks), np.take(v, ks)
        bk[s] = np.clip(1.0 - uk * uk, 0.0, None) * np.clip(1.0 - vk * vk, 0.0, None)
    b[k] = bk
    return inside, b


# Pairs pair_beta tests at once: their rows of the patch table (128 bytes a pair) and every
# temporary stay in cache (half a million pairs at once took twice as long per pair)
PAIR_BLOCK = 1 << 15


def pair_beta(patches, idx, points, normals, sheets, beta: str) -> tuple[np.ndarray, np.ndarray]:
    """Membership (m,) bool and beta (m,) for paired rows (point j, patch idx[j]); sheets (m,) the
    points' sheets, or None when every pair is known to share its sheet (PatchGrid candidates)."""
    idx = np.asarray(idx)
    if len(idx) > PAIR_BLOCK:
        member, b = np.empty(len(idx), bool), np.empty(len(idx))
        for lo in range(0, len(idx), PAIR_BLOCK):
            s = slice(lo, lo + PAIR_BLOCK)
            member[s], b[s] = pair_beta(
                patches, idx[s], points[s], normals[s], None if sheets is None else sheets[s], beta
            )
        return member, b
    if sheets is None:
        return _same_sheet_beta(patches, idx, points, normals, beta)
    member = np.zeros(len(idx), bool)
    b = np.zeros(len(idx))
    # Cheap rejections first (sheet, then distance to the centre), full test on what is left.
    cand = np.flatnonzero(sheets == np.take(patches.sheet, idx))
    i = np.take(idx, cand)
    rel = np.take(points, cand, axis=0) - np.take(patches.centers, i, axis=0)
    # no member is farther than its bounding radius (with the rim tolerance) in the plane and
    # its thickness off it
    br = np.take(patches.bounding_radii, i) * (1.0 + 10.0 * RIM_TOLERANCE)
    near = np.flatnonzero(np.einsum("ij,ij->i", rel, rel) <= br * br + np.take(patches.thickness, i) ** 2)
    cand = np.take(cand, near)
    member[cand], b[cand] = _same_sheet_beta(
        patches, np.take(i, near), np.take(points, cand, axis=0), np.take(normals, cand, axis=0), beta
    )
    return member, b


def _same_sheet_beta(patches, i, points, normals, beta: str) -> tuple[np.ndarray, np.ndarray]:
    """The full membership test and beta for pairs already known to share their sheet (the
    candidates of a PatchGrid, or what pair_beta's rejections leave)."""
    return _table_beta(np.take(patches.table, i, axis=0), points, normals, beta)


def _table_beta(p, points, normals, beta: str) -> tuple[np.ndarray, np.ndarray]:
    """_same_sheet_beta on the pairs' rows p (m, TABLE_WIDTH) of the patch table."""
    rel = points - p[:, CENTER]
    x = np.einsum("ij,ij->i", rel, p[:, TANGENT])
    y = np.einsum("ij,ij->i", rel, p[:, BITANGENT])
    n_i = p[:, NORMAL]
    h = np.einsum("ij,ij->i", rel, n_i)
    ok = np.einsum("ij,ij->i", normals, n_i) >= p[:, MIN_COS]
    ok &= np.abs(h) <= p[:, THICKNESS]
    inside, b = _inside_beta(p[:, RADIUS], p[:, SHAPE], x, y, beta, h, ok)
    return ok & inside, b


def alpha_from_pairs(
    rows: np.ndarray, cols: np.ndarray, member: np.ndarray, b: np.ndarray, shape
) -> csr_matrix:
    """Partition of unity alpha (sparse, points x patches) from membership and beta of candidate pairs.

    alpha_i = beta_i / sum_j beta_j. Where every covering beta is 0 (a point on the rims of all
    its smooth patches) the box profile is used instead, so alpha still sums to 1 there.
    """
    rows, cols, b = rows[member], cols[member], b[member]
    return csr_matrix((alpha_values(rows, b, shape[0]), (rows, cols)), shape=shape)


def alpha_values(rows: np.ndarray, b: np.ndarray, m: int) -> np.ndarray:
    """alpha (k,) of member pairs (rows (k,) in [0, m), beta b (k,)), as alpha_from_pairs gives it."""
    bsum = np.bincount(rows, weights=b, minlength=m)
    count = np.bincount(rows, minlength=m).astype(np.float64)
    bs = np.take(bsum, rows)
    zero = bs <= 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(zero, 1.0 / np.take(count, rows), b / bs)
