"""Placement on planar sheets: a grid aligned with each chart, disks inside, squares on border cells
(curved sheets: curved.py).

Placement depends on areas and a target spacing, never on how finely the mesh is tessellated.
Every point of a sheet ends up inside at least one patch: a grid cell is covered by the disk
circumscribing it (or by a square equal to it), and a voxel's surface samples by a disk
reaching its farthest sample plus the sampling gap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from ..geometry import start_of, tangent_frame, unique_rows
from ..names import SHAPE_DISK, SHAPE_SQUARE


@dataclass
class Placed:
    """Patches placed on one sheet (arrays of equal length k)."""

    centers: np.ndarray  # (k, 3)
    normals: np.ndarray  # (k, 3)
    tangents: np.ndarray  # (k, 3)
    radii: np.ndarray  # (k,)
    shapes: np.ndarray  # (k,) int8
    thickness: np.ndarray  # (k,)
    min_cos: np.ndarray  # (k,)
    triangle: np.ndarray  # (k,) int64: a triangle (of those given) of the sheet under the patch


def _ranges(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For integer ranges [lo_k, hi_k] give (owner k, value) pairs, vectorised."""
    counts = np.maximum(hi - lo + 1, 0)
    owner = np.repeat(np.arange(len(lo)), counts)
    start = np.cumsum(counts) - counts
    value = lo[owner] + np.arange(counts.sum()) - start[owner]
    return owner, value


def plane_frame(points2d: np.ndarray) -> float:
    """Angle (radians) of the minimum-area bounding rectangle of 2-D points (rotating calipers)."""
    pts = points2d
    try:
        hull = pts[ConvexHull(pts).vertices]
    except QhullError:  # collinear or too few points: any orientation will do
        return 0.0
    edges = np.roll(hull, -1, axis=0) - hull
    ang = np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2)
    c, s = np.cos(ang), np.sin(ang)
    x = hull[:, 0][None] * c[:, None] + hull[:, 1][None] * s[:, None]
    y = -hull[:, 0][None] * s[:, None] + hull[:, 1][None] * c[:, None]
    area = np.ptp(x, axis=1) * np.ptp(y, axis=1)
    # Among near-minimal rectangles prefer the smallest angle, so results are deterministic.
    good = area <= area.min() * (1 + 1e-9)
    return float(np.min(ang[good]))


def _sat_overlap(tri2d: np.ndarray, lo: np.ndarray, hi: np.ndarray, eps) -> np.ndarray:
    """Triangles (m, 3, 2) and rectangles [lo, hi] (m, 2) overlap with positive area (SAT, margin
    eps: one, or one per pair (m,))."""
    eps = np.asarray(eps, np.float64)
    e2 = eps[:, None] if eps.ndim else eps
    ok = np.all(tri2d.max(axis=1) > lo + e2, axis=1) & np.all(tri2d.min(axis=1) < hi - e2, axis=1)
    corners = np.stack(
        [lo, np.stack([hi[:, 0], lo[:, 1]], 1), hi, np.stack([lo[:, 0], hi[:, 1]], 1)], axis=1
    )  # (m, 4, 2)
    for k in range(3):
        e = tri2d[:, (k + 1) % 3] - tri2d[:, k]
        nrm = np.stack([-e[:, 1], e[:, 0]], 1)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        pt = np.einsum("mvk,mk->mv", tri2d, nrm)
        pr = np.einsum("mvk,mk->mv", corners, nrm)
        ok &= (pt.max(1) > pr.min(1) + eps) & (pr.max(1) > pt.min(1) + eps)
    return ok


def _segment_touches(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray, eps) -> np.ndarray:
    """Segments a-b (m, 2) touch or cross the closed rectangles [lo - eps, hi + eps] (m, 2); eps:
    one, or one per segment (m,)."""
    eps = np.asarray(eps, np.float64)
    e2 = eps[:, None] if eps.ndim else eps
    lo, hi = lo - e2, hi + e2
    ok = np.all(np.maximum(a, b) >= lo, axis=1) & np.all(np.minimum(a, b) <= hi, axis=1)
    d = b - a
    nrm = np.stack([-d[:, 1], d[:, 0]], 1)
    corners = np.stack([lo, np.stack([hi[:, 0], lo[:, 1]], 1), hi, np.stack([lo[:, 0], hi[:, 1]], 1)], axis=1)
    side = np.einsum("mvk,mk->mv", corners - a[:, None], nrm)
    ok &= (side.min(1) <= 0) & (side.max(1) >= 0)
    return ok


