"""Quadrature of patch supports: points on the surface with area weights, for C and every per-patch mean.

C[h, i] = c_ih = integral over D_h of alpha_i; its row sums are the support areas A_h and its
diagonal the effective areas c_hh. Integration uses a polar rule on each patch's disk or square
(polar_rule: Gauss points on the pieces of each ray between neighbours' rims), with every rule
point moved onto the patch's own sheet along the patch normal (rule points that land nowhere
on the sheet are outside the support and get no weight).
"""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from ..atlas.balls import BallRule, ball_quadrature, ball_rule
from ..names import SHAPE_BALL
from .cuts import support_cuts, surface_rule
from .rule import Quadrature
from .sight import Contacts

QUADRATURE_CHUNK = 8192  # patches per patch_quadrature pass


def patch_quadrature(
    atlas,
    index,
    ids: np.ndarray,
    q: int,
    nb: np.ndarray | None = None,
    rings: int | None = None,
    *,
    visibility: Contacts | None,
    balls: BallRule | None = None,
) -> Quadrature:
    """Quadrature of the supports D_h for patches `ids`, on the surface, with area weights.

    Rule points are moved onto the patch's own sheet along its normal; points that land on
    another sheet, or nowhere, are outside the support and get weight 0. Where that happens
    (the sheet's border cuts the patch) the rule rays it cuts are split where they cross it
    (support_cuts), so the cut is resolved closely. Ball patches (clutter.py) are integrated
    with samples of the pieces they hold.
    visibility: the patches' contacts (overlap.contacts.contacts()); points a cut patch cannot see
    along its sheet are then outside it. None: no such test (the coarse rule that finds them).
    balls: the atlas's clutter samples (atlas.balls.ball_rule), made here when ids hold a ball patch
    and none is given: callers that integrate in many calls make it once and pass it.
    """
    if nb is None:
        nb = np.zeros((len(ids), 0), np.int64)
    if balls is None and np.any(atlas.shapes[ids] == SHAPE_BALL):
        balls = ball_rule(atlas, index)
    if len(ids) > QUADRATURE_CHUNK:
        # a patch's rule depends on itself and its neighbours only: in chunks, the temporaries of
        # every patch's rays and rule points are never held at once (100 k patches: 2.8 GB at once)
        parts = []
        for s in range(0, len(ids), QUADRATURE_CHUNK):
            sl = slice(s, s + QUADRATURE_CHUNK)
            part = patch_quadrature(
                atlas, index, ids[sl], q, nb[sl], rings, visibility=visibility, balls=balls
            )
            parts.append(replace(part, owner=part.owner + s))
        return Quadrature(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Quadrature)))
    ball = atlas.shapes[ids] == SHAPE_BALL
    if ball.any():
        return _with_balls(atlas, index, ids, q, nb, rings, ball, visibility, balls)
    if rings is None:
        # coarse rings first. On each rule ray where a point fell off the support (a border, a
        # crease, a contact cuts the patch there), every change between on and off along the ray
        # is found (support_cuts) and the ray split there, so each piece is on or off the support
        # as a whole. Splitting the cut rays into 2q rings instead took 2 300 rule points per
        # patch on the production room's small pieces at 100 k patches (most of its Generate:
        # each point is cast onto the surface and paired with every neighbour)
        coarse, ray, flat = surface_rule(atlas, index, ids, q, nb, max(q // 4, 1), visibility)
        off = coarse.triangle < 0
        if not off.any():
            return coarse
        cut_rays = np.zeros((len(ids), 4 * q), bool)
        cut_rays[coarse.owner[off], ray[off]] = True
        # rays with a point on the sheet but off the support: a contact or a closed object hides it
        hidden = np.zeros_like(cut_rays)
        hidden[coarse.owner[off & flat], ray[off & flat]] = True
        where = np.flatnonzero(cut_rays.any(axis=1))
        on = cut_rays[coarse.owner, ray]
        cuts = support_cuts(atlas, index, ids[where], q, cut_rays[where], hidden[where], visibility)
        fine = surface_rule(
            atlas, index, ids[where], q, nb[where], max(q // 4, 1), visibility, cut_rays[where], cuts
        )[0]
        keep = ~on
        return Quadrature(
            owner=np.concatenate([coarse.owner[keep], where[fine.owner]]),
            points=np.concatenate([coarse.points[keep], fine.points]),
            normals=np.concatenate([coarse.normals[keep], fine.normals]),
            weights=np.concatenate([coarse.weights[keep], fine.weights]),
            triangle=np.concatenate([coarse.triangle[keep], fine.triangle]),
            cand=np.concatenate([coarse.cand[keep], fine.cand]),
        )
    return surface_rule(atlas, index, ids, q, nb, rings, visibility)[0]


def _with_balls(atlas, index, ids, q, nb, rings, ball, visibility, balls: BallRule) -> Quadrature:
    """patch_quadrature of ids when some are ball patches: their rule from clutter samples (at
    most 8 q^2 points each), the others' as usual, in one Quadrature."""

    parts = []
    where = np.flatnonzero(ball)
    owner, pts, nrm, w, tri = ball_quadrature(atlas, ids[where], 8 * q * q, balls)
    cand = nb[where][owner] >= 0  # any same-sheet neighbour may hold a sample
    parts.append(Quadrature(where[owner], pts, nrm, w, tri, cand))
    rest = np.flatnonzero(~ball)
    if len(rest):
        other = patch_quadrature(
            atlas, index, ids[rest], q, nb[rest], rings, visibility=visibility, balls=balls
        )
        parts.append(replace(other, owner=rest[other.owner]))
    return Quadrature(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Quadrature)))
