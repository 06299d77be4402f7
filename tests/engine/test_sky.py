"""World light (light/sky.py): constant colour and equirectangular maps against closed forms and
direct sums."""

import numpy as np
import pytest

from ovrad_addon.errors import OvradError
from ovrad_addon.light.sky import Sky, equirect_uv, fibonacci_sphere, sky_directions, sky_irradiance
from ovrad_addon.scene.rays import make_rays
from scenes import cube

# One small triangle far below: a scene for the ray backend that hides nothing above z = 0.
FAR = make_rays(np.array([[0, 0, -50.0], [1, 0, -50.0], [0, 1, -50.0]]), np.array([[0, 1, 2]]))
UP = np.array([[0.0, 0.0, 1.0]])


def _pixel_grid(h, w):
    """Pixel-centre directions (h, w, 3) and solid angles (h, w) of Cycles' equirectangular layout,
    computed here from the layout's definition (independently of light/sky.py)."""
    el = ((np.arange(h) + 0.5) / h - 0.5) * np.pi
    phi = (0.5 - (np.arange(w) + 0.5) / w) * 2 * np.pi
    E, P = np.meshgrid(el, phi, indexing="ij")
    d = np.stack([np.cos(E) * np.cos(P), np.cos(E) * np.sin(P), np.sin(E)], axis=-1)
    lo = (np.arange(h) / h - 0.5) * np.pi
    hi = ((np.arange(h) + 1) / h - 0.5) * np.pi
    omega = np.repeat(((np.sin(hi) - np.sin(lo)) * 2 * np.pi / w)[:, None], w, axis=1)
    return d, omega


def test_constant_sky_over_an_open_plane_gives_pi_times_its_radiance():
    L = np.array([0.6, 0.75, 1.0])
    H, _ = sky_irradiance(Sky(tuple(L)), FAR, np.zeros((1, 3)), UP, 50.0, samples=1024)
    # the closed form: integral of L cos over the hemisphere = pi L; the Fibonacci rule's error
    # on the clamped cosine is well under 0.5 % at 1024 directions
    np.testing.assert_allclose(H[0], np.pi * L, rtol=5e-3)


def test_a_uniform_map_gives_the_same_as_a_constant_sky():
    """The balance-heuristic weights of the two direction sets sum to the right measure."""
    img = np.full((32, 64, 3), 0.5)
    H, _ = sky_irradiance(
        Sky(image=img), FAR, np.zeros((2, 3)), np.array([[0, 0, 1.0], [1.0, 0, 0]]), 50.0, 1024
    )
    np.testing.assert_allclose(H, np.pi * 0.5, rtol=1e-2)


def test_a_sun_in_the_map_matches_the_direct_sum_over_its_pixels():
    h, w = 64, 128
    d, omega = _pixel_grid(h, w)
    sun = np.array([0.0, -np.cos(0.6), np.sin(0.6)])
    img = 0.2 + 50.0 * np.exp((d @ sun - 1.0) / 0.003)[..., None] * np.array([1.0, 0.9, 0.7])
    normals = np.array([[0, 0, 1.0], sun, [0, 1.0, 0]])
    H, _ = sky_irradiance(Sky(image=img), FAR, np.zeros((3, 3)), normals, 50.0, samples=2048)
    # the independent answer: sum over every pixel of L cos+ dOmega
    cos = np.clip(np.einsum("hwk,nk->nhw", d, normals), 0, None)
    exact = np.einsum("nhw,hwc,hw->nc", cos, img, omega)
    np.testing.assert_allclose(H, exact, rtol=0.03)
    assert H[1, 0] > 2 * H[2, 0]  # the sun is in the test: facing it more than doubles the light


def test_turning_the_map_turns_the_light():
    h, w = 32, 64
    d, _ = _pixel_grid(h, w)
    img = np.where((d[..., 0] > 0.5)[..., None], 4.0, 0.1) * np.ones(3)  # bright towards +X
    n_x, n_y = np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])
    a, _ = sky_irradiance(Sky(image=img), FAR, np.zeros((1, 3)), n_x, 50.0, 1024)
    b, _ = sky_irradiance(Sky(image=img, rotation_z=np.pi / 2), FAR, np.zeros((1, 3)), n_y, 50.0, 1024)
    np.testing.assert_allclose(a, b, rtol=2e-2)


def test_pixel_centres_map_back_to_their_pixel():
    h, w = 16, 32
    d, _ = _pixel_grid(h, w)
    u, v = equirect_uv(d.reshape(-1, 3), 0.0)
    rows, cols = np.divmod(np.arange(h * w), w)
    np.testing.assert_array_equal(np.floor(u * w).astype(int), cols)
    np.testing.assert_array_equal(np.floor(v * h).astype(int), rows)


def test_a_point_inside_a_closed_box_gets_no_sky():
    room = cube(inward=True)
    rays = make_rays(room.vertices, room.triangles)
    H, cast = sky_irradiance(Sky((1.0, 1.0, 1.0)), rays, np.array([[0.5, 0.5, 0.0]]), UP, 1.0, 256)
    assert cast > 0 and np.all(H == 0)


def test_fibonacci_directions_are_unit_and_balanced():
    d = fibonacci_sphere(1000)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    assert np.abs(d.mean(axis=0)).max() < 2e-3


def test_rule_weights_integrate_the_sphere():
    """Sum of weights / L over the rule = 4 pi for a uniform map (each direction's share of the sphere)."""
    img = np.ones((8, 16, 3))
    dirs, wts = sky_directions(Sky(image=img), 512)
    assert wts[:, 0].sum() == pytest.approx(4 * np.pi, rel=1e-9)


def test_bad_sky_input_is_refused():
    with pytest.raises(OvradError):
        Sky((1.0, -1.0, 0.0))
    with pytest.raises(OvradError):
        Sky(image=np.full((4, 8, 3), np.nan))


def test_mean_radiance_is_the_solid_angle_mean():
    # closed forms: a constant sky is its colour; a map bright above the horizon only is half of
    # it (the hemispheres hold equal solid angles, whatever the rows' heights in the map); a band
    # between elevations a and b holds (sin b - sin a) / 2 of the sphere
    assert np.allclose(Sky((0.2, 0.4, 0.6)).mean_radiance(), [0.2, 0.4, 0.6])
    h, w = 90, 8
    img = np.zeros((h, w, 3))
    img[h // 2 :] = [2.0, 4.0, 6.0]  # row 0 at the bottom: the upper half of the rows
    np.testing.assert_allclose(Sky(image=img).mean_radiance(), [1.0, 2.0, 3.0], rtol=1e-12)
    band = np.zeros((h, w, 3))
    band[60:75] = 1.0  # elevations 30 to 60 degrees (2 degrees per row, from -90)
    expect = (np.sin(np.radians(60)) - np.sin(np.radians(30))) / 2
    np.testing.assert_allclose(Sky(image=band).mean_radiance(), expect, rtol=1e-12)
