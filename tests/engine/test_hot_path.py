"""The hot path of alpha gives the values of its plain formulation, kept here as the reference.

The fast path (overlap/queries.py alpha_pairs): points in blocks, every per-patch field of a pair
gathered in one row of the patch table (atlas/support.py patch_table), beta computed only where the
other tests keep the pair, the cell of a point found through the grid's direct table
(atlas/lookup.py), the contact test run once on the members of cut and covered patches
(overlap/contacts.py seen_members), the CSR built from pairs already in row order. The reference:
each field taken row by row, the full test and beta on every candidate pair, the cell by binary
search in the sorted keys, the contact test on every member, alpha through alpha_from_pairs. On two
rooms joined by a doorway (contact lines), a room of leaves (ball patches) and both beta profiles,
at sampled points, points on patch rims and transport ray hits: the same entries in the same order,
values within 1e-12 relative (on x86-64 they agree bit for bit).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from test_clutter import small_cluttered_room
from test_contact import two_rooms

import scenes
from ovrad_addon.atlas.support import RIM_TOLERANCE, pair_beta
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.names import SHAPE_BALL, SHAPE_SQUARE
from ovrad_addon.overlap.queries import alpha_at, alpha_pairs, ray_hits
from ovrad_addon.overlap.sight import visible
from ovrad_addon.radiosity.problem import prepare
from ovrad_addon.radiosity.transport import cosine_directions
from ovrad_addon.settings import AtlasSettings

RTOL = 1e-12


def reference_beta(atlas, idx, x, y, beta, h):
    r = atlas.radii[idx]
    shape = atlas.shapes[idx]
    square = shape == SHAPE_SQUARE
    u, v = x / r, y / r
    d2 = u * u + v * v + np.where(shape == SHAPE_BALL, np.square(h / r), 0.0)
    inside = np.where(
        square, np.maximum(np.abs(u), np.abs(v)) <= 1.0 + RIM_TOLERANCE, d2 <= (1.0 + RIM_TOLERANCE) ** 2
    )
    if beta == "box":
        return inside, inside.astype(np.float64)
    disk = np.square(np.clip(1.0 - d2, 0.0, None))
    sq = np.clip(1.0 - u * u, 0.0, None) * np.clip(1.0 - v * v, 0.0, None)
    return inside, np.where(inside, np.where(square, sq, disk), 0.0)


def reference_same_sheet(atlas, i, points, normals, beta):
    rel = points - atlas.centers[i]
    x = np.einsum("ij,ij->i", rel, atlas.tangents[i])
    y = np.einsum("ij,ij->i", rel, atlas.bitangents[i])
    h = np.einsum("ij,ij->i", rel, atlas.normals[i])
    inside, b = reference_beta(atlas, i, x, y, beta, h)
    ok = inside & (np.einsum("ij,ij->i", normals, atlas.normals[i]) >= atlas.min_cos[i])
    ok &= np.abs(h) <= atlas.thickness[i]
    return ok, np.where(ok, b, 0.0)


def reference_pair_beta(atlas, idx, points, normals, sheets, beta):
    member, b = np.zeros(len(idx), bool), np.zeros(len(idx))
    cand = np.flatnonzero(sheets == atlas.sheet[idx])
    i = idx[cand]
    rel = points[cand] - atlas.centers[i]
    br = atlas.bounding_radii[i] * (1.0 + 10.0 * RIM_TOLERANCE)
    near = np.einsum("ij,ij->i", rel, rel) <= br * br + atlas.thickness[i] ** 2
    cand = cand[near]
    member[cand], b[cand] = reference_same_sheet(atlas, i[near], points[cand], normals[cand], beta)
    return member, b


def reference_candidates(grid, points, sheets):
    """PatchGrid.candidates by binary search in the sorted keys."""
    ok = (sheets >= 0) & (sheets < len(grid.cell))
    s = np.where(ok, sheets, 0)
    ijk, inside = grid.cells(points, s)
    ok &= inside
    d = grid.dims[s]
    key = grid.offset[s] + ijk[:, 0] + d[:, 0] * (ijk[:, 1] + d[:, 1] * ijk[:, 2])
    pos = np.minimum(np.searchsorted(grid.keys, key), len(grid.keys) - 1)
    ok &= grid.keys[pos] == key
    rows = np.flatnonzero(ok)
    first, last = grid.start[pos[rows]], grid.start[pos[rows] + 1]
    cols = [grid.patches[a:b] for a, b in zip(first, last, strict=True)]
    return np.repeat(rows, last - first), np.concatenate(cols) if cols else np.zeros(0, np.int64)


def reference_alpha(atlas, index, found, points, tri, side):
    sheets = index.sheet_of(tri, side)
    nrm = index.charts.normals[np.maximum(tri, 0)] * np.where(side < 0, -1.0, 1.0)[:, None]
    rows, cols = reference_candidates(atlas.grid, points, sheets)
    member, b = reference_same_sheet(atlas, cols, points[rows], nrm[rows], atlas.beta)
    check = np.flatnonzero(member)
    seen = member.copy()
    seen[check] = visible(found, atlas, index, cols[check], points[rows[check]])
    m = len(points)
    lost = (np.bincount(rows[member], minlength=m) > 0) & ~(np.bincount(rows[seen], minlength=m) > 0)
    member = np.where(lost[rows], member, seen)
    rows, cols, b = rows[member], cols[member], b[member]
    bsum = np.bincount(rows, weights=b, minlength=m)
    count = np.bincount(rows, minlength=m).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(bsum[rows] <= 0.0, 1.0 / count[rows], b / bsum[rows])
    return csr_matrix((a, (rows, cols)), shape=(m, len(atlas)))


def assert_same(got: csr_matrix, want: csr_matrix):
    want.sum_duplicates()
    np.testing.assert_array_equal(got.indptr, want.indptr)
    np.testing.assert_array_equal(got.indices, want.indices)
    np.testing.assert_allclose(got.data, want.data, rtol=RTOL, atol=0)


def rim_points(atlas, index, count, rng):
    """Points on patch rims (disk circles, square sides), with their triangles."""
    k = rng.integers(0, len(atlas), count)
    th = rng.random(count) * 2 * np.pi
    u, v = np.cos(th), np.sin(th)
    scale = np.where(atlas.shapes[k] == SHAPE_SQUARE, 1.0 / np.maximum(np.abs(u), np.abs(v)), 1.0)
    p = atlas.centers[k] + (atlas.radii[k] * scale)[:, None] * (
        u[:, None] * atlas.tangents[k] + v[:, None] * atlas.bitangents[k]
    )
    n = atlas.normals[k]
    _, tri = index.rays.closest_hit(p + 1e-6 * n, -n, 1e-5)
    ok = tri >= 0
    return p[ok], tri[ok]


@pytest.fixture(scope="module", params=["doorway-smooth", "doorway-box", "leaves-smooth"])
def case(request):
    """(surfaces, atlas, index, contacts) as a solve has them (radiosity.problem.prepare)."""
    name, beta = request.param.split("-")
    s = two_rooms() if name == "doorway" else small_cluttered_room()
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=600, beta=beta)))
    return s, problem.atlas, problem.index, problem.contacts


def test_alpha_at_equals_the_reference_at_points_rims_and_ray_hits(case):
    s, atlas, index, found = case
    if "leaves" in s.object_names:
        assert np.any(atlas.shapes == SHAPE_BALL)
    else:
        assert found.cut.sum() > 10  # the doorway's contact lines cut patches
    rng = np.random.default_rng(4)
    pts, tri = scenes.sample_surface(s, 6000, seed=5)
    rp, rt = rim_points(atlas, index, 1500, rng)
    pts, tri = np.concatenate([pts, rp]), np.concatenate([tri, rt])
    side = np.where(rng.random(len(tri)) < 0.8, 1, -1)
    # transport-like hits: cosine rays from sampled points, on the side they arrive at
    o, ot = scenes.sample_surface(s, 300, seed=6)
    nrm = index.charts.normals[ot]
    d = cosine_directions(nrm, 32, rng).reshape(-1, 3)
    hits = ray_hits(index, np.repeat(o + 1e-6 * s.extent * nrm, 32, axis=0), d)
    pts, tri = np.concatenate([pts, hits.points]), np.concatenate([tri, hits.triangle])
    side = np.concatenate([side, hits.side])
    assert len(tri) > 12_000  # several blocks of the fast path
    want = reference_alpha(atlas, index, found, pts, tri, side)
    got = alpha_at(atlas, index, found, pts, tri, side)
    assert_same(got, want)
    assert want.nnz > len(tri)  # points overlap several patches: not a comparison of empty rows
    # the pairs come in the CSR's order
    rows, cols, a = alpha_pairs(atlas, index, found, pts, tri, side)
    coo = got.tocoo()
    np.testing.assert_array_equal(rows, coo.row)
    np.testing.assert_array_equal(cols, coo.col)
    np.testing.assert_array_equal(a, coo.data)
    # the grid's binary search, where its cells are too many for a direct table, finds the same
    slow = replace(atlas.grid, direct=None)
    for got_rc, want_rc in zip(
        slow.candidates(pts, index.sheet_of(tri, side)),
        atlas.grid.candidates(pts, index.sheet_of(tri, side)),
        strict=True,
    ):
        np.testing.assert_array_equal(got_rc, want_rc)


def test_pair_beta_across_sheets_equals_the_reference(case):
    """C's integration pairs rule points with patches of any sheet (pair_beta with sheets)."""
    s, atlas, index, _ = case
    rng = np.random.default_rng(7)
    pts, tri = scenes.sample_surface(s, 4000, seed=8)
    side = np.where(rng.random(len(tri)) < 0.8, 1, -1)
    sheets = index.sheet_of(tri, side)
    nrm = index.charts.normals[tri] * side[:, None]
    # each point paired with its nearest patches, whatever their sheet, and random others
    _, near = atlas.tree.query(pts, 6)
    rows = np.concatenate([np.repeat(np.arange(len(pts)), 6), rng.integers(0, len(pts), 4000)])
    cols = np.concatenate([near.ravel(), rng.integers(0, len(atlas), 4000)])
    want = reference_pair_beta(atlas, cols, pts[rows], nrm[rows], sheets[rows], atlas.beta)
    got = pair_beta(atlas, cols, pts[rows], nrm[rows], sheets[rows], atlas.beta)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_allclose(got[1], want[1], rtol=RTOL, atol=0)
    assert want[0].sum() > 4000
