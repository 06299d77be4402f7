"""Contacts: a patch's support stops where other geometry stands on its sheet.

A floor that runs under a partition, a wall that passes through a floor, a shelf on a wall: the
other geometry meets the sheet along a contact line, and light on one side of that line has
nothing to do with light on the other (or under it). A patch whose disk crosses such a line
averages both sides, darkening the lit side and lighting the hidden one: on two rooms joined by a
doorway through an open 10 cm partition (benchmarks/real_scenes.py), the second room came out
2.8 % darker than a converged Cycles bake; +0.5 % with the supports cut.

So on planar sheets a point M belongs to D_h only if it can be seen from the patch's anchor (a
point of its support) along the sheet: the segment between the two, lifted a hair off the sheet
(LIFT of the radius), hits nothing. At Generate a patch that a contact line cuts is split into one
patch per part it can see (split_at_contacts: same disk or square, one anchor in each part), so the
parts on both sides of the line stay covered; the anchors are stored with the atlas. Only cut
patches pay for rays. A point no patch sees (a sliver) keeps the plain membership, so alpha
sums to one everywhere. Closed objects' footprints are removed before the contacts are found
(atlas.index.buried); curved sheets and clutter balls are left as they are.

The outline of a cover is a contact line too (covered()): geometry hung closer over the sheet than
half a patch radius (a lamp panel 1 cm under a ceiling, a picture off a wall, a board low over a
floor) parts the sheet under it from the sheet beside it. On the production room (an emissive
quad 1 cm under its ceiling, its back lighting the ceiling over it) ceiling patches straddling
the quad's outline carried that light into the room: 14 % too bright against Cycles at 2 000
patches, 7 % with covers.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .quadrature import patch_quadrature
from .sight import Contacts, blocked, covered, lift_of, planar_patches, visible

MAX_PIECES = 3  # a patch splits into at most this many parts at contact lines

LEAST_PIECE = 0.05  # ... each holding at least this share of its area

CHUNK = 8192  # patches whose rule points contacts() holds at once

COARSE_Q, COARSE_RINGS = 4, 2  # the coarse rule that finds contacts (and locates a patch's sheet)


def coarse_rule(atlas, index, ids):
    """The on-sheet points of a coarse rule of patches ids, without the contact rule: (owner position
    in ids, points, weights, triangles), and whether each patch had all its rule points on (len(ids),)."""

    quad = patch_quadrature(atlas, index, ids, COARSE_Q, rings=COARSE_RINGS, visibility=None)
    on = np.flatnonzero(quad.weights > 0)
    whole = np.bincount(quad.owner, weights=quad.weights <= 0, minlength=len(ids)) == 0
    return quad.owner[on], quad.points[on], quad.weights[on], quad.triangle[on], whole


def _nearest(atlas, ids, owner, points, among) -> np.ndarray:
    """Per patch position in ids with a point among `among` (bool per point): the index of its point
    nearest the patch centre (-1 where none). Rule points come in rings at equal distances: the
    distance is rounded and ties go to the rule's own order, so the choice does not depend on the
    scene's scale or position."""
    out = np.full(len(ids), -1, np.int64)
    cand = np.flatnonzero(among)
    if len(cand) == 0:
        return out
    g = ids[owner[cand]]
    d = np.linalg.norm(points[cand] - atlas.centers[g], axis=1) / atlas.radii[g]
    order = cand[np.lexsort((np.round(d * 1e6), owner[cand]))]
    o = owner[order]
    first = np.r_[True, o[1:] != o[:-1]]
    out[o[first]] = order[first]
    return out


def contacts(atlas, index) -> Contacts:
    """The anchors and cut flags of an atlas on an index: the stored anchor, else the on-sheet rule
    point nearest the centre; cut where a rule point is hidden from it. Found once where the work is
    prepared (radiosity.problem.prepare, generate.build.integrate) and passed on as a value: 100 k
    patches take about 5 s."""
    n = len(atlas)
    lift = lift_of(atlas, index)
    anchor = atlas.centers.copy() if atlas.anchor is None else np.asarray(atlas.anchor, np.float64).copy()
    cut = np.zeros(n, bool)
    whole = np.zeros(n, bool)
    under = np.zeros(n, bool)
    every = planar_patches(atlas, index)
    for start in range(0, len(every), CHUNK):  # a patch's anchor and cut are its own: in chunks
        ids = every[start : start + CHUNK]
        owner, points, _, _, whole[ids] = coarse_rule(atlas, index, ids)
        todo = ~np.all(np.isfinite(anchor[ids]), axis=1)
        near = _nearest(atlas, ids, owner, points, todo[owner])
        got = near >= 0
        anchor[ids[got]] = points[near[got]]
        anchor[ids] = np.where(np.isfinite(anchor[ids]), anchor[ids], atlas.centers[ids])
        under[ids] = covered(atlas, index, ids, anchor[ids], lift)
        points_under = covered(atlas, index, ids[owner], points, lift)
        seen = _sees(atlas, index, ids, owner, anchor[ids], under[ids], points, points_under, lift)
        cut[ids] = np.bincount(owner, weights=~seen, minlength=len(ids)) > 0
    anchor = np.where(np.isfinite(anchor), anchor, atlas.centers)
    return Contacts(anchor, lift, cut, whole, under)


