"""The near field of a light tree's cut (light/tree.py): a point near a cut node walks the node's
subtree, nodes taken as one point where far enough, the nearest triangles by their exact form
factor (near_picked)."""

from __future__ import annotations

import numpy as np

from ..geometry import ranges_flat
from .emitters import EmitterSamples, plane_heights, polygon_irradiance
from .lamps import shadow_origin
from .tree import BELOW, CUT, NODE_FLOATS, NODE_INTS, LightTree, second_order

NEAR_EXACT = 4.0  # near_picked takes a node of the light tree as one point this x its radius away

NEAR_POINTS = 1 << 13  # points whose near emitters near_picked finds at once (memory: their frontier)
# (point, node) pairs a block's frontier (or its found nodes) holds at most: a block whose walk would
# hold more is walked in halves (a point 2 cm from a finely split emitter walks thousands of nodes;
# 8 192 such points at once asked 3.5 GB for one level's rows)
FRONTIER_MOST = 1 << 20


def near_picked(H, rs, P, N, src: EmitterSamples, tree: LightTree, g, rays, eps: float) -> int:
    """The near field of a light tree's cut (`src`: its samples; g (m, k) their geometric terms at
    the points, as emitter_irradiance added them to H): a point within reach of a cut node's
    triangles (CUT_REACH x the node's radius past them) gets that node's light from its subtree in
    place of its sample's. Walking the tree, a node farther than NEAR_EXACT x its radius, wholly
    above the point's horizon and flat enough that the point sees all its faces from one side,
    gives its light as one point (its power vector, corrected to second order for its extent:
    second_order); a node wholly under the horizon gives none; a single triangle nearer than that,
    its exact unoccluded light (Lambert's contour); each x whether the point sees the node's central
    triangle's centroid (one shadow ray). Points go in blocks of NEAR_POINTS. Returns the rays cast."""
    cast = 0
    blocks = [np.arange(b0, min(len(P), b0 + NEAR_POINTS)) for b0 in range(0, len(P), NEAR_POINTS)]
    while blocks:
        block = blocks.pop(0)
        n = _near_block(H, rs, P, N, src, tree, g, rays, eps, block)
        if n is None:  # its frontier outgrew FRONTIER_MOST: its halves, in order
            half = (len(block) + 1) // 2
            blocks[:0] = [block[:half], block[half:]]
        else:
            cast += n
    return cast


