"""Adaptive patches: smaller patches where a solution varies, large ones where it does not.

Overlapping supports make refinement local (the paper names it as future work): a patch is
replaced by five (or four) children covering its support, and nothing else changes. No remeshing, no
constraint between neighbours: alpha is recomputed from memberships, so the partition of unity and
the reciprocity of the transport hold as on any atlas.

- A disk of radius r is covered by the four disks of radius r / sqrt(2) centred at
  (+-r/2, +-r/2) in its tangent frame (each covers one quadrant of its bounding square); a square
  of half side a by the four squares of half side a/2 tiling it. So every point the parent held is
  held by a child: coverage stays whole. A disk's centre lies on all four rims (where smooth beta
  is zero, and box beta only just reaches): a fifth child of radius r/2 sits there, also in squares
  with smooth beta. A box-beta square gets its four quadrants only, so squares generated without
  overlap stay a tiling: the classical limit, where the transport's reciprocity is tested, survives
  refinement.
- Children lie on the parent's sheet (same plane, normal, triangle and side); those whose support
  holds none of the sheet (a border square's quadrant off the surface) get no area and are dropped.
- A patch cut by a contact line was split into pieces with one anchor each (overlap/contacts.py): the
  pieces share one disk, so they are refined together, and the children are split again.
- Where: the indicator of a patch is the largest relative difference between its radiosity and an
  overlapping neighbour's, |L_i - L_j| / ((L_i + L_j) / 2 + floor), L the luminance of B and the
  floor a tenth of the area-weighted mean (so dark corners' noise does not count). Neighbouring
  patches that disagree mean the solution varies within a patch: a shadow edge, the fall-off under a
  lamp, a corner. Patches on evenly lit walls agree with every neighbour and stay large. Only planar
  disks and squares are refined (curved sheets and clutter balls are left as they are), down to a
  quarter of the radius they were generated with (two levels).
"""

from __future__ import annotations

import numpy as np

from ..atlas.patches import Atlas
from ..names import SHAPE_SQUARE
from ..overlap.contacts import split_at_contacts
from ..overlap.matrix import neighbour_pairs
from ..overlap.sight import planar_patches
from ..radiosity.first_shot import solve
from ..radiosity.problem import prepare
from ..settings import SolveSettings

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

FLOOR = 0.1  # of the mean luminance: differences below it in dark regions do not refine

MIN_SCALE = 0.25  # children never get smaller than this share of the atlas's median radius

THRESHOLD = 0.6  # refine patches whose indicator exceeds this...

BUDGET = 0.2  # ... at most this share of the patches per pass, the largest indicators first


def indicator(atlas: Atlas, radiosity: np.ndarray, C=None) -> np.ndarray:
    """(n,) largest relative difference between each patch's radiosity and an overlapping
    neighbour's (C's off-diagonal pattern, or without C the same-sheet pairs whose bounding balls
    meet).

    With C the patches are compared by their mean reconstructed radiosity over their supports,
    (C B)_h / A_h, not by their coefficients B_h: with smooth beta and large overlaps the
    coefficients oscillate around the field they reconstruct (C is ill-conditioned, ray noise
    rings), and comparing them would refine everywhere."""
    L = np.asarray(radiosity, np.float64).reshape(len(atlas), -1) @ LUMINANCE[: np.shape(radiosity)[-1]]
    if C is not None:
        C = C.tocsr()
        L = (C @ L) / np.maximum(np.asarray(C.sum(axis=1)).ravel(), 1e-300)
        pairs = C.tocoo()
        i, j = pairs.row, pairs.col
    else:
        i, j = neighbour_pairs(atlas)
    L = np.maximum(L, 0.0)
    w = np.asarray(atlas.effective_area, np.float64)
    mean = float(np.sum(w * L) / np.sum(w)) if np.sum(w) > 0 else float(np.mean(L))
    floor = FLOOR * max(mean, 1e-300)
    off = i != j
    i, j = i[off], j[off]
    d = np.abs(L[i] - L[j]) / (0.5 * (L[i] + L[j]) + floor)
    out = np.zeros(len(atlas))
    np.maximum.at(out, i, d)
    return out


def refinable(atlas: Atlas, index, smallest: float) -> np.ndarray:
    """(n,) bool: planar disks and squares that are larger than `smallest` (a radius)."""
    ok = np.zeros(len(atlas), bool)
    ok[planar_patches(atlas, index)] = True
    return ok & (atlas.radii > smallest * (1.0 + 1e-9))


def _groups(atlas: Atlas) -> np.ndarray:
    """(n,) group id: the pieces of one disk or square split at contact lines share it."""
    key = np.column_stack(
        [np.round(atlas.centers / np.maximum(atlas.radii, 1e-300)[:, None] * 1e6), atlas.sheet, atlas.shapes]
    )
    return np.unique(key, axis=0, return_inverse=True)[1].ravel()


