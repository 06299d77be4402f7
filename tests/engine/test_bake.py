"""Texel rasterisation of UV triangles and dilation (ovrad_addon/bake.py), with exact expectations."""

import numpy as np
import pytest

from ovrad_addon.bake.texels import dilate, rasterize, to_image
from ovrad_addon.errors import OvradError

# A unit quad in UV (two triangles) mapped onto a 2 x 3 rectangle at z = 1 in the world.
QUAD_UV = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)
QUAD_WORLD = np.array([[[0, 0, 1], [2, 0, 1], [2, 3, 1]], [[0, 0, 1], [2, 3, 1], [0, 3, 1]]], float)


def centres(width, height):
    i, j = np.meshgrid(np.arange(width), np.arange(height))
    return np.stack(
        [(i.ravel() + 0.5) / width, (j.ravel() + 0.5) / height], axis=1
    ), j.ravel() * width + i.ravel()


def test_unit_quad_covers_every_texel_once_at_its_world_point():
    w, h = 16, 8
    t = rasterize(QUAD_UV, QUAD_WORLD, [7, 9], w, h)
    assert len(t) == w * h
    np.testing.assert_array_equal(t.texel, np.arange(w * h))
    uv, flat = centres(w, h)
    np.testing.assert_allclose(t.points, np.c_[2 * uv[flat, 0], 3 * uv[flat, 1], np.ones(w * h)], atol=1e-12)
    # Centres below the diagonal u > v belong to the first triangle; on or above it to the second
    # (on the diagonal itself: the first, which comes first in the input).
    u, v = uv[:, 0], uv[:, 1]
    np.testing.assert_array_equal(t.triangle, np.where(u >= v, 7, 9))
    np.testing.assert_allclose(t.weights.sum(axis=1), 1.0)


def test_texel_centres_covered_are_exactly_those_inside():
    rng = np.random.default_rng(4)
    w, h = 37, 29
    uv, flat = centres(w, h)
    for _ in range(20):
        tri = rng.uniform(-0.2, 1.2, size=(3, 2))
        t = rasterize(tri[None], np.zeros((1, 3, 3)), [0], w, h)
        a, b, c = tri
        d = np.cross(b - a, c - a)
        wa = np.cross(b - uv, c - uv) / d
        wb = np.cross(c - uv, a - uv) / d
        inside = (wa > 0) & (wb > 0) & (1 - wa - wb > 0)  # random corners: no centre on an edge
        np.testing.assert_array_equal(t.texel, np.sort(flat[inside]))


def test_world_points_interpolate_the_corners():
    uv = np.array([[[0.1, 0.1], [0.9, 0.2], [0.3, 0.8]]])
    world = np.array([[[1.0, 2.0, 3.0], [-1.0, 0.0, 5.0], [4.0, 4.0, 4.0]]])
    t = rasterize(uv, world, [3], 64, 64)
    assert len(t) > 500
    np.testing.assert_allclose(t.points, t.weights @ world[0], atol=1e-12)
    # the barycentric weights reproduce the texel's UV centre
    i, j = t.texel % 64, t.texel // 64
    np.testing.assert_allclose(t.weights @ uv[0], np.c_[(i + 0.5) / 64, (j + 0.5) / 64], atol=1e-12)


def test_inset_moves_points_towards_the_centroid():
    t0 = rasterize(QUAD_UV, QUAD_WORLD, [0, 1], 8, 8)
    t1 = rasterize(QUAD_UV, QUAD_WORLD, [0, 1], 8, 8, inset=0.25)
    np.testing.assert_array_equal(t0.texel, t1.texel)
    centroid = QUAD_WORLD.mean(axis=1)[t0.triangle]
    np.testing.assert_allclose(t1.points, 0.75 * t0.points + 0.25 * centroid, atol=1e-12)


def test_shared_edges_give_each_texel_to_one_triangle():
    # a fan of 8 triangles around the centre: centres on the spokes must be counted once
    ang = np.linspace(0, 2 * np.pi, 9)
    rim = np.c_[0.5 + 0.5 * np.cos(ang), 0.5 + 0.5 * np.sin(ang)]
    uv = np.array([[[0.5, 0.5], rim[k], rim[k + 1]] for k in range(8)])
    t = rasterize(uv, np.zeros((8, 3, 3)), np.arange(8), 32, 32)
    assert len(np.unique(t.texel)) == len(t.texel)
    # every centre strictly inside the octagon is covered
    pts, flat = centres(32, 32)
    r = np.linalg.norm(pts - 0.5, axis=1)
    assert set(flat[r < 0.5 * np.cos(np.pi / 8) - 1e-9]) <= set(t.texel)


