"""Placement on curved sheets: area-weighted samples, one disk per occupied voxel of the sheet's
spacing (slivers merged, small pieces one patch), many sheets at once."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..geometry import tangent_frame, unique_rows
from ..scene.surfaces import triangle_geometry
from .planar import Placed

SAMPLE_SPLIT = 6.0  # a curved sheet is sampled at its spacing / SAMPLE_SPLIT (build.py counts alike)


def sample_counts(areas: np.ndarray, gap: np.ndarray) -> np.ndarray:
    """Random samples sample_sheets draws on triangles of these areas at these gaps: one per gap^2,
    at least one (each triangle's three corners come on top)."""
    return np.maximum(np.ceil(areas / gap**2), 1).astype(np.int64)


def sample_sheets(
    corners: np.ndarray, sheet: np.ndarray, gap: np.ndarray, seeds: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Random surface samples about gap[s] apart on each sheet s, plus every corner. corners
    (T, 3, 3): the triangles of all sheets, grouped by sheet (sheet (T,) ascending). Returns the
    points (m, 3), their triangles (m,), their sheets (m,), ascending, and which are random (m,)
    bool. A sheet's samples do not depend on the other sheets sampled with it: its random points
    from its own stream (seeds[s]; u, then v), then its triangles' corners."""
    count = sample_counts(triangle_geometry(corners)[0], gap[sheet])
    tri = np.repeat(np.arange(len(corners)), count)
    per_sheet = np.bincount(sheet[tri], minlength=len(gap))
    u, v = np.empty(len(tri)), np.empty(len(tri))
    at = 0
    for s, c in enumerate(per_sheet.tolist()):
        rng = np.random.default_rng(int(seeds[s]))
        u[at : at + c], v[at : at + c] = rng.random(c), rng.random(c)
        at += c
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    c = corners[tri]
    pts = c[:, 0] + u[:, None] * (c[:, 1] - c[:, 0]) + v[:, None] * (c[:, 2] - c[:, 0])
    all_tri = np.concatenate([tri, np.repeat(np.arange(len(corners)), 3)])
    part = np.concatenate([np.zeros(len(tri), np.int64), np.ones(3 * len(corners), np.int64)])
    order = np.argsort(2 * sheet[all_tri] + part, kind="stable")  # per sheet: random, then corners
    all_tri = all_tri[order]
    return np.concatenate([pts, corners.reshape(-1, 3)])[order], all_tri, sheet[all_tri], part[order] == 0


# A curved sheet whose area is under this x the disk of a patch's nominal radius gets one patch.
# Production room at 100 k patches (two builds): 5.99 / 4.93 % without, 4.78 / 4.74 % at 0.7,
# 4.82 / 4.73 % at 1.0, 4.70 / 5.16 % at 0.4; its default count is unchanged up to 0.7 and 0.26
# point worse at 1.0 (pieces there are large enough for their light to vary across them).
ONE_PATCH_AREA = 0.7

# A voxel holding less of its sheet than this x spacing^2 joins the nearest voxel that holds more:
# its patch would sit almost on a neighbour's and hold a sliver of the sheet, and two such patches
# make a nearly singular block of C (production room, an atlas of 8 759 patches: three patches on
# one bent piece solved to B of -8.4, -4.9 and +9.9 where the scatter's median is 0.05).
SLIVER_AREA = 0.35

SLIVER_PIECE = 4.0  # ... on pieces under this many patch disks; larger sheets keep every voxel


def _sample_areas(tri: np.ndarray, areas: np.ndarray, random: np.ndarray) -> np.ndarray:
    """The area each of sample_sheets' points (their triangles tri (m,)) stands for, given the
    triangles' areas (T,): its triangle's area over the triangle's random samples (random (m,) bool);
    the corners stand for none."""
    count = np.bincount(tri[random], minlength=len(areas))
    return np.where(random, areas[tri] / np.maximum(count[tri], 1), 0.0)


def _merge_slivers(pts: np.ndarray, vox: np.ndarray, weight: np.ndarray, least: float) -> np.ndarray:
    """Voxel labels (m,) with every voxel holding under `least` area (weights (m,)) merged into the
    one nearest its mean among those holding more; all into one where none does."""
    k = int(vox.max()) + 1
    area = np.bincount(vox, weights=weight, minlength=k)
    small = area < least
    if not np.any(small):
        return vox
    if np.all(small):
        return np.zeros_like(vox)
    cnt = np.bincount(vox, minlength=k).astype(np.float64)
    mean = np.stack([np.bincount(vox, weights=pts[:, j], minlength=k) for j in range(3)], 1) / cnt[:, None]
    big = np.flatnonzero(~small)
    target = np.arange(k)
    target[small] = big[cKDTree(mean[big]).query(mean[small])[1]]
    _, label = np.unique(target, return_inverse=True)
    return label.reshape(-1)[vox]


def place_curved(
    corners: np.ndarray,
    tri_normals: np.ndarray,
    spacing: float,
    overlap: float,
    extent: float,
    seed: int,
    count_only: bool = False,
) -> Placed | int:
    """Disk patches on a curved sheet: one per occupied voxel of side `spacing` (count_only: how
    many, without placing them). tri_normals (T, 3) are already oriented for the sheet's side."""
    one = np.zeros(len(corners), np.int64)
    got = place_curved_many(
        corners, tri_normals, one, np.array([spacing]), overlap, extent, [seed], count_only
    )
    return int(got[0]) if count_only else got[0]


def place_curved_many(
    corners: np.ndarray,
    tri_normals: np.ndarray,
    sheet: np.ndarray,
    spacing: np.ndarray,
    overlap: float,
    extent: float,
    seeds,
    count_only: bool = False,
) -> tuple[Placed, np.ndarray] | np.ndarray:
    """Disk patches on curved sheets, one per occupied voxel of side spacing[s] on sheet s, all
    sheets at once (each placed as if alone: its own seeded samples, seeds[s]). corners (T, 3, 3)
    and tri_normals (T, 3), already oriented for their sheet's side, grouped by sheet (sheet (T,)
    ascending, from 0 to len(spacing) - 1). Returns (the patches, sheet by sheet, their
    triangles indexing corners; how many each sheet got (S,)), or with count_only only the counts.
    """
    S = len(spacing)
    spacing = np.asarray(spacing, np.float64)
    gap = spacing / SAMPLE_SPLIT
    pts, tri, ps, random = sample_sheets(corners, sheet, gap, np.asarray(seeds))
    begin = np.searchsorted(ps, np.arange(S))  # each sheet's first sample
    nrm = tri_normals[tri]
    areas = triangle_geometry(corners)[0]
    area = np.bincount(sheet, weights=areas, minlength=S)
    disk = np.pi * (overlap * spacing / np.sqrt(2.0)) ** 2
    # voxels, numbered sheet by sheet in the order of their keys. A piece smaller than a patch's
    # disk gets one patch: the voxels it crosses gave a bent scatter piece 3-8 nearly coincident
    # patches, whose block of C is nearly singular, and the transport's noise came out amplified
    # (the production room at 100 k patches: B from -5.4 to +3.3 on one piece, the scatter's
    # median 0.037)
    lo = np.minimum.reduceat(pts, begin, axis=0)
    key = np.floor((pts - lo[ps]) / spacing[ps, None]).astype(np.int64)
    key[(area < ONE_PATCH_AREA * disk)[ps]] = 0
    _, vox = unique_rows(np.column_stack([ps, key]), return_inverse=True)
    local = vox - np.minimum.reduceat(vox, begin)[ps]  # (keys sort by sheet first)
    sliver = (area >= ONE_PATCH_AREA * disk) & (area < SLIVER_PIECE * disk)
    if np.any(sliver):
        weight = _sample_areas(tri, areas, random)
        held = np.bincount(vox, weights=weight)
        least = SLIVER_AREA * spacing**2
        for s in np.flatnonzero(sliver & (np.bincount(ps[held[vox] < least[ps]], minlength=S) > 0)):
            mine = slice(begin[s], begin[s + 1] if s + 1 < S else len(ps))
            local[mine] = _merge_slivers(pts[mine], local[mine], weight[mine], least[s])
    k_per = np.maximum.reduceat(local, begin) + 1
    if count_only:
        return k_per
    vox = (np.cumsum(k_per) - k_per)[ps] + local
    k = int(k_per.sum())
    cnt = np.bincount(vox, minlength=k).astype(np.float64)
    mean = np.stack([np.bincount(vox, weights=pts[:, j], minlength=k) for j in range(3)], 1) / cnt[:, None]
    nsum = np.stack([np.bincount(vox, weights=nrm[:, j], minlength=k) for j in range(3)], 1)
    normals = nsum / np.maximum(np.linalg.norm(nsum, axis=1, keepdims=True), 1e-300)
    # Centre: the voxel's sample nearest its mean, so the patch sits on the surface.
    d_mean = np.linalg.norm(pts - mean[vox], axis=1)
    order = np.lexsort((d_mean, vox))
    first = order[np.searchsorted(vox[order], np.arange(k))]
    centers = pts[first]
    tangents = tangent_frame(normals)[0]
    rel = pts - centers[vox]
    h = np.einsum("ij,ij->i", rel, normals[vox])
    inplane = np.sqrt(np.maximum(np.einsum("ij,ij->i", rel, rel) - h * h, 0.0))
    reach = np.zeros(k)
    np.maximum.at(reach, vox, inplane)
    own_cos = np.ones(k)
    np.minimum.at(own_cos, vox, np.einsum("ij,ij->i", nrm, normals[vox]))
    patch_sheet = ps[first]
    radii = overlap * np.maximum(reach + gap[patch_sheet], spacing[patch_sheet] / np.sqrt(2.0))
    min_cos = np.minimum(0.5, own_cos) - 0.02
    # Thickness: how far from its plane the sheet strays inside the patch's disk (its own sheet's
    # samples only: a fourth coordinate far apart per sheet keeps the others out of every ball)
    apart = 4.0 * (float(np.ptp(pts, axis=0).max()) + float(radii.max()) + 1.0)
    tree = cKDTree(np.column_stack([pts, apart * ps]))
    lists = tree.query_ball_point(np.column_stack([centers, apart * patch_sheet]), radii * 1.0000001)
    lens = np.fromiter((len(x) for x in lists), np.int64, k)
    idx = np.concatenate([np.asarray(x, np.int64) for x in lists]) if k else np.zeros(0, np.int64)
    own = np.repeat(np.arange(k), lens)
    rel = pts[idx] - centers[own]
    hh = np.abs(np.einsum("ij,ij->i", rel, normals[own]))
    agree = np.einsum("ij,ij->i", nrm[idx], normals[own]) >= min_cos[own]
    thick = np.zeros(k)
    np.maximum.at(thick, own[agree], hh[agree])
    placed = Placed(
        centers=centers,
        normals=normals,
        tangents=tangents,
        radii=radii,
        shapes=np.zeros(k, np.int8),
        thickness=1.05 * thick + 1e-3 * radii + 1e-6 * extent,
        min_cos=min_cos,
        triangle=tri[first],
    )
    return placed, k_per
