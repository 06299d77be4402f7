"""Textured albedo (scene/albedo.py): sampling rules checked against linear functions they must reproduce."""

import numpy as np
import pytest

from ovrad_addon.errors import OvradError
from ovrad_addon.scene.albedo import TextureAlbedo, albedo_at, barycentric, bilinear, triangle_means


def _ramp(h=8, w=16):
    """An image whose texel (row r, col c) holds (c + 0.5) / w in red, (r + 0.5) / h in green:
    bilinear interpolation between texel centres reproduces (u, v) exactly inside the centres."""
    cols = (np.arange(w) + 0.5) / w
    rows = (np.arange(h) + 0.5) / h
    img = np.zeros((h, w, 3))
    img[..., 0] = cols[None, :]
    img[..., 1] = rows[:, None]
    img[..., 2] = 0.25
    return img


def test_bilinear_reproduces_a_linear_ramp_between_texel_centres():
    img = _ramp()
    rng = np.random.default_rng(0)
    uv = rng.uniform([0.5 / 16, 0.5 / 8], [1 - 0.5 / 16, 1 - 0.5 / 8], size=(200, 2))
    out = bilinear(img, uv)
    np.testing.assert_allclose(out[:, :2], uv, atol=1e-12)
    np.testing.assert_allclose(out[:, 2], 0.25)


def test_bilinear_wraps_around_like_repeat():
    img = _ramp()
    uv = np.array([[0.3, 0.4], [1.3, -0.6], [-2.7, 3.4]])
    out = bilinear(img, uv)
    np.testing.assert_allclose(out, out[[0, 0, 0]], atol=1e-12)


def test_barycentric_weights_rebuild_the_point():
    rng = np.random.default_rng(1)
    corners = rng.normal(size=(50, 3, 3))
    bary = rng.dirichlet([1, 1, 1], size=50)
    pts = np.einsum("mk,mkj->mj", bary, corners)
    np.testing.assert_allclose(barycentric(corners, pts), bary, atol=1e-9)


def _quad_textures(tint=1.0):
    """A unit square in z = 0 as two triangles, UV = (x, y), both on the ramp image."""
    verts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    corners = verts[tris]
    tex = TextureAlbedo((_ramp(),), np.array([0, 0]), corners[:, :, :2].copy(), np.full((2, 3), tint))
    return tex, corners


def test_albedo_at_follows_the_uv_map_and_the_tint():
    tex, corners = _quad_textures(tint=0.5)
    pts = np.array([[0.25, 0.1, 0.0], [0.4, 0.7, 0.0]])
    out = albedo_at(tex, np.full((2, 3), 0.8), corners, np.array([0, 1]), pts)
    np.testing.assert_allclose(out[:, :2], 0.5 * pts[:, :2], atol=1e-12)


def test_triangles_without_a_map_keep_their_reflectance():
    tex, corners = _quad_textures()
    tex = TextureAlbedo(tex.images, np.array([-1, 0]), tex.uv, tex.tint)
    rho = np.array([[0.1, 0.2, 0.3], [0.9, 0.9, 0.9]])
    out = albedo_at(tex, rho, corners, np.array([0, 0]), np.array([[0.5, 0.2, 0], [0.7, 0.1, 0]]))
    np.testing.assert_array_equal(out, rho[[0, 0]])


def test_triangle_mean_of_a_linear_map_is_its_value_at_the_centroid():
    tex, corners = _quad_textures()
    means = triangle_means(tex, np.zeros((2, 3)), corners)
    centroid = corners.mean(axis=1)
    np.testing.assert_allclose(means[:, :2], centroid[:, :2], atol=1e-12)


def test_inconsistent_texture_tables_are_refused():
    with pytest.raises(OvradError):
        TextureAlbedo((_ramp(),), np.array([0, 1]), np.zeros((2, 3, 2)), np.ones((2, 3)))


