"""C kept with the atlas: Generate integrates the overlap matrix once and the file keeps it, so a solve
uses it instead of integrating it again.

C is block diagonal over atlas objects (patches overlap only on their own sheet, and a sheet lies on
one object), and a patch's row of C depends on that patch and its sheet's patches around it only
(overlap.matrix.overlap_matrix), so each atlas object keeps its own block: its off-diagonal entries on mesh
edges between overlapping patches, (C[i, j], C[j, i]) for the edge (i, j), i < j (C[h, k] = c_kh, the
integral of alpha_k over D_h: C is not symmetric), and its diagonal c_kk as the patches' effective
areas. Values are float32, as every attribute: the solve moves by about
1e-8 of its radiosity (Cornell box), far below its noise. The support areas A_h are taken again as
the row sums of the C read back, so sum_i c_ih = A_h holds exactly, as the solver expects.

A kept block is used only when its key, stored with it, is the key of what the solve reads: the
patches (every array C depends on), the world geometry they were integrated in (each object's
triangles in world space, in any object order: rays meet every object), the patches' own objects,
the rule (quadrature, crease angle, RULE_VERSION) and the kept values themselves. Anything else
(an edited atlas, a moved object, an atlas from an older version with no C) is integrated again.
The quadrature is the block's own (KeptOverlaps.quadrature, kept beside the key; Generate chooses
it by the atlas's size, AtlasSettings.rule_order): the key is checked with the rule the block was
integrated with.

A block also keeps its patches' contact flags (overlap.contacts.contact_flags: cut, whole, covered; the
anchors are the atlas's own), under its key: a solve whose block fits takes the contacts C was
integrated with instead of finding them again (100 k patches: about 5 s), and so does a bake of the
reopened file. Blocks kept before the flags were have keys made without them and still fit; their
patches' contacts are found again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix, triu

from ..atlas.patches import Atlas
from ..digest import add_array, hasher
from ..scene.surfaces import Surfaces
from ..settings import FINE_QUADRATURE, AtlasSettings

# Raise when the overlap package integrates C differently (its rule, membership, contacts, clutter
# samples): a C kept in a file with another RULE_VERSION is then integrated again instead of used.
# 2: rows of repeated neighbourhoods copied (overlap.matrix.repeated_rows); 3: border crossings
# (overlap.cuts.support_cuts)
RULE_VERSION = 3


@dataclass(frozen=True)
class KeptOverlaps:
    """The block of C of `count` patches of an atlas, from patch `start` on (one atlas object), as a
    file keeps it: edges (m, 2) int32 patch pairs i < j within the block, values (m, 2) float32
    (C[i, j], C[j, i]), diagonal (count,) float32 c_kk, key, the overlap_key() it was stored with,
    and quadrature, the rule it was integrated with (blocks kept before it was stored: 12); contacts
    (count,) int32, the patches' contact flags C was integrated with (overlap.contacts.contact_flags; None:
    kept without them, found again by a solve)."""

    start: int
    count: int
    key: str
    edges: np.ndarray
    values: np.ndarray
    diagonal: np.ndarray
    quadrature: int = FINE_QUADRATURE
    contacts: np.ndarray | None = None

    def matrix(self) -> csr_matrix:
        """The block (count x count, float64)."""
        i, j = self.edges[:, 0].astype(np.int64), self.edges[:, 1].astype(np.int64)
        k = np.arange(self.count)
        rows = np.concatenate([i, j, k])
        cols = np.concatenate([j, i, k])
        vals = np.concatenate([self.values[:, 0], self.values[:, 1], self.diagonal]).astype(np.float64)
        C = coo_matrix((vals, (rows, cols)), shape=(self.count, self.count)).tocsr()
        C.eliminate_zeros()
        return C


def kept_form(C: csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(edges, values, diagonal) of a block of C as a file keeps it (see KeptOverlaps)."""
    C = csr_matrix(C)
    pairs = triu(C + C.T, k=1).tocoo()
    order = np.lexsort((pairs.col, pairs.row))
    i, j = pairs.row[order], pairs.col[order]
    # C[i, j] with empty index arrays is a (1, 0) sparse matrix, not an empty array: an atlas whose
    # patches overlap nothing (a few small separate pieces) has no pairs
    values = np.zeros((0, 2))
    if len(i):
        values = np.column_stack([np.asarray(C[i, j]).ravel(), np.asarray(C[j, i]).ravel()])
    return (
        np.column_stack([i, j]).astype(np.int32).reshape(-1, 2),
        values.astype(np.float32).reshape(-1, 2),
        C.diagonal().astype(np.float32),
    )


def _object_digest(piece: bytes) -> bytes:
    h = hasher(16)
    h.update(piece)
    return h.digest()


def object_keys(surfaces: Surfaces) -> list[bytes]:
    """Per surfaces object, a hash of its triangles' world-space corners, in its own triangle order."""
    n = len(surfaces.object_names)
    order = np.argsort(surfaces.object_index, kind="stable")
    ends = np.searchsorted(surfaces.object_index[order], np.arange(n + 1))
    corners = np.ascontiguousarray(surfaces.vertices[surfaces.triangles[order]])
    pieces = (corners[ends[o] : ends[o + 1]].tobytes() for o in range(n))
    return [_object_digest(b) for b in pieces]


