"""Emitters whose Emission Color is an image (Surfaces.emitted): their light comes from pieces of
about a texel (light.emitters.emission_pieces), checked against the irradiance of the image's
bilinear radiance integrated over the panel independently of the engine."""

import numpy as np
import pytest

from ovrad_addon.light import emitters, near, tree
from ovrad_addon.light.direct import emitter_irradiance
from ovrad_addon.light.emitters import emission_pieces, emitting_triangles, piece_splits
from ovrad_addon.scene import albedo
from ovrad_addon.scene.albedo import TextureAlbedo, texel_means, triangle_means
from ovrad_addon.scene.rays import make_rays
from ovrad_addon.scene.surfaces import Surfaces

TINT = np.array([3.0, 2.0, 1.0])  # the emission strength x colour on the image
WIDTH, HEIGHT = 1.0, 0.5  # the panel: [0, 1] x [0, 0.5] at z = 0, u = x, v = y / 0.5
BANDS = np.array([1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0] * 2)  # a 16 x 1 image: bright, dark, ...


def panel(emitted: bool = True) -> Surfaces:
    """The panel as two triangles emitting the banded image through its UVs (emitted=False: each
    triangle its mean colour, as it emitted before its image's pieces)."""
    v = np.array([[0.0, 0.0, 0.0], [WIDTH, 0.0, 0.0], [WIDTH, HEIGHT, 0.0], [0.0, HEIGHT, 0.0]])
    t = np.array([[0, 1, 2], [0, 2, 3]])
    uv = (v[:, :2] / [WIDTH, HEIGHT])[t]
    image = np.repeat(BANDS[None, :, None], 3, axis=2)  # (h, w, 3) = (1, 16, 3)
    table = TextureAlbedo((image,), np.zeros(2, np.int64), uv, np.tile(TINT, (2, 1)))
    mean = triangle_means(table, np.zeros((2, 3)), v[t], clip=False)
    return Surfaces.from_arrays(v, t, emission=mean, emitted=table if emitted else None)


def radiance_along_x(x: np.ndarray) -> np.ndarray:
    """The image's radiance factor at x: linear between texel centres (i + 0.5) / 16, wrapping
    around (what Cycles' Linear interpolation with Repeat gives)."""
    w = len(BANDS)
    centres = (np.arange(-1, w + 1) + 0.5) / w
    values = np.concatenate([BANDS[-1:], BANDS, BANDS[:1]])
    return np.interp(np.mod(x, 1.0) * WIDTH, centres * WIDTH, values)


def exact_irradiance(p: np.ndarray) -> np.ndarray:
    """Irradiance (3,) at p under the panel (z < 0, facing up): the integral over the panel of
    L(x) cos cos / r^2, across y in closed form and along x by a midpoint rule of 200 000 steps."""
    n = 200_000
    x = (np.arange(n) + 0.5) / n * WIDTH
    h = -p[2]
    a2 = (x - p[0]) ** 2 + h * h
    a = np.sqrt(a2)

    def f(y):  # the antiderivative of 1 / (a^2 + y^2)^2 in y
        return y / (2 * a2 * (a2 + y * y)) + np.arctan(y / a) / (2 * a2 * a)

    across = h * h * (f(HEIGHT - p[1]) - f(-p[1]))
    return np.sum(radiance_along_x(x) * across) * (WIDTH / n) * TINT


def points(height: float) -> np.ndarray:
    x = np.array([0.03, 0.125, 0.25, 0.31, 0.375, 0.5, 0.6, 0.75, 0.97])
    return np.column_stack([x, np.full(len(x), 0.25), np.full(len(x), -height)])


# (height under the panel, bound): measured 3.4 % (at x = 0.25 and 0.75, halfway up a ramp between a
# dark and a bright texel, which pieces of 1/17 of the panel hold as steps), 1.0 % and 1.2 % (the
# light tree's cut: 64 samples for the lit ones of 578 pieces); each triangle's mean colour alone: 60 %,
# 48 % and 18 %
@pytest.mark.parametrize(("height", "bound"), [(0.03, 0.04), (0.1, 0.02), (0.3, 0.02)])
def test_a_panel_emitting_an_image_lights_each_point_as_its_texels_do(height, bound):
    pts = points(height)
    nrm = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    exact = np.array([exact_irradiance(p) for p in pts])
    errors = {}
    for emitted in (True, False):
        s = panel(emitted)
        H, _ = emitter_irradiance(s, make_rays(s.vertices, s.triangles), np.ones(2, bool), pts, nrm, 64)
        errors[emitted] = np.abs(H - exact).max(axis=0) / exact.max(axis=0)
    # relative to the brightest point's light, every channel, every point
    assert errors[True].max() < bound
    assert errors[False].max() > 0.15


def image_power(t: int) -> np.ndarray:
    """(3,) the power per steradian-radiance unit (area x mean radiance) the image emits over the
    panel's triangle t: L(x) x the triangle's extent in y at x, integrated along x."""
    x = (np.arange(100_000) + 0.5) / 100_000
    across = HEIGHT * x if t == 0 else HEIGHT * (1 - x)
    return np.sum(radiance_along_x(x) * across) / len(x) * WIDTH * TINT


def test_a_triangle_over_many_texels_emits_their_mean():
    # The panel's triangles span 16 texels: their emission is the image's mean over them
    # (albedo.texel_means), where 16 samples of it (triangle_means' rule) were 3.8 and 2.6 % off
    s = panel()
    table = s.emitted
    few = triangle_means(table, np.zeros((2, 3)), s.corners, clip=False)
    for t in range(2):
        np.testing.assert_allclose(s.emission[t] * 0.5 * WIDTH * HEIGHT, image_power(t), rtol=1e-3)
        assert np.abs(few[t] * 0.5 * WIDTH * HEIGHT / image_power(t) - 1).max() > 0.02


