"""Small sampling helpers against their defining properties: tangent frames, cosine-distributed
hemisphere directions, directions over a cone, and where shadow rays start."""

import numpy as np
import pytest

from ovrad_addon.geometry import tangent_frame
from ovrad_addon.light.lamps import cone_directions, shadow_origin
from ovrad_addon.radiosity.transport import cosine_directions


def unit_vectors(count, seed):
    v = np.random.default_rng(seed).normal(size=(count, 3))
    v = np.concatenate([v, np.eye(3), -np.eye(3)])  # axis-aligned normals too
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_tangent_frame_is_orthonormal_and_right_handed():
    n = unit_vectors(500, seed=1)
    t, b = tangent_frame(n)
    for u, v, want in ((t, t, 1), (b, b, 1), (t, b, 0), (t, n, 0), (b, n, 0)):
        np.testing.assert_allclose(np.einsum("ij,ij->i", u, v), want, atol=1e-14)
    np.testing.assert_allclose(np.cross(t, b), n, atol=1e-14)  # (t, b, n) right-handed
    t1, b1 = tangent_frame(n[0])  # one normal (3,) gives one frame
    np.testing.assert_allclose([t1, b1], [t[0], b[0]], atol=1e-15)


def test_cosine_directions_are_unit_vectors_in_the_hemisphere():
    n = unit_vectors(200, seed=2)
    d = cosine_directions(n, 32, np.random.default_rng(0))
    assert d.shape == (len(n), 32, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0, atol=1e-14)
    assert np.einsum("mkj,mj->mk", d, n).min() >= -1e-14


@pytest.mark.parametrize("count, bands", [(32, 4), (36, 6), (7, 1)])
def test_cosine_directions_fill_each_band_of_sin2_equally(count, bands):
    # Cosine-distributed: sin^2(theta) = 1 - cos^2 is uniform on [0, 1]. Stratified on a
    # bands x (count / bands) grid (bands the largest divisor of count up to its square root),
    # every point has exactly count / bands directions in each band [i / bands, (i + 1) / bands).
    n = unit_vectors(100, seed=3)
    cos = np.einsum("mkj,mj->mk", cosine_directions(n, count, np.random.default_rng(1)), n)
    band = np.floor((1.0 - cos**2) * bands).clip(0, bands - 1).astype(int)
    counts = np.stack([np.bincount(row, minlength=bands) for row in band])
    assert (counts == count // bands).all()


def test_cosine_directions_mean_cosine_is_within_its_strata_bounds():
    # cos = sqrt(1 - s) with s stratified in 4 bands of 8 samples (count 32): the mean cosine of
    # each point lies between the band-wise minima and maxima, (sqrt(3/4) + sqrt(1/2) + sqrt(1/4)
    # + 0) / 4 and (1 + sqrt(3/4) + sqrt(1/2) + sqrt(1/4)) / 4, and the expected 2/3 is inside.
    low = (np.sqrt(0.75) + np.sqrt(0.5) + 0.5) / 4
    high = (1.0 + np.sqrt(0.75) + np.sqrt(0.5) + 0.5) / 4
    n = unit_vectors(300, seed=4)
    mean = np.einsum("mkj,mj->mk", cosine_directions(n, 32, np.random.default_rng(2)), n).mean(axis=1)
    assert low < 2.0 / 3.0 < high
    assert low <= mean.min() and mean.max() <= high


@pytest.mark.parametrize("count", [4, 16, 17, 64])
def test_cone_directions_mean_is_exactly_along_the_axis(count):
    # Equal-solid-angle rings (midpoints in cos) with evenly spaced azimuths: the components
    # across the axis cancel, and the mean cosine to the axis is the cone's, (1 + cos a) / 2.
    axis = unit_vectors(50, seed=5)
    cos_a = np.random.default_rng(6).uniform(-0.5, 0.999, len(axis))
    d, norm = cone_directions(axis, cos_a, count, np.random.default_rng(7))
    k = d.shape[1]
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0, atol=1e-14)
    assert (np.einsum("mkj,mj->mk", d, axis) >= cos_a[:, None] - 1e-14).all()  # inside the cone
    np.testing.assert_allclose(d.mean(axis=1), 0.5 * (1.0 + cos_a)[:, None] * axis, atol=1e-14)
    np.testing.assert_allclose(norm, k * 0.5 * (1.0 + cos_a), rtol=1e-14)


def test_shadow_origin_steps_eps_off_the_surface_and_twice_eps_along_the_ray():
    # p = (1, 2, 0) on a floor (n = +z), ray towards (0.6, 0, 0.8), eps = 1e-3:
    # p + eps n + 2 eps d = (1 + 0.0012, 2, 0.001 + 0.0016).
    got = shadow_origin(
        np.array([[1.0, 2.0, 0.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([[0.6, 0.0, 0.8]]), 1e-3
    )
    np.testing.assert_allclose(got, [[1.0012, 2.0, 0.0026]], rtol=0, atol=1e-15)


def test_shadow_origin_at_a_wall_foot_leaves_both_planes():
    # A floor point on the foot of the wall x = 0: a grazing ray into the room (along +x, in the
    # floor's plane) must start off the wall's plane too, else it hits the wall at t = 0.
    eps = 1e-6
    p = np.zeros((1, 3))
    grazing = shadow_origin(p, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]), eps)
    np.testing.assert_allclose(grazing, [[2 * eps, 0.0, eps]], rtol=0, atol=1e-21)