def overlap_key(
    surfaces: Surfaces | list[bytes],
    atlas: Atlas,
    edges: np.ndarray,
    values: np.ndarray,
    diagonal: np.ndarray,
    quadrature: int,
    crease_angle: float = AtlasSettings().crease_angle,
    contacts: np.ndarray | None = None,
) -> str:
    """The key of a kept block of C (edges, values, diagonal) of `atlas` (one atlas object's patches,
    as stored: see the module's docstring for what it covers), with its contact flags where it keeps
    them (int32; None: a block kept without them has the key it had before they were kept).
    surfaces: or their object_keys()."""
    keys = object_keys(surfaces) if isinstance(surfaces, Surfaces) else surfaces
    world = sorted(set(keys))
    rank = {k: r for r, k in enumerate(world)}
    h = hasher(20)
    h.update(f"ovrad overlaps {RULE_VERSION} q{quadrature} crease{crease_angle!r} {atlas.beta}".encode())
    h.update(b"".join(sorted(keys)))
    object_rank = np.array([rank[k] for k in keys], np.int64)
    add_array(h, object_rank[np.asarray(atlas.source_object, np.int64)])
    for a in (*atlas.placement, atlas.random, atlas.triangle, atlas.side, atlas.anchor):
        add_array(h, a)
    for a in (edges, values, diagonal):
        add_array(h, a)
    if contacts is not None:
        add_array(h, np.asarray(contacts, np.int32))
    return h.hexdigest()


def keep(
    surfaces: Surfaces | list[bytes],
    atlas: Atlas,
    C: csr_matrix,
    quadrature: int,
    crease_angle: float,
    start: int = 0,
    contacts: np.ndarray | None = None,
) -> KeptOverlaps:
    """The block C (len(atlas) square) of `atlas` (as stored, one atlas object's patches; start: the
    position of its first patch in the atlas a solve concatenates) ready to be kept, with its key;
    contacts (len(atlas),): the patches' contact flags C was integrated with (overlap.contacts.contact_flags).
    surfaces: or their object_keys() (computed once for many blocks)."""
    edges, values, diagonal = kept_form(C)
    if contacts is not None:
        contacts = np.asarray(contacts, np.int32)
    key = overlap_key(surfaces, atlas, edges, values, diagonal, quadrature, crease_angle, contacts)
    return KeptOverlaps(start, len(atlas), key, edges, values, diagonal, quadrature, contacts)


def fitting(surfaces: Surfaces, atlas: Atlas, kept: list[KeptOverlaps]) -> list[KeptOverlaps]:
    """The kept blocks that fit: their key, with their own quadrature, is the key of what the solve
    reads now (no two of them hold the same patch)."""
    n = len(atlas)
    known = np.zeros(n, bool)
    out = []
    keys = object_keys(surfaces) if kept else []
    for k in kept:
        part = np.arange(k.start, k.start + k.count)
        if k.count == 0 or k.start < 0 or k.start + k.count > n or np.any(known[part]):
            continue
        if len(k.diagonal) != k.count or (len(k.edges) and (k.edges.min() < 0 or k.edges.max() >= k.count)):
            continue
        if k.contacts is not None and len(k.contacts) != k.count:
            continue
        key = overlap_key(
            keys, atlas.select(part), k.edges, k.values, k.diagonal, k.quadrature, contacts=k.contacts
        )
        if key != k.key:
            continue
        known[part] = True
        out.append(k)
    return out


def usable(
    surfaces: Surfaces, atlas: Atlas, kept: list[KeptOverlaps]
) -> tuple[np.ndarray, csr_matrix | None]:
    """The kept blocks that fit (fitting()), as stacked() gives them."""
    return stacked(fitting(surfaces, atlas, kept), len(atlas))


def stacked(fit: list[KeptOverlaps], n: int) -> tuple[np.ndarray, csr_matrix | None]:
    """(known (n,) bool: the patches whose rows and columns of C the blocks `fit` (fitting()) of an
    atlas of n patches give, C (n x n) holding them; None: no block)."""
    known = np.zeros(n, bool)
    blocks = []
    for k in fit:
        known[k.start : k.start + k.count] = True
        blocks.append(k.matrix().tocoo())
        blocks[-1].row += k.start
        blocks[-1].col += k.start
    if not blocks:
        return known, None
    rows = np.concatenate([b.row for b in blocks])
    cols = np.concatenate([b.col for b in blocks])
    vals = np.concatenate([b.data for b in blocks])
    return known, coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()


def kept_contacts(fit: list[KeptOverlaps], n: int) -> tuple[np.ndarray, np.ndarray]:
    """(flags (n,) int32, flagged (n,) bool): the contact flags kept by the blocks `fit` (fitting())
    of an atlas of n patches, and the patches they give them for."""
    flags = np.zeros(n, np.int32)
    flagged = np.zeros(n, bool)
    for k in fit:
        if k.contacts is not None:
            flags[k.start : k.start + k.count] = k.contacts
            flagged[k.start : k.start + k.count] = True
    return flags, flagged