def children(atlas: Atlas, parents: np.ndarray) -> Atlas:
    """The children of each patch in `parents` (indices of one patch per disk or square), with
    no anchor (found again) and no areas yet."""
    p = np.asarray(parents, np.int64)
    sign = np.array([[1, 1], [1, -1], [-1, 1], [-1, -1], [0, 0]], float)
    q = np.repeat(p, len(sign))
    s = np.tile(sign, (len(p), 1))
    # the middle child: for disks (their quadrant disks only just cover the centre, which lies on
    # all four rims) and with smooth beta (zero on those rims); a box-beta square's quadrants tile it
    middle = np.all(s == 0, axis=1)
    keep = ~middle | (atlas.shapes[q] != SHAPE_SQUARE) | (atlas.beta == "smooth")
    q, s = q[keep], s[keep]
    r = atlas.radii[q]
    square = atlas.shapes[q] == SHAPE_SQUARE
    step = 0.5 * r  # the quadrants' centres, in both shapes
    centers = atlas.centers[q] + step[:, None] * (
        s[:, :1] * atlas.tangents[q] + s[:, 1:] * atlas.bitangents[q]
    )
    radii = np.where(np.all(s == 0, axis=1), 0.5 * r, np.where(square, 0.5 * r, r / np.sqrt(2.0)))
    k = len(q)
    extent_part = atlas.thickness[q] - 1e-3 * r  # the scene-extent share placement added
    return Atlas(
        centers=centers,
        normals=atlas.normals[q],
        tangents=atlas.tangents[q],
        radii=radii,
        shapes=atlas.shapes[q],
        sheet=atlas.sheet[q],
        source_object=atlas.source_object[q],
        thickness=1e-3 * radii + np.maximum(extent_part, 0.0),
        min_cos=atlas.min_cos[q],
        support_area=np.zeros(k),
        effective_area=np.zeros(k),
        overlap_count=np.zeros(k, np.int64),
        random=np.random.default_rng([7, len(atlas), k]).random(k),
        beta=atlas.beta,
        triangle=None if atlas.triangle is None else atlas.triangle[q],
        side=None if atlas.side is None else atlas.side[q],
        anchor=np.full((k, 3), np.nan),
    )


def refine(
    atlas: Atlas,
    index,
    radiosity: np.ndarray,
    threshold: float = THRESHOLD,
    budget: float = BUDGET,
    smallest: float | None = None,
    C=None,
    only: np.ndarray | None = None,
) -> tuple[Atlas, int]:
    """The atlas with its most varying patches (indicator above `threshold`, at most `budget` x n of
    them, largest indicator first) each replaced by its children (five; four for box-beta squares); and
    how many were replaced.

    atlas as solved (sheets attached to `index`), C its overlap matrix if at hand (else its
    neighbour pairs are searched); smallest: the least radius a refined patch may have (default
    MIN_SCALE x the median radius); only: (n,) bool, the patches that may be refined (default all).
    The result has no areas yet: integrate C again (radiosity.problem.prepare with drop_unsupported, or
    generate.build.integrate) before solving; children without support are dropped there."""
    n = len(atlas)
    if smallest is None:
        smallest = MIN_SCALE * float(np.median(atlas.radii)) * np.sqrt(2.0)
    score = indicator(atlas, radiosity, C)
    group = _groups(atlas)
    ok = refinable(atlas, index, smallest) & (True if only is None else np.asarray(only, bool))
    # a disk's pieces refine together: the group's score is its pieces' largest
    g_score = np.zeros(group.max() + 1 if n else 0)
    np.maximum.at(g_score, group, np.where(ok, score, 0.0))
    g_ok = np.zeros_like(g_score, dtype=bool)
    g_ok[group[ok]] = True
    cand = np.flatnonzero(g_ok & (g_score > threshold))
    cand = cand[np.argsort(-g_score[cand], kind="stable")]
    cand = cand[np.cumsum(np.bincount(group)[cand]) <= budget * n]  # the budget counts patches
    if len(cand) == 0:
        return atlas, 0
    chosen = np.zeros(len(g_score), bool)
    chosen[cand] = True
    replaced = chosen[group]
    first = np.unique(group[replaced], return_index=True)[1]
    heads = np.flatnonzero(replaced)[first]
    kids = split_at_contacts(children(atlas, heads), index)[0]
    kept = atlas.select(~replaced)
    out = Atlas.concatenate([kept, kids])
    return out, int(replaced.sum())


def solve_adaptive(
    surfaces,
    atlas: Atlas,
    lamps=(),
    settings=None,
    passes: int = 1,
    threshold: float = THRESHOLD,
    budget: float = BUDGET,
    emission_scale: float = 1.0,
    sky=None,
    backend: str = "auto",
):
    """Solve, refine where the solution varies, solve again, `passes` times: (problem, state,
    patches replaced per pass). Each pass integrates C and the transport of the refined atlas anew
    (the form factors of untouched patches are not kept: alpha changes wherever a child overlaps
    them). The smallest radius is set by the atlas as given (MIN_SCALE of its median radius)."""

    settings = settings if settings is not None else SolveSettings()
    problem = prepare(surfaces, atlas, settings, backend=backend)
    state = solve(problem, lamps, settings, emission_scale, sky=sky)
    smallest = MIN_SCALE * float(np.median(problem.atlas.radii)) * np.sqrt(2.0)
    replaced = []
    for _ in range(passes):
        finer, k = refine(
            problem.atlas, problem.index, state.radiosity, threshold, budget, smallest, problem.C
        )
        replaced.append(k)
        if k == 0:
            break
        problem = prepare(surfaces, finer, settings, backend=backend, drop_unsupported=True)
        state = solve(problem, lamps, settings, emission_scale, sky=sky)
    return problem, state, replaced
