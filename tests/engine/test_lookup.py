"""The patch grid (atlas/lookup.py) finds every patch that contains a point: alpha at points through the
grid equals alpha from testing every (point, patch) pair, on flat, curved and mixed-density scenes,
including points exactly on patch rims."""

import numpy as np
import pytest

import scenes
from ovrad_addon.atlas.index import index_surfaces
from ovrad_addon.atlas.support import alpha_from_pairs, pair_beta
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.overlap.contacts import contacts as find_contacts
from ovrad_addon.overlap.contacts import seen_members
from ovrad_addon.overlap.queries import alpha_at
from ovrad_addon.settings import AtlasSettings, ObjectSettings


def brute_alpha(atlas, index, pts, tri, side):
    """alpha from every (point, patch) pair: no candidate search at all (then the same contact rule,
    overlap/contacts.py, as alpha_at)."""
    m, n = len(pts), len(atlas)
    rows = np.repeat(np.arange(m), n)
    cols = np.tile(np.arange(n), m)
    sheets = index.sheet_of(tri, side)
    nrm = index.charts.normals[tri] * side[:, None]
    member, b = pair_beta(atlas, cols, pts[rows], nrm[rows], sheets[rows], atlas.beta)
    member = seen_members(atlas, index, find_contacts(atlas, index), rows, cols, pts[rows], member)
    return alpha_from_pairs(rows, cols, member, b, (m, n))


def rim_points(atlas, index, count, rng):
    """Points on patch rims (disk circles, square sides) of planar sheets, with their triangles."""
    k = rng.integers(0, len(atlas), count)
    th = rng.random(count) * 2 * np.pi
    u, v = np.cos(th), np.sin(th)
    square = atlas.shapes[k] == 1
    scale = np.where(square, 1.0 / np.maximum(np.abs(u), np.abs(v)), 1.0)
    p = atlas.centers[k] + (atlas.radii[k] * scale)[:, None] * (
        u[:, None] * atlas.tangents[k] + v[:, None] * atlas.bitangents[k]
    )
    n = atlas.normals[k]
    t, tri = index.rays.closest_hit(p + 1e-6 * n, -n, 1e-5)
    ok = tri >= 0
    return p[ok], tri[ok]


@pytest.mark.parametrize(
    "name, settings",
    [
        ("cornell", AtlasSettings(patch_count=600, beta="box")),
        ("sphere", AtlasSettings(patch_count=300, beta="smooth")),
        # a dense object beside coarse ones: per-sheet cell sizes
        (
            "cornell",
            AtlasSettings(patch_count=400, beta="smooth", objects=(ObjectSettings(density=4.0),)),
        ),
    ],
)
def test_grid_finds_every_covering_patch(name, settings):
    s = scenes.cornell() if name == "cornell" else scenes.sphere(1.0, 3)
    atlas = build_atlas(s, settings)
    index = index_surfaces(s, settings)
    rng = np.random.default_rng(1)
    pts, tri = scenes.sample_surface(s, 3000, seed=2)
    rp, rt = rim_points(atlas, index, 500, rng)
    pts, tri = np.concatenate([pts, rp]), np.concatenate([tri, rt])
    checked = 0
    for side in (1, -1):
        sides = np.full(len(tri), side)
        got = alpha_at(atlas, index, find_contacts(atlas, index), pts, tri, sides).toarray()
        want = brute_alpha(atlas, index, pts, tri, sides).toarray()
        np.testing.assert_array_equal(got != 0, want != 0)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        checked += int((want.sum(axis=1) > 0).sum())
    assert checked >= 3000  # most points are covered: the comparison is not between empty rows