# Bits of contact_flags(): what a file keeps of a patch's contacts beside its kept C (overlap/kept.py)
CUT, WHOLE, COVERED = 1, 2, 4


def contact_flags(c: Contacts) -> np.ndarray:
    """(n,) int32 per patch: CUT | WHOLE | COVERED, the bits of its cut, whole and covered flags."""
    return (c.cut * CUT | c.whole * WHOLE | c.covered * COVERED).astype(np.int32)


def seed_contacts(atlas, index, flags: np.ndarray, known: np.ndarray) -> Contacts | None:
    """The contacts of `atlas` on `index` that `flags` (n,) (contact_flags) give for the patches
    `known` (n,) bool, the other patches' found with contacts() on them alone (a patch's contacts are
    its own); the anchors are the atlas's. A solve whose kept C fits (overlap.kept.fitting) takes the
    contacts that C was integrated with instead of finding them again (100 k patches: about 5 s).
    None where the atlas has no anchors or a known one is not finite."""
    if atlas.anchor is None or not known.any():
        return None
    anchor = np.asarray(atlas.anchor, np.float64)
    if not np.all(np.isfinite(anchor[known])):
        return None
    flags = np.asarray(flags, np.int64)
    cut, whole, covered = ((flags & bit) != 0 for bit in (CUT, WHOLE, COVERED))
    anchor = anchor.copy()
    rest = np.flatnonzero(~known)
    if len(rest):
        found = contacts(atlas.select(rest), index)
        anchor[rest], cut[rest] = found.anchor, found.cut
        whole[rest], covered[rest] = found.whole, found.covered
    return Contacts(anchor, lift_of(atlas, index), cut, whole, covered)


def split_at_contacts(
    atlas, index, pieces: int = MAX_PIECES, least: float = LEAST_PIECE
) -> tuple[object, Contacts]:
    """The atlas with each patch a contact line cuts split into one patch per part it can see.

    A patch's coarse rule points are taken in turn from the centre outwards: the nearest one not
    yet seen becomes an anchor, and what it sees is its part; at most `pieces` parts. Each part
    holding at least `least` of the patch's area becomes a patch of its own (same disk or square,
    that anchor, the triangle under the anchor), kept next to the others; a patch with no part
    that large keeps its largest. Every patch gets its anchor stored (Atlas.anchor), so Solve
    sees the same supports. Anchors are rounded to float32 as a file keeps them, and the split
    atlas's contacts (what contacts() would find for it: the same rule points, seen from the same
    anchors) come with it, (split atlas, its Contacts), so integrating its C does not find them again.
    """
    n = len(atlas)
    ids = planar_patches(atlas, index)
    other = np.setdiff1d(np.arange(n), ids)
    none = np.zeros(len(other), bool)
    rows, anchors, tris = [other], [atlas.centers[other]], [np.full(len(other), -1, np.int64)]
    cuts, wholes, covers = [none], [none], [none]  # contacts() leaves patches off planar sheets alone
    lift = lift_of(atlas, index)
    for start in range(0, len(ids), CHUNK):  # a patch's parts are its own: in chunks
        for r, a, t, c, w, u in _parts(atlas, index, ids[start : start + CHUNK], lift, pieces, least):
            rows.append(r)
            anchors.append(a)
            tris.append(t)
            cuts.append(c)
            wholes.append(w)
            covers.append(u)
    row = np.concatenate(rows)
    order = np.argsort(row, kind="stable")
    out = atlas.select(row[order])
    tri = np.concatenate(tris)[order]
    stored = out.triangle
    if stored is not None:
        stored = stored.copy()
        has = tri >= 0
        stored[has] = index.surfaces.local_triangle[tri[has]]
    out = replace(out, anchor=np.concatenate(anchors)[order], triangle=stored)
    flags = (np.concatenate(x)[order] for x in (cuts, wholes, covers))
    return out, Contacts(out.anchor, lift_of(out, index), *flags)


def _sees(atlas, index, ids, owner, anchor, over, points, under, lift) -> np.ndarray:
    """(m,) bool: the rule points (m, 3) of patches ids[owner] (under (m,): covered) are seen from
    their patch's anchor (anchor (len(ids), 3), over (len(ids),): covered): contacts() and the split
    (_parts) test them alike, so the split's contacts are those contacts() finds."""
    g = ids[owner]
    seen = ~blocked(index, atlas.normals[g], lift[g], anchor[owner], points)
    return seen & (over[owner] == under)


