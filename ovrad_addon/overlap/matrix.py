"""The overlap matrix C (c_ih = integral of alpha_i over D_h) and the support areas A_h, row by
row from each patch's quadrature; rows of patches placed alike are integrated once and copied."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.spatial import cKDTree

from ..atlas.balls import BallRule, ball_rule
from ..atlas.support import alpha_from_pairs, pair_beta
from ..geometry import unique_rows
from ..names import SHAPE_DISK, SHAPE_SQUARE
from ..parallel import WORKERS, threaded
from .contacts import seen_members
from .cuts import CUT_SAMPLES
from .quadrature import patch_quadrature
from .sight import Contacts, planar_patches


def neighbour_pairs(atlas) -> tuple[np.ndarray, np.ndarray]:
    """All (h, i) on the same sheet whose bounding balls intersect, h == i included.

    Searched per sheet (a fourth coordinate keeps sheets apart) with each patch's own reach (its
    bounding radius plus the largest on its sheet): a search radius of the largest patch anywhere
    would pair every small patch of a cluster of small pieces with thousands of others.
    """
    br = atlas.bounding_radii
    n = len(atlas)
    sheet = np.asarray(atlas.sheet, np.int64)
    _, local_sheet = np.unique(sheet, return_inverse=True)
    largest = np.zeros(local_sheet.max() + 1 if n else 0)
    np.maximum.at(largest, local_sheet, br)
    gap = 4.0 * float(br.max()) + 1.0
    pts = np.column_stack([atlas.centers, local_sheet * gap])
    found = cKDTree(pts).query_ball_point(pts, r=br + largest[local_sheet], return_sorted=False)
    counts = np.fromiter((len(f) for f in found), np.int64, n)
    a = np.repeat(np.arange(n), counts)
    b = np.fromiter((j for f in found for j in f), np.int64, int(counts.sum()))
    d = np.linalg.norm(atlas.centers[a] - atlas.centers[b], axis=1)
    keep = (a < b) & (d <= br[a] + br[b]) & (sheet[a] == sheet[b])
    a, b = a[keep], b[keep]
    h = np.concatenate([a, b, np.arange(n)])
    i = np.concatenate([b, a, np.arange(n)])
    order = np.lexsort((i, h))
    return h[order], i[order]


@dataclass(frozen=True)
class RowCopies:
    """Rows of C taken from another patch's: member (k,) patches, rep (k,) the patch whose row each
    copies, and their neighbours in matching order, nb_member and nb_rep (k, c) (one block per
    neighbour count c)."""

    member: np.ndarray
    rep: np.ndarray
    nb_member: np.ndarray
    nb_rep: np.ndarray


KEY_SCALE = 1e6  # configurations equal to 1e-6 of the patch radius are one


def repeated_rows(
    atlas, index, con: Contacts, ph: np.ndarray, pi: np.ndarray, start: np.ndarray
) -> list[RowCopies]:
    """Patches whose row of C is another's, found by their neighbourhoods.

    A row C[h, .] = the integrals over D_h of the alpha_i depends on nothing but the disks and
    squares around h when h's support is plain: a disk on a planar sheet, whole (every point of its
    coarse rule on the sheet: no border, footprint or hole in it, overlap.sight.Contacts.whole), and no
    contact line cutting it or any patch overlapping it (their memberships are then geometric).
    Two such patches whose neighbours sit at the same offsets in their planes (1e-6 of the radius),
    with the same radii, shapes and square orientations, have the same row up to the rotation of
    the rule. A sheet's patches lie on a regular grid, so most interior patches of large flat faces
    repeat a few configurations: the Cornell box at 25 000 patches has 15 300 plain patches in 1 012
    configurations. Each configuration is integrated once per sheet, on the member with the
    smallest Atlas.random: the choice depends on neither the patches' order nor other sheets, so a
    row stays a function of its own sheet's patches (overlap/kept.py relies on it).
    """
    n = len(atlas)
    plain = np.zeros(n, bool)
    plain[planar_patches(atlas, index)] = True
    uncut = plain & ~con.cut & ~con.covered  # a covered patch's disk may reach past its cover
    ok = uncut & con.whole & (atlas.shapes == SHAPE_DISK)
    other = ph != pi
    ok[ph[other & ~uncut[pi]]] = False  # a neighbour cut by a contact line
    deg = np.diff(start)
    rel = atlas.centers[pi] - atlas.centers[ph]
    r = atlas.radii
    t, b = atlas.tangents, atlas.bitangents
    kx = np.round(np.einsum("ij,ij->i", rel, t[ph]) / r[ph] * KEY_SCALE).astype(np.int64)
    ky = np.round(np.einsum("ij,ij->i", rel, b[ph]) / r[ph] * KEY_SCALE).astype(np.int64)
    kr = np.round(r[pi] / r[ph] * KEY_SCALE).astype(np.int64)
    # a square neighbour's turn in h's plane (a quarter turn is the same square)
    turn = np.arctan2(np.einsum("ij,ij->i", t[pi], b[ph]), np.einsum("ij,ij->i", t[pi], t[ph]))
    square = atlas.shapes[pi] == SHAPE_SQUARE
    ka = np.where(square, np.round(np.mod(turn, 0.5 * np.pi) * KEY_SCALE), -1).astype(np.int64)
    size = np.round(r / max(float(r.max()), 1e-300) * 1e9).astype(np.int64)
    out = []
    for c in np.unique(deg[ok]):
        rows = np.flatnonzero(ok & (deg == c))
        slot = start[rows][:, None] + np.arange(c)[None, :]
        keys = [kx[slot], ky[slot], kr[slot], ka[slot]]
        order = np.lexsort(keys[::-1], axis=1)
        keys = [np.take_along_axis(k, order, axis=1) for k in keys]
        nb = np.take_along_axis(pi[slot], order, axis=1)
        sheet = np.asarray(atlas.sheet, np.int64)[rows]  # a row is copied within its own sheet only
        _, group = unique_rows(np.column_stack([sheet, size[rows], *keys]), return_inverse=True)
        group = group.ravel()
        first = np.lexsort((rows, atlas.random[rows], group))  # by group, smallest random first
        lead = np.empty(group.max() + 1, np.int64)
        lead[group[first[::-1]]] = first[::-1]
        rep = lead[group]
        copy = rep != np.arange(len(rows))
        out.append(RowCopies(rows[copy], rows[rep[copy]], nb[copy], nb[rep[copy]]))
    return out


def overlap_matrix(
    atlas,
    index,
    q: int,
    contacts: Contacts,
    progress: Callable[[float], None] | None = None,
    chunk_points: int = 1_000_000,
    workers: int = WORKERS,
    rows: np.ndarray | None = None,
    reuse: bool = True,
    balls: BallRule | None = None,
) -> tuple[csr_matrix, np.ndarray]:
    """C (n x n sparse, C[h, i] = c_ih) and the support areas A_h (n,).

    Row h is integrated on D_h with a rule that depends on patch h and the patches of its sheet
    around it only (never on the other patches' order, or on patches elsewhere), so the rows
    of one atlas object's patches are the same whatever atlases are integrated with it.
    rows: integrate these rows only (the others are empty, their support areas 0).
    Patches go in chunks of about chunk_points rule-point pairs, on `workers` threads
    (parallel.py): 2.0 s instead of 4.1 s for 6 400 patches on 2 cores.
    reuse: a row that repeats another's configuration is copied from it (repeated_rows).
    contacts: the atlas's (overlap.contacts.contacts()); balls: its clutter samples
    (atlas.balls.ball_rule; made here when None or not the atlas's)."""
    n = len(atlas)
    rows = np.arange(n) if rows is None else np.asarray(rows, np.int64)
    if len(rows) == 0:
        return csr_matrix((n, n)), np.zeros(n)
    ph, pi = neighbour_pairs(atlas)
    start = np.searchsorted(ph, np.arange(n + 1))
    deg = np.diff(start)
    wanted = rows
    copies = []
    if reuse:
        asked = np.zeros(n, bool)
        asked[wanted] = True
        for block in repeated_rows(atlas, index, contacts, ph, pi, start):
            keep = asked[block.member]
            if np.any(keep):
                copies.append(
                    RowCopies(block.member[keep], block.rep[keep], block.nb_member[keep], block.nb_rep[keep])
                )
        if copies:
            copied = np.concatenate([c.member for c in copies])
            todo = np.ones(n, bool)
            todo[copied] = False
            rows = np.union1d(wanted[todo[wanted]], np.concatenate([c.rep for c in copies]))
    # rule points per patch grow with its neighbours (rim crossings), and each point is paired
    # with every neighbour of its chunk's widest patch: rows go by degree, in chunks whose pairs
    # stay within budget. (Sized by the atlas's widest patch, the production room's chunks at
    # 100 k patches would hold 7 patches each: numpy's per-call cost would outweigh the work. By
    # degree, counting rule points only, Generate's peak there is 3.6 GB; with support_cuts'
    # samples counted too, 0.57 GB in the same 91 s.)
    rows = rows[np.argsort(deg[rows], kind="stable")]
    # a patch's pairs: its rule points (and, if cut, up to 4q (CUT_SAMPLES q + 2) support_cuts samples)
    # times its neighbours
    cost = (8 * q * (deg[rows] + q // 4 + 1) + 4 * q * (CUT_SAMPLES * q + 2)) * np.maximum(deg[rows], 2)
    starts = [0]
    while starts[-1] < len(rows):
        a = starts[-1]
        # the patches after a whose cost times the chunk's last (widest) one stays within budget
        span = min(len(rows) - a, chunk_points // int(cost[a]) + 1)
        fit = np.searchsorted(np.arange(1, span + 1) * cost[a : a + span], chunk_points, side="right")
        starts.append(a + max(1, int(fit)))
    bounds = list(zip(starts[:-1], starts[1:], strict=True))
    balls = ball_rule(atlas, index, balls)

    def chunk(k: int):
        ids = rows[bounds[k][0] : bounds[k][1]]
        lo, hi = start[ids], start[ids + 1]
        m = int((hi - lo).max())
        slot = np.arange(m)[None, :]
        nb = np.where(slot < (hi - lo)[:, None], pi[np.minimum(lo[:, None] + slot, len(pi) - 1)], -1)
        nb = np.where(nb == ids[:, None], -1, nb)
        quad = patch_quadrature(atlas, index, ids, q, nb, visibility=contacts, balls=balls)
        area = np.bincount(quad.owner, weights=quad.weights, minlength=len(ids))
        # Pair every rule point with its own patch and the neighbours that may contain it.
        pt, slot = np.nonzero(quad.cand)
        prow = np.concatenate([np.arange(len(quad.owner)), pt])
        pcol = np.concatenate([ids[quad.owner], nb[quad.owner[pt], slot]])
        sheets = np.where(quad.triangle >= 0, atlas.sheet[ids[quad.owner]], -1)
        at = np.take(quad.points, prow, axis=0)
        member, b = pair_beta(atlas, pcol, at, np.take(quad.normals, prow, axis=0), sheets[prow], atlas.beta)
        member = seen_members(atlas, index, contacts, prow, pcol, at, member)
        alpha = alpha_from_pairs(prow, pcol, member, b, (len(quad.owner), n)).tocoo()
        # Sum per (h, i) within the chunk: what is kept is then the size of C, not of the rule.
        part = (
            coo_matrix(
                (alpha.data * quad.weights[alpha.row], (quad.owner[alpha.row], alpha.col)),
                shape=(len(ids), n),
            )
            .tocsr()
            .tocoo()
        )
        return ids, area, ids[part.row], part.col, part.data

    r_all, c_all, v_all = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros(0)]
    support = np.zeros(n)
    done = 0
    for ids, area, r, c, v in threaded(chunk, len(bounds), workers):
        support[ids] = area
        r_all.append(r)
        c_all.append(c)
        v_all.append(v)
        done += len(ids)
        if progress is not None:
            progress(min(1.0, done / max(len(rows), 1)))
    C = coo_matrix((np.concatenate(v_all), (np.concatenate(r_all), np.concatenate(c_all))), shape=(n, n))
    C = C.tocsr()
    if copies:
        C, support = _with_copies(C, support, copies, wanted)
    C.eliminate_zeros()
    return C, support


def _with_copies(C: csr_matrix, support: np.ndarray, copies: list[RowCopies], wanted: np.ndarray):
    """C and support with the copied rows filled from their representatives', and only the
    `wanted` rows kept (a representative integrated for others only is dropped)."""
    n = C.shape[0]
    support = support.copy()
    keep = np.zeros(n, bool)
    keep[wanted] = True
    base = C.tocoo()
    on = keep[base.row]
    r_all, c_all, v_all = [base.row[on]], [base.col[on]], [base.data[on]]
    for block in copies:
        k, c = block.nb_member.shape
        vals = np.asarray(C[np.repeat(block.rep, c), block.nb_rep.ravel()]).ravel()
        r_all.append(np.repeat(block.member, c))
        c_all.append(block.nb_member.ravel())
        v_all.append(vals)
        support[block.member] = support[block.rep]
    support[~keep] = 0.0
    out = coo_matrix((np.concatenate(v_all), (np.concatenate(r_all), np.concatenate(c_all))), shape=(n, n))
    return out.tocsr(), support