def _near_block(H, rs, P, N, src: EmitterSamples, tree: LightTree, g, rays, eps, block) -> int | None:
    """near_picked for the points `block`: the tree walked a level at a time for all of them at once
    (a frontier of (point, node) pairs), then one batch of shadow rays; None, with H untouched, where
    the frontier of a block of several points would outgrow FRONTIER_MOST. A point's light does not
    depend on the block it is walked in."""
    i, j = block, np.zeros(len(block), np.int64)
    found = []  # per level: points, irradiance (., 3), central triangle, samples' range
    held = 0  # pairs in found
    for (F, I, power), state, reach in zip(tree.levels, tree.state, tree.reach_columns, strict=True):  # noqa: E741
        ints = np.take(I, j, axis=0)
        live = ints[:, NODE_INTS["count"]] > 0
        if not live.all():
            i, j, ints = i[live], j[live], ints[live]
        if len(i) == 0:
            break
        if len(i) > FRONTIER_MOST and len(block) > 1:
            return None
        r, Pi = np.take(reach, j, axis=0), np.take(P, i, axis=0)
        v = r[:, NODE_FLOATS["centroid"]] - Pi
        d = np.sqrt(np.einsum("ij,ij->i", v, v))
        spread, radius = r[:, NODE_FLOATS["spread"]], r[:, NODE_FLOATS["radius"]]
        near = d + spread < r[:, NODE_FLOATS["reach_min"]]
        far = d - spread >= r[:, NODE_FLOATS["reach_max"]]
        # a cut node within reach takes its sample's light back and has its whole subtree walked:
        # under it every node is near (its light comes from here, not from a sample)
        st = state[j]
        cut_near = (st == CUT) & ~far
        near |= cut_near | (st == BELOW)
        far &= st != BELOW
        # a pair out of reach is done with (its light came from the samples): the rest of a node's
        # row is gathered for the others only
        stay = np.flatnonzero(~far)
        if len(stay) < len(i):
            i, j, ints, Pi, v, d = i[stay], j[stay], ints[stay], Pi[stay], v[stay], d[stay]
            spread, radius, near, far, st, cut_near = (
                x[stay] for x in (spread, radius, near, far, st, cut_near)
            )
        f, Ni = np.take(F, j, axis=0), np.take(N, i, axis=0)
        single = ints[:, NODE_INTS["count"]] == 1
        rep = ints[:, NODE_INTS["rep"]]
        height = np.einsum("ij,ij->i", v, Ni)
        # wholly above the point's horizon, or wholly under it (no light, and its samples gave none):
        # by the node's bounding ball or its box (a flat node parallel to the point's plane, a panel
        # under a ceiling, has a thin box); a single triangle's by its corners
        box = np.einsum("ij,ij->i", f[:, NODE_FLOATS["box_mid"]] - Pi, Ni)
        half = np.einsum("ij,ij->i", f[:, NODE_FLOATS["box_half"]], np.abs(Ni))
        above = (height > radius) | (box > half)
        under = (height < -radius) | (box < -half)
        one = np.flatnonzero(single & near)
        h = plane_heights(tree.corners[rep[one]] - Pi[one][:, None], Ni[one])
        above[one], under[one] = h.min(axis=1) > 0, h.max(axis=1) <= 0
        far |= under
        near &= ~under
        omega = v / np.maximum(d, 1e-300)[:, None]
        sees_one_side = (
            np.abs(np.einsum("ij,ij->i", omega, f[:, NODE_FLOATS["axis"]])) >= f[:, NODE_FLOATS["one_side"]]
        )
        point = near & above & sees_one_side & (d > NEAR_EXACT * radius)
        contour = near & single & ~point
        E = np.zeros((len(i), 3))
        p = np.flatnonzero(point)
        cos_r = height[p] / np.maximum(d[p], 1e-300)
        E[p] = cos_r[:, None] * np.abs(np.einsum("kcj,kj->kc", power[j[p]], omega[p])) / d[p, None] ** 2
        if len(p):
            axis = f[p, NODE_FLOATS["axis"]]
            axis *= np.where(np.einsum("ij,ij->i", axis, v[p]) < 0, -1.0, 1.0)[:, None]
            with np.errstate(divide="ignore", invalid="ignore"):
                fix = second_order(f[p, NODE_FLOATS["moment"]], v[p], Ni[p], axis)
            E[p] *= np.clip(np.nan_to_num(1.0 + fix, nan=1.0), 0.0, 2.0)[:, None]
        q = np.flatnonzero(contour)
        E[q] = polygon_irradiance(Pi[q], Ni[q], tree.corners[rep[q]])[:, None] * tree.radiance[rep[q]]
        done = point | contour
        # a cut node walked further gives back its sample's light here (no light of its own)
        back = np.flatnonzero(cut_near & ~done & ~far)
        done = np.flatnonzero(done)
        found.append(
            (i[done], E[done], rep[done], ints[done, NODE_INTS["s_lo"]], ints[done, NODE_INTS["s_hi"]])
        )
        if len(back):
            found.append((i[back], np.zeros((len(back), 3)), rep[back], ints[back, 2], ints[back, 3]))
        held += len(done) + len(back)
        if held > FRONTIER_MOST and len(block) > 1:
            return None
        down = ~far
        down[done] = False
        i, j = np.repeat(i[down], 2), (2 * j[down, None] + [0, 1]).ravel()
    if not found:
        return 0
    i, E, rep, s_lo, s_hi = (np.concatenate(x) for x in zip(*found, strict=True))
    if len(i) == 0:
        return 0
    target = tree.centroid_t[rep]
    v = target - P[i]
    omega = v / np.maximum(np.linalg.norm(v, axis=1), 1e-300)[:, None]
    ask = (np.einsum("ij,ij->i", omega, N[i]) > 0) & (E.sum(axis=1) > 0)
    seen = np.ones(len(i))  # a centroid under the point's horizon: the clipped part is seen
    cast = int(ask.sum())
    if cast:
        normal = tree.normal_t[rep[ask]]
        facing = np.einsum("ij,ij->i", omega[ask], normal)
        origin = shadow_origin(P[i][ask], N[i][ask], omega[ask], eps)
        seg = target[ask] - (eps * np.sign(facing))[:, None] * normal - origin
        length = np.linalg.norm(seg, axis=1)
        seen[ask] = rays.transmittance(origin, seg / np.maximum(length, 1e-300)[:, None], length * (1 - 1e-6))
    np.add.at(H, rs[i], E * seen[:, None])
    # less what the samples picked on those triangles gave (a node's samples are one run)
    many = s_hi - s_lo
    if many.sum():
        row = np.repeat(i, many)
        sample = tree.sample_order[ranges_flat(s_lo, many)]
        np.add.at(H, rs[row], -g[row, sample][:, None] * src.radiance[sample])
    return cast