def test_degenerate_and_outside_triangles_cover_nothing():
    uv = np.array([[[0.2, 0.2], [0.4, 0.4], [0.6, 0.6]], [[1.5, 1.5], [2, 1.5], [2, 2]]])
    t = rasterize(uv, np.zeros((2, 3, 3)), [0, 1], 16, 16)
    assert len(t) == 0 and t.points.shape == (0, 3)


def test_many_triangles_in_chunks_match_one_by_one():
    rng = np.random.default_rng(1)
    uv = rng.uniform(0, 1, size=(300, 3, 2))
    world = rng.normal(size=(300, 3, 3))
    t = rasterize(uv, world, np.arange(300), 128, 128)
    for k in (0, 17, 299):
        one = rasterize(uv[k : k + 1], world[k : k + 1], [k], 128, 128)
        mine = t.triangle == k
        assert set(t.texel[mine]) <= set(one.texel)
    assert len(np.unique(t.texel)) == len(t)


def test_bad_sizes_are_refused():
    with pytest.raises(OvradError, match="image size"):
        rasterize(QUAD_UV, QUAD_WORLD, [0, 1], 0, 8)
    with pytest.raises(OvradError, match="one row per triangle"):
        rasterize(QUAD_UV, QUAD_WORLD, [0], 8, 8)


def test_dilation_fills_exactly_margin_rings():
    img = np.zeros((21, 21, 3))
    mask = np.zeros((21, 21), bool)
    img[10, 10] = (1.0, 2.0, 3.0)
    mask[10, 10] = True
    for margin in (0, 1, 3):
        out, filled = dilate(img, mask, margin)
        y, x = np.nonzero(filled)
        # the filled set is the Chebyshev ball of radius margin, all with the one value
        assert filled.sum() == (2 * margin + 1) ** 2
        assert max(np.abs(y - 10).max(), np.abs(x - 10).max()) == margin
        np.testing.assert_allclose(out[filled], np.tile([1.0, 2.0, 3.0], (filled.sum(), 1)))
        assert np.all(out[~filled] == 0)
    np.testing.assert_array_equal(img[10, 10], [1, 2, 3])  # input untouched


def test_dilation_averages_neighbours_and_keeps_filled_texels():
    img = np.zeros((4, 6, 1))
    mask = np.zeros((4, 6), bool)
    img[:, :2, 0] = 1.0
    img[:, 4:, 0] = 3.0
    mask[:, :2] = mask[:, 4:] = True
    out, filled = dilate(img, mask, 5)
    assert filled.all()
    np.testing.assert_array_equal(out[:, :2, 0], 1.0)
    np.testing.assert_array_equal(out[:, 4:, 0], 3.0)
    # column 2 sees only column 1, column 3 only column 4 (both filled in the same ring)
    np.testing.assert_allclose(out[:, 2, 0], 1.0)
    np.testing.assert_allclose(out[:, 3, 0], 3.0)


def test_dilation_of_an_empty_or_full_image_changes_nothing():
    img = np.random.default_rng(0).random((5, 5, 4))
    for mask in (np.zeros((5, 5), bool), np.ones((5, 5), bool)):
        out, filled = dilate(img, mask, 3)
        np.testing.assert_array_equal(out, img)
        np.testing.assert_array_equal(filled, mask)
    with pytest.raises(OvradError):
        dilate(img, np.ones((4, 4), bool), 1)


def test_to_image_places_values_at_their_texels():
    t = rasterize(QUAD_UV, QUAD_WORLD, [0, 1], 4, 2)
    img, mask = to_image(t, t.points, 4, 2)
    assert img.shape == (2, 4, 4) and mask.all()
    # row 1 (top), column 3: centre (0.875, 0.75) -> world (1.75, 2.25, 1)
    np.testing.assert_allclose(img[1, 3], [1.75, 2.25, 1.0, 1.0])