def _parts(atlas, index, ids, lift, pieces: int, least: float):
    """split_at_contacts for planar patches ids: (patches, anchors, triangles, cut, whole, covered)
    per kept part, in the order the atlas keeps them (first parts, second parts, ..., patches left
    whole); cut, whole and covered as contacts() finds them for that patch and anchor."""
    out = []
    owner, points, weights, tri, whole = coarse_rule(atlas, index, ids)
    part = np.full(len(owner), -1, np.int64)
    under = covered(atlas, index, ids[owner], points, lift)
    heads = []
    for k in range(pieces):
        a = _nearest(atlas, ids, owner, points, part < 0)
        has = a >= 0
        if not np.any(has):
            break
        # the anchor as a file keeps it (float32), so contacts() of the stored atlas sees from it
        anchor = np.zeros((len(ids), 3))
        anchor[has] = points[a[has]].astype(np.float32)
        over = np.zeros(len(ids), bool)
        over[has] = covered(atlas, index, ids[has], anchor[has], lift)
        test = np.flatnonzero((part < 0) & has[owner])
        tested, seen = np.zeros(len(owner), bool), np.zeros(len(owner), bool)
        tested[test] = True
        seen[test] = _sees(atlas, index, ids, owner[test], anchor, over, points[test], under[test], lift)
        part[test[seen[test]]] = k
        part[a[has]] = k
        heads.append((a, anchor, over, tested, seen))
    total = np.bincount(owner, weights=weights, minlength=len(ids))
    held = [
        np.bincount(owner[part == k], weights=weights[part == k], minlength=len(ids))
        for k in range(len(heads))
    ]
    share = np.reshape(held, (len(heads), len(ids))) / np.maximum(total, 1e-300)
    best = np.argmax(share, axis=0) if len(heads) else np.zeros(len(ids), np.int64)
    for k, (a, anchor, over, tested, seen) in enumerate(heads):
        take = (a >= 0) & ((share[k] >= least) | (best == k))
        # a kept part is cut where any rule point of its patch is hidden from its anchor: the points
        # an earlier part took were not tested from this anchor yet
        rest = np.flatnonzero(take[owner] & ~tested)
        seen[rest] = _sees(atlas, index, ids, owner[rest], anchor, over, points[rest], under[rest], lift)
        cut = np.bincount(owner, weights=take[owner] & ~seen, minlength=len(ids)) > 0
        out.append((ids[take], anchor[take], tri[a[take]], cut[take], whole[take], over[take]))
    none = total <= 0  # no rule point on the sheet: the patch stays as it is, seen from its centre
    centers = atlas.centers[ids[none]]
    under_none = covered(atlas, index, ids[none], centers, lift)
    out.append(
        (
            ids[none],
            centers,
            np.full(len(centers), -1, np.int64),
            np.zeros(len(centers), bool),
            whole[none],
            under_none,
        )
    )
    return out


def seen_members(
    atlas,
    index,
    found: Contacts,
    rows: np.ndarray,
    cols: np.ndarray,
    points: np.ndarray,
    member: np.ndarray,
    per_row: bool = False,
):
    """Membership of (row point, col patch) pairs with the hidden pairs of cut patches removed (found:
    the atlas's contacts); a point that would be left in no patch keeps its plain membership. points
    (m, 3) per pair, or per_row: one per row point (rows index them)."""
    # only cut or covered patches hide anything (visible() is true for the others)
    check = np.flatnonzero(member & np.take(found.cut | found.covered, cols))
    if len(check) == 0:
        return member
    at = np.take(points, np.take(rows, check) if per_row else check, axis=0)
    hidden = check[~visible(found, atlas, index, np.take(cols, check), at)]
    if len(hidden) == 0:
        return member
    seen = member.copy()
    seen[hidden] = False
    m = int(rows.max()) + 1
    lost = (np.bincount(rows[member], minlength=m) > 0) & ~(np.bincount(rows[seen], minlength=m) > 0)
    return np.where(lost[rows], member, seen)


def split_corners(index, vertex: np.ndarray, corners: np.ndarray, inside: np.ndarray, normals: np.ndarray):
    """(m,) bool per face corner: the corners of its vertex lie on different sides of a contact line.

    vertex (m,) the vertex of each corner, corners (m, 3) their shared positions, inside (m, 3) each
    stepped a hair into its own triangle, normals (m, 3) the sides baked. A floor vertex on the
    line where a partition stands has corners on the lit floor and corners under the partition:
    each must be lit as its own face is there (a converged path-traced vertex bake averages them),
    not all as the first one's face. Corners sharing a normal are compared with their vertex's
    first corner by a segment between the stepped points, lifted a tenth of the step.
    """
    m = len(vertex)
    out = np.zeros(m, bool)
    if m == 0:
        return out
    order = np.argsort(vertex, kind="stable")
    v = vertex[order]
    first = np.r_[True, v[1:] != v[:-1]]
    head = order[np.maximum.accumulate(np.where(first, np.arange(m), 0))]  # per sorted corner
    rest = order[~first]
    head = head[~first]
    same = np.einsum("ij,ij->i", normals[rest], normals[head]) > 1.0 - 1e-6
    rest, head = rest[same], head[same]
    if len(rest) == 0:
        return out
    step = np.linalg.norm(inside[rest] - corners[rest], axis=1) + np.linalg.norm(
        inside[head] - corners[head], axis=1
    )
    lift = 0.05 * step
    hidden = blocked(index, normals[rest], lift, inside[head], inside[rest])
    split_vertex = np.zeros(int(vertex.max()) + 1, bool)
    split_vertex[vertex[rest[hidden]]] = True
    return split_vertex[vertex]