def grid_angle(corners: np.ndarray, normal: np.ndarray) -> float:
    """The turn of a planar sheet's grid (triangles (T, 3, 3), normal (3,)) from tangent_frame's
    first axis: its minimum-area bounding rectangle's (plane_frame). It does not depend on the
    spacing, so placing a sheet again may reuse it (place_planar's `angle`)."""
    n = normal / np.linalg.norm(normal)
    e1, e2 = tangent_frame(n)
    rel = corners.reshape(-1, 3) - corners.reshape(-1, 3).mean(axis=0)
    return plane_frame(np.stack([rel @ e1, rel @ e2], axis=-1))


def place_planar(
    corners: np.ndarray,
    normal: np.ndarray,
    spacing: float,
    overlap: float,
    shapes: str,
    extent: float,
    angle: float | None = None,
    count_only: bool = False,
) -> Placed | int:
    """Grid patches on one planar sheet given its triangles (T, 3, 3) and the sheet's unit normal;
    angle: its grid_angle() when known. count_only: how many, without placing them."""
    ang = grid_angle(corners, normal) if angle is None else angle
    got = place_planar_many(
        corners,
        np.zeros(len(corners), np.int64),
        np.reshape(normal, (1, 3)),
        np.array([spacing]),
        overlap,
        shapes,
        extent,
        np.array([ang]),
        count_only,
    )
    return int(got[0]) if count_only else got[0]


def place_planar_many(
    corners: np.ndarray,
    owner: np.ndarray,
    normals: np.ndarray,
    spacing: np.ndarray,
    overlap: float,
    shapes: str,
    extent: float,
    angles: np.ndarray,
    count_only: bool = False,
) -> tuple[Placed, np.ndarray] | np.ndarray:
    """Grid patches on many planar sheets at once, each exactly as placed alone (no Python loop).

    corners (m, 3, 3): the triangles of len(normals) sheets, grouped by sheet (owner (m,) ascending,
    every sheet at least one triangle); normals (S, 3) the sheets' normals (any length); spacing
    (S,); angles (S,) their grid_angle(). Each sheet's grid is aligned with its bounding
    rectangle, cells of at most `spacing`, one patch per cell a triangle overlaps with area: a
    square on cells a border edge touches (shapes AUTO), else the disk circumscribing the cell.
    Returns (Placed, k_per (S,)): the patches grouped by sheet (triangle indexing corners), or
    with count_only the counts (S,) alone.
    """
    S = len(normals)
    owner = np.asarray(owner, np.int64)
    n = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    e1, e2 = tangent_frame(n)
    tri_per = np.bincount(owner, minlength=S)
    first = start_of(tri_per)
    origin = np.add.reduceat(corners.sum(axis=1), first, axis=0) / (3 * tri_per)[:, None]
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    t1 = c * e1 + s * e2
    t2 = np.cross(n, t1)
    rel = corners - origin[owner][:, None]
    p2 = np.stack([np.einsum("tvk,tk->tv", rel, t1[owner]), np.einsum("tvk,tk->tv", rel, t2[owner])], -1)
    lo = np.minimum.reduceat(p2.min(axis=1), first, axis=0)
    hi = np.maximum.reduceat(p2.max(axis=1), first, axis=0)
    ncell = np.maximum(np.ceil((hi - lo) / spacing[:, None] - 1e-9), 1).astype(np.int64)
    h = np.maximum((hi - lo) / ncell, 1e-300)
    eps = 1e-9 * np.maximum(extent, np.max(hi - lo, axis=1))
    base = start_of(ncell[:, 0] * ncell[:, 1])  # cell keys: base[sheet] + ix * ny + iy
    # Candidate (triangle, cell) pairs from each triangle's bounding box, then exact overlap.
    lo_t, h_t, n_t = lo[owner], h[owner], ncell[owner]
    tlo = np.floor((p2.min(axis=1) - lo_t) / h_t).astype(np.int64).clip(0, n_t - 1)
    thi = np.floor((p2.max(axis=1) - lo_t) / h_t).astype(np.int64).clip(0, n_t - 1)
    tx, ix = _ranges(tlo[:, 0], thi[:, 0])
    rep = thi[tx, 1] - tlo[tx, 1] + 1
    pair = np.repeat(tx, rep)  # the triangle of each pair
    ixr = np.repeat(ix, rep)
    iy = tlo[pair, 1] + np.arange(rep.sum()) - np.repeat(start_of(rep), rep)
    sheet = owner[pair]
    clo = lo[sheet] + np.stack([ixr, iy], 1) * h[sheet]
    hit = _sat_overlap(p2[pair], clo, clo + h[sheet], eps[sheet])
    key = base[sheet[hit]] + ixr[hit] * ncell[sheet[hit], 1] + iy[hit]
    cells, at = np.unique(key, return_index=True)
    cell_sheet = sheet[hit][at]
    k_per = np.bincount(cell_sheet, minlength=S)
    if count_only:
        return k_per
    cell_tri = pair[hit][at]  # a triangle overlapping each cell (its patch's sheet is under it)
    local = cells - base[cell_sheet]
    cx, cy = local // ncell[cell_sheet, 1], local % ncell[cell_sheet, 1]
    square = np.full(len(cells), shapes == "SQUARES")
    if shapes == "AUTO":
        square = np.isin(cells, _border_cells(p2, owner, lo, h, ncell, eps, base))
    lo_c, hi_c, h_c, eps_c = lo[cell_sheet], hi[cell_sheet], h[cell_sheet], eps[cell_sheet]
    centre2 = lo_c + (np.stack([cx, cy], 1) + 0.5) * h_c
    frame = (origin[cell_sheet], t1[cell_sheet], t2[cell_sheet], n[cell_sheet])
    placed = _cell_patches(lo_c, hi_c, h_c, centre2, square, overlap, eps_c[:, None], frame, extent, cell_tri)
    return placed, k_per