def _painted_triangles():
    """Two triangles: the first painted (a colour per corner), the second not (NaN)."""
    corners = np.array([[[0.0, 0, 0], [2.0, 0, 0], [0.0, 1, 0]], [[3.0, 0, 0], [4.0, 0, 0], [3.0, 1, 0]]])
    paint = np.full((2, 3, 3), np.nan)
    paint[0] = [[0.9, 0.1, 0.2], [0.1, 0.8, 0.3], [0.3, 0.3, 0.7]]
    albedo = TextureAlbedo((), np.full(2, -1, np.int64), np.zeros((2, 3, 2)), np.ones((2, 3)), corners=paint)
    return corners, paint, albedo


def test_painted_albedo_is_the_corners_colours_interpolated_linearly():
    corners, paint, albedo = _painted_triangles()
    rng = np.random.default_rng(3)
    w = rng.dirichlet(np.ones(3), size=50)  # barycentric weights, then the points they make
    points = np.einsum("mk,kj->mj", w, corners[0])
    rho = np.array([[0.5, 0.5, 0.5], [0.2, 0.4, 0.6]])
    got = albedo_at(albedo, rho, corners, np.zeros(50, np.int64), points)
    np.testing.assert_allclose(got, w @ paint[0], atol=1e-12)
    other = albedo_at(albedo, rho, corners, np.ones(3, np.int64), corners[1])
    np.testing.assert_array_equal(other, np.tile(rho[1], (3, 1)))  # not painted: its own constant
    assert albedo.painted.tolist() == [True, False] and albedo.varies.tolist() == [True, False]


def test_a_painted_triangles_mean_albedo_is_its_corners_mean():
    """The mean of a linear function over a triangle is the mean of its corner values."""
    corners, paint, albedo = _painted_triangles()
    rho = np.array([[0.5, 0.5, 0.5], [0.2, 0.4, 0.6]])
    means = triangle_means(albedo, rho, corners)
    np.testing.assert_allclose(means[0], paint[0].mean(axis=0), atol=1e-12)
    np.testing.assert_array_equal(means[1], rho[1])


def test_paint_changes_the_key_and_a_table_without_paint_keeps_its_key():
    corners, paint, albedo = _painted_triangles()
    plain = TextureAlbedo((), albedo.image_of, albedo.uv, albedo.tint)
    repainted = TextureAlbedo((), albedo.image_of, albedo.uv, albedo.tint, corners=paint * 0.5)
    assert len({plain.key(), albedo.key(), repainted.key()}) == 3
    with pytest.raises(OvradError, match="corner colours"):
        TextureAlbedo((), albedo.image_of, albedo.uv, albedo.tint, corners=paint[:, :2])


def test_paint_on_a_textured_triangle_multiplies_its_map():
    img = _ramp()
    corners = np.array([[[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0]]])
    uv = np.array([[[0.2, 0.2], [0.8, 0.2], [0.2, 0.8]]])
    paint = np.array([[[1.0, 0.5, 0.2], [0.5, 0.5, 0.5], [0.2, 1.0, 0.8]]])
    plain = TextureAlbedo((img,), np.zeros(1, np.int64), uv, np.ones((1, 3)))
    both = TextureAlbedo((img,), np.zeros(1, np.int64), uv, np.ones((1, 3)), corners=paint)
    rng = np.random.default_rng(5)
    w = rng.dirichlet(np.ones(3), size=40)
    points = np.einsum("mk,kj->mj", w, corners[0])
    tri = np.zeros(40, np.int64)
    rho = np.full((1, 3), 0.5)
    expected = albedo_at(plain, rho, corners, tri, points) * (w @ paint[0])
    np.testing.assert_allclose(albedo_at(both, rho, corners, tri, points), expected, atol=1e-12)
    assert both.varies.all() and not both.painted.any() and both.has_paint.all()


def test_an_emitted_colour_is_not_clipped_as_an_albedo_is():
    img = np.full((2, 2, 3), 0.8)
    corners = np.array([[[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0]]])
    table = TextureAlbedo((img,), np.zeros(1, np.int64), np.full((1, 3, 2), 0.5), np.full((1, 3), 3.0))
    rho = np.zeros((1, 3))
    np.testing.assert_allclose(triangle_means(table, rho, corners), 1.0)  # an albedo: at most 1
    np.testing.assert_allclose(triangle_means(table, rho, corners, clip=False), 2.4, rtol=1e-12)