def test_an_image_of_one_colour_emits_as_its_triangles_means():
    # pieces that all emit the triangle's mean leave it whole: its rows are those given
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    table = TextureAlbedo((np.full((8, 8, 3), 0.5),), np.zeros(1, np.int64), v[None, :, :2], TINT[None])
    s = Surfaces.from_arrays(v, [[0, 1, 2]], emission=[TINT * 0.5], emitted=table)
    corners, radiance = emitting_triangles(s, np.ones(1, bool))
    np.testing.assert_array_equal(corners, v[None])
    np.testing.assert_array_equal(radiance, [TINT * 0.5])


def test_pieces_tile_their_triangle_in_its_place_and_keep_its_power():
    s = panel()
    tri = np.arange(2)
    k = piece_splits(s.emitted, tri)
    assert list(k) == [17, 17]  # the diagonal spans 16.03 texels: a piece per texel
    corners, radiance = emission_pieces(s.emitted, tri, s.corners, s.emission, 1.0)
    assert len(corners) == 2 * 289
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert np.all(cross[:, 2] > 0)  # wound as the triangle
    for t in tri:
        own = slice(289 * t, 289 * (t + 1))  # the first triangle's pieces, then the second's
        area = 0.5 * cross[own, 2]
        np.testing.assert_allclose(area.sum(), 0.5 * WIDTH * HEIGHT, rtol=1e-12)
        inside = corners[own].reshape(-1, 3) @ np.cross(*(s.corners[t, 1:] - s.corners[t, 0]))
        np.testing.assert_allclose(inside, 0.0, atol=1e-15)
        # the pieces' power is the image's over the triangle
        np.testing.assert_allclose(area @ radiance[own], image_power(t), rtol=2e-3)
    # the pieces that emit nothing (the dark bands) are left out of the light
    lit, _ = emitting_triangles(s, np.ones(2, bool))
    assert len(lit) == np.sum(radiance.sum(axis=1) > 0) < len(corners)


def test_a_triangle_over_many_texels_splits_at_most_so_far_and_all_within_the_budget(monkeypatch):
    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    image = np.random.default_rng(0).uniform(0.2, 1.0, (512, 512, 3))
    one = TextureAlbedo((image,), np.zeros(1, np.int64), v[None, :, :2], TINT[None])
    assert list(piece_splits(one, np.arange(1))) == [emitters.PIECES_PER_EDGE_MOST]
    monkeypatch.setattr(emitters, "PIECES_MOST", 1000)
    many = TextureAlbedo(
        (image,), np.zeros(40, np.int64), np.repeat(v[None, :, :2], 40, 0), np.tile(TINT, (40, 1))
    )
    k = piece_splits(many, np.arange(40))
    assert np.sum(k * k) <= 1000
    assert np.all(k >= 4)


def test_a_walk_too_large_for_one_block_gives_each_point_the_same_light(monkeypatch):
    # Points 3 cm from the panel's 384 lit pieces walk the light tree to most of them; with the
    # frontier held to 500 (point, node) pairs their block is walked in halves, down to one point
    # at a time, and every point gets the same bits.
    s = panel()
    rng = np.random.default_rng(4)
    pts = np.column_stack([rng.uniform(0, WIDTH, 200), rng.uniform(0, HEIGHT, 200), np.full(200, -0.03)])
    nrm = np.tile([0.0, 0.0, 1.0], (200, 1))
    rays = make_rays(s.vertices, s.triangles)
    whole, cast = emitter_irradiance(s, rays, np.ones(2, bool), pts, nrm, 64)
    monkeypatch.setattr(near, "FRONTIER_MOST", 500)
    walked, block = [], near._near_block

    def spy(*args):
        out = block(*args)
        walked.append((len(args[-1]), out is None))
        return out

    monkeypatch.setattr(near, "_near_block", spy)
    halves, cast_halves = emitter_irradiance(s, rays, np.ones(2, bool), pts, nrm, 64)
    np.testing.assert_array_equal(halves, whole)
    assert cast_halves == cast
    assert walked[0] == (200, True)  # the whole block was too large
    assert sum(n for n, gave_up in walked if not gave_up) == 200  # each point walked once in the end


def test_a_triangles_mean_does_not_depend_on_the_block_it_is_taken_in(monkeypatch):
    rng = np.random.default_rng(5)
    corners = rng.uniform(0, 1, (50, 3, 3))
    uv = rng.uniform(0, 3, (50, 3, 2))
    table = TextureAlbedo((rng.uniform(0, 1, (20, 30, 3)),), np.zeros(50, np.int64), uv, np.ones((50, 3)))
    whole = texel_means(table, np.zeros((50, 3)), corners, clip=False)
    monkeypatch.setattr(albedo, "MEAN_BLOCK", 100)  # a block a triangle
    np.testing.assert_array_equal(texel_means(table, np.zeros((50, 3)), corners, clip=False), whole)


def test_the_walks_reach_columns_are_the_trees_finished_rows():
    # the near walk tests a node's reach on a copy of its first columns: taken once the cut has
    # set the reaches (a copy taken before read every reach as 0 and gave a screen's wall 75 % off)
    s = panel()
    corners, radiance = emitting_triangles(s, np.ones(2, bool))
    light = tree.LightTree(corners, radiance, 64)
    assert len(light.reach_columns) == len(light.levels)
    for reach, (F, _, _) in zip(light.reach_columns, light.levels, strict=True):
        np.testing.assert_array_equal(reach, F[:, : tree.REACH_COLUMNS])
    assert any(np.any(F[:, 6] > 0) for F, _, _ in light.levels)  # the reaches were set