def _cell_patches(lo, hi, h, centre2, square, overlap, eps, frame, extent, triangle) -> Placed:
    """One patch per grid cell (m,): a disk circumscribing the cell, or where `square` a square
    equal to it, grown by `overlap`. lo, hi (m, 2): the rectangle of the cell's sheet in its plane,
    h (m, 2) the cell's sides, centre2 (m, 2) its centre there; frame: (origin, t1, t2, n) per cell,
    the plane's origin, axes and normal; triangle (m,) a triangle under each patch."""
    half_diag = 0.5 * np.hypot(h[:, 0], h[:, 1])
    half_side = 0.5 * h.max(axis=1)
    radii = overlap * np.where(square, half_side, half_diag)
    # Pull patches that stick out of the sheet's bounding rectangle back inside, as far as
    # keeps their own cell covered: on rectangular sheets no support is then clipped, so the
    # integration rule needs no refinement at the borders.
    slack = np.where(square, radii - half_side, (radii - half_diag) / np.sqrt(2.0))[:, None]
    reach = radii[:, None]
    low = np.maximum(lo + reach, centre2 - slack)
    high = np.minimum(hi - reach, centre2 + slack)
    centre2 = np.where(low <= high + eps, np.minimum(np.maximum(centre2, low), high + eps), centre2)
    origin, t1, t2, n = frame
    return Placed(
        centers=origin + centre2[:, :1] * t1 + centre2[:, 1:] * t2,
        normals=n,
        tangents=t1,
        radii=radii,
        shapes=np.where(square, SHAPE_SQUARE, SHAPE_DISK).astype(np.int8),
        thickness=1e-3 * radii + 1e-6 * extent,
        min_cos=np.full(len(radii), 0.9),
        triangle=triangle,
    )


def _border_cells(p2, owner, lo, h, ncell, eps, base) -> np.ndarray:
    """Keys of the cells (as place_planar_many's) that a border edge of their sheet touches: an edge
    used once among the sheet's triangles (p2 (m, 3, 2) in the sheets' planes, welded by position)."""
    e_a = p2[:, [0, 1, 2]].reshape(-1, 2)
    e_b = p2[:, [1, 2, 0]].reshape(-1, 2)
    sheet = np.repeat(owner, 3)
    quantum = (eps * 100)[sheet, None]
    qa = np.round(e_a / quantum).astype(np.int64)
    qb = np.round(e_b / quantum).astype(np.int64)
    swap = (qa[:, 0] > qb[:, 0]) | ((qa[:, 0] == qb[:, 0]) & (qa[:, 1] > qb[:, 1]))
    weld = np.column_stack([sheet, np.where(swap[:, None], qb, qa), np.where(swap[:, None], qa, qb)])
    _, inv, cnt = unique_rows(weld, return_inverse=True, return_counts=True)
    border = cnt[inv] == 1
    ba, bb, bs = e_a[border], e_b[border], sheet[border]
    if len(ba) == 0:
        return np.zeros(0, np.int64)
    lo_b, h_b, n_b, eps_b = lo[bs], h[bs], ncell[bs], eps[bs, None]
    blo = np.floor((np.minimum(ba, bb) - eps_b - lo_b) / h_b).astype(np.int64).clip(0, n_b - 1)
    bhi = np.floor((np.maximum(ba, bb) + eps_b - lo_b) / h_b).astype(np.int64).clip(0, n_b - 1)
    bx, jx = _ranges(blo[:, 0], bhi[:, 0])
    rep = bhi[bx, 1] - blo[bx, 1] + 1
    edge = np.repeat(bx, rep)
    jxr = np.repeat(jx, rep)
    jy = blo[edge, 1] + np.arange(rep.sum()) - np.repeat(start_of(rep), rep)
    es = bs[edge]
    clo = lo[es] + np.stack([jxr, jy], 1) * h[es]
    touch = _segment_touches(ba[edge], bb[edge], clo, clo + h[es], eps[es])
    return np.unique(base[es[touch]] + jxr[touch] * ncell[es[touch], 1] + jy[touch])


def place_planar_small(
    corners: np.ndarray,
    sheet: np.ndarray,
    count: int,
    normal: np.ndarray,
    spacing: np.ndarray,
    overlap: float,
    shapes: str,
    extent: float,
) -> tuple[np.ndarray, np.ndarray, Placed]:
    """place_planar for many small planar sheets at once (no Python loop over sheets).

    corners (m, 3, 3) the triangles of `count` sheets, grouped by sheet (sheet (m,) ascending,
    a few triangles each), normal (count, 3), spacing (count,). Sheets that fit in one grid
    cell get their one patch here; returns (done (count,) bool, which sheets got a patch
    (k,), their Placed (k patches, triangle indexing `corners`)). Sheets not done must go
    through place_planar. Same placement as place_planar (the bounding
    rectangle's angle is searched among all corner pairs, a superset of the hull's edges).
    """
    n = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    helper = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    e1 = np.cross(helper, n)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(n, e1)
    k_per = np.bincount(sheet, minlength=count)
    first = np.cumsum(k_per) - k_per
    origin = np.add.reduceat(corners.sum(axis=1), first, axis=0) / (3 * k_per)[:, None]
    rel = corners - origin[sheet][:, None]
    p2 = np.stack([np.einsum("tvk,tk->tv", rel, e1[sheet]), np.einsum("tvk,tk->tv", rel, e2[sheet])], -1)
    # Points per sheet, padded with the sheet's first point (which changes no extent).
    width = 3 * int(k_per.max())
    slot = (np.arange(len(sheet)) - first[sheet])[:, None] * 3 + np.arange(3)[None]
    pts = np.repeat(p2[first, :1], width, axis=1)
    pts[np.repeat(sheet, 3), slot.ravel()] = p2.reshape(-1, 2)
    d = pts[:, None, :, :] - pts[:, :, None, :]  # (S, P, P, 2) every pair
    ang = np.mod(np.arctan2(d[..., 1], d[..., 0]), np.pi / 2).reshape(count, -1)
    ang = np.where(np.hypot(d[..., 0], d[..., 1]).reshape(count, -1) > 0, ang, np.nan)
    c, s = np.cos(ang), np.sin(ang)  # (S, A)
    x = pts[:, None, :, 0] * c[..., None] + pts[:, None, :, 1] * s[..., None]  # (S, A, P)
    y = -pts[:, None, :, 0] * s[..., None] + pts[:, None, :, 1] * c[..., None]
    with np.errstate(invalid="ignore"):
        area = np.ptp(x, axis=2) * np.ptp(y, axis=2)
        area = np.where(np.isnan(area), np.inf, area)  # coincident pairs give no angle
        good = area <= area.min(axis=1, keepdims=True) * (1 + 1e-9)
    best = np.min(np.where(good, ang, np.inf), axis=1)
    best = np.where(np.isfinite(best), best, 0.0)
    c, s = np.cos(best)[:, None], np.sin(best)[:, None]
    t1 = c * e1 + s * e2
    t2 = np.cross(n, t1)
    p2 = np.stack([np.einsum("tvk,tk->tv", rel, t1[sheet]), np.einsum("tvk,tk->tv", rel, t2[sheet])], -1)
    lo = np.minimum.reduceat(p2.min(axis=1), first, axis=0)
    hi = np.maximum.reduceat(p2.max(axis=1), first, axis=0)
    ncell = np.maximum(np.ceil((hi - lo) / spacing[:, None] - 1e-9), 1).astype(np.int64)
    one = np.all(ncell == 1, axis=1)
    h = np.maximum(hi - lo, 1e-300)
    eps = 1e-9 * extent  # as place_planar's: a sheet within one cell is smaller than the scene
    hit = _sat_overlap(p2, lo[sheet], (lo + h)[sheet], eps) & one[sheet]
    idx = np.flatnonzero(hit)
    has = np.zeros(count, bool)
    has[sheet[idx]] = True
    tri_first = np.full(count, -1, np.int64)
    tri_first[sheet[idx[::-1]]] = idx[::-1]  # the first hit triangle of each sheet
    done = one.copy()  # one-cell sheets are done (with no patch when no triangle has area)
    keep = np.flatnonzero(one & has)
    lo, hi, h = lo[keep], hi[keep], h[keep]
    k = len(keep)
    square = np.full(k, shapes != "DISKS")  # a planar sheet always has border edges in its one cell
    frame = (origin[keep], t1[keep], t2[keep], n[keep])
    placed = _cell_patches(lo, hi, h, lo + 0.5 * h, square, overlap, eps, frame, extent, tri_first[keep])
    return done, keep, placed
