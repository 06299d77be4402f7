"""See-through surfaces (a material's alpha below 1, scene/coverage.py, scene/rays.SeeThroughRays):
shadow rays' transmittance, first hits in proportion to alpha, alpha-cut masks, and the whole
solve against closed forms (a furnace with a see-through sheet, a floor under a black veil)."""

import numpy as np
import pytest
from reference import analytic

import scenes
from ovrad_addon.bake.points import BakeRequest, radiance_at
from ovrad_addon.errors import OvradError
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.light.lamps import Lamp, lamp_irradiance
from ovrad_addon.radiosity.first_shot import solve
from ovrad_addon.radiosity.problem import prepare
from ovrad_addon.scene.coverage import Coverage
from ovrad_addon.scene.rays import SeeThroughRays, ray_uniform, surface_rays
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, SolveSettings


@pytest.fixture(params=["embree", "numpy"])
def backend(request):
    return request.param


def _sheets(alphas, images=(), image_of=None):
    """Squares [0, 1]^2 at z = 1, 2, 3, ... of the given constant alphas (a map where image_of >= 0),
    UVs = (x, y)."""
    parts = [scenes.plane(size=1.0, n=1, z=k + 1.0) for k in range(len(alphas))]
    v, t, obj = scenes.merge(parts)
    opacity = np.repeat(np.asarray(alphas, float), 2)
    uv = v[t][:, :, :2].copy()
    cov = Coverage(opacity, tuple(images), None if image_of is None else np.repeat(image_of, 2), uv)
    return Surfaces.from_arrays(v, t, object_index=obj, coverage=cov)


def _upward(count, seed=0, x=(0.05, 0.95)):
    rng = np.random.default_rng(seed)
    o = np.zeros((count, 3))
    o[:, 0] = rng.uniform(*x, count)
    o[:, 1] = rng.uniform(0.05, 0.95, count)
    return o, np.tile([0.0, 0.0, 1.0], (count, 1))


def test_transmittance_is_the_product_of_one_minus_alpha(backend):
    s = _sheets([0.3, 0.5, 1.0])
    rays = surface_rays(s, backend)
    assert isinstance(rays, SeeThroughRays)
    o, d = _upward(500)
    # up to between the second and the third sheet, then past the opaque third
    np.testing.assert_allclose(rays.transmittance(o, d, np.full(500, 2.5)), 0.7 * 0.5, rtol=1e-12)
    assert np.all(rays.transmittance(o, d, np.full(500, 3.5)) == 0.0)
    assert np.all(rays.transmittance(o, d, np.full(500, 0.5)) == 1.0)  # short of every sheet
    # geometric queries still see every sheet
    assert np.all(rays.occluded(o, d, np.full(500, 1.5)))


def test_first_hits_stop_in_proportion_to_alpha_and_are_deterministic(backend):
    s = _sheets([0.3, 0.5, 1.0])
    rays = surface_rays(s, backend)
    n = 40_000
    o, d = _upward(n, seed=1)
    t, tri = rays.light_hit(o, d, np.inf)
    sheet = s.object_index[tri]
    share = np.bincount(sheet, minlength=3) / n
    # independent Bernoulli stops: 0.3, 0.7 x 0.5, the rest; 5 binomial sigmas (<= 0.0125)
    want = np.array([0.3, 0.35, 0.35])
    assert np.all(np.abs(share - want) <= 5 * np.sqrt(want * (1 - want) / n))
    np.testing.assert_allclose(t, sheet + 1.0, rtol=1e-6)  # where they stopped
    # the same rays in another batch split give the same stops
    t2 = np.concatenate([rays.light_hit(o[k : k + 999], d[k : k + 999], np.inf)[0] for k in range(0, n, 999)])
    assert np.array_equal(t, t2)


def test_ray_uniform_is_uniform_and_depends_on_every_input():
    rng = np.random.default_rng(5)
    o, d = rng.normal(size=(100_000, 3)), rng.normal(size=(100_000, 3))
    u = ray_uniform(o, d, np.zeros(100_000, np.int64))
    assert u.min() >= 0.0 and u.max() < 1.0
    counts = np.bincount((u * 10).astype(int), minlength=10)
    assert np.all(np.abs(counts - 10_000) < 5 * np.sqrt(10_000 * 0.9))
    assert not np.any(ray_uniform(o, d, np.ones(100_000, np.int64)) == u)
    o2 = o.copy()
    o2[:, 2] = np.nextafter(o2[:, 2], np.inf)
    assert np.mean(ray_uniform(o2, d, np.zeros(100_000, np.int64)) == u) < 1e-3


def test_alpha_cut_mask_lets_light_through_its_holes_exactly(backend):
    # an 8 x 8 map: alpha 0 in columns 0-3, 1 in columns 4-7; bilinear between texel centres
    # (i + 0.5) / 8 blends only for x in (0.4375, 0.5625) and, wrapping, within 1/16 of 0 and 1
    mask = np.zeros((8, 8))
    mask[:, 4:] = 1.0
    s = _sheets([1.0], images=[mask], image_of=np.array([0]))
    rays = surface_rays(s, backend)
    o_hole, d = _upward(2000, x=(0.1, 0.4))
    o_leaf, _ = _upward(2000, x=(0.6, 0.9))
    assert np.all(rays.transmittance(o_hole, d, np.inf) == 1.0)
    assert np.all(rays.transmittance(o_leaf, d, np.inf) == 0.0)
    assert np.all(rays.light_hit(o_hole, d, np.inf)[1] == -1)
    assert np.all(rays.light_hit(o_leaf, d, np.inf)[1] >= 0)
    # halfway between the centres of texels 3 and 4 the alpha is 0.5
    mid = np.array([[0.5, 0.5, 0.0]])
    np.testing.assert_allclose(rays.transmittance(mid, d[:1], np.inf), 0.5, rtol=1e-12)


def test_point_lamp_shadow_of_a_veil_is_one_minus_alpha_of_its_light(backend):
    floor_v, floor_t = scenes.plane(size=4.0, n=2)
    veil_v, veil_t = scenes.plane(size=4.0, n=2, z=0.6)
    v, t, obj = scenes.merge([(floor_v - [2, 2, 0], floor_t), (veil_v - [2, 2, 0], veil_t)])
    opacity = np.where(obj == 1, 0.4, 1.0)
    s = Surfaces.from_arrays(v, t, object_index=obj, coverage=Coverage(opacity))
    rays = surface_rays(s, backend)
    lamp = Lamp("POINT", position=(0.2, -0.1, 1.5), power=400.0)
    rng = np.random.default_rng(2)
    pts = np.zeros((300, 3))
    pts[:, :2] = rng.uniform(-1.2, 1.2, (300, 2))
    up = np.tile([0.0, 0.0, 1.0], (300, 1))
    H, _ = lamp_irradiance((lamp,), pts, up, rays, s.extent)
    want = 0.6 * analytic.point_lamp_irradiance(400.0, (0.2, -0.1, 1.5), pts, up)
    np.testing.assert_allclose(H[:, 0], want, rtol=1e-9)


def test_furnace_with_a_see_through_sheet_stays_uniform():
    # a closed cube and a half-transparent sheet across it, every surface emitting 2 and
    # reflecting 0.8: whatever a ray meets, radiance 2 / (1 - 0.8) = 10 everywhere, on the sheet
    # too. Rays that pass the sheet must go on to the walls (lost ones would darken the box).
    box = scenes.box_faces((0, 0, 0), (1, 1, 1), inward=True)
    sheet = scenes.quad((0.0, 0.0, 0.45), (1.0, 0.0, 0.45), (1.0, 1.0, 0.45), (0.0, 1.0, 0.45))
    v, t, obj = scenes.merge([*box, sheet], obj=[0] * 6 + [1])
    opacity = np.where(obj == 1, 0.5, 1.0)
    s = Surfaces.from_arrays(
        v, t, object_index=obj, reflectance=[0.8] * 3, emission=[2.0] * 3, coverage=Coverage(opacity)
    )
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=400)))
    state = solve(problem, settings=SolveSettings(tolerance=1e-5))
    pts, tri = scenes.sample_surface(s, 4000, seed=4)
    L = radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1)
    # uniform radiance is the solution whether a ray stops at the sheet or goes on, as long as
    # no ray is lost; the transport's own error is what remains (measured 7e-6)
    np.testing.assert_allclose(L, 10.0, rtol=1e-3)


def test_floor_under_a_black_veil_gets_one_minus_alpha_of_the_sun():
    # a floor (rho 0.5) under a black veil of alpha 0.3, a sun and nothing else: the floor's
    # radiance is 0.5 x 0.7 x E_sun / pi (its reflected light escapes or meets the black veil)
    floor_v, floor_t = scenes.plane(size=4.0, n=4)
    veil_v, veil_t = scenes.plane(size=6.0, n=2, z=0.8)
    v, t, obj = scenes.merge([(floor_v - [2, 2, 0], floor_t), (veil_v - [3, 3, 0], veil_t)])
    rho = np.where(obj[:, None] == 1, 0.0, 0.5) * np.ones(3)
    s = Surfaces.from_arrays(
        v,
        t,
        object_index=obj,
        reflectance=rho,
        receiver=[True, False],
        coverage=Coverage(np.where(obj == 1, 0.3, 1.0)),
    )
    sun = Lamp("SUN", direction=(0.2, 0.1, -1.0), power=3.0)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=300)))
    state = solve(problem, lamps=(sun,))
    rng = np.random.default_rng(3)
    pts = np.zeros((300, 3))
    pts[:, :2] = rng.uniform(-1.0, 1.0, (300, 2))
    tri = problem.index.rays.closest_hit(pts + [0, 0, 1e-3], np.tile([0, 0, -1.0], (300, 1)), 1.0)[1]
    L = radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1)
    e_sun = analytic.sun_irradiance(3.0, -np.array([0.2, 0.1, -1.0]), np.array([[0.0, 0.0, 1.0]]))
    # uniform light on the patches reconstructs exactly (test_pipeline: the sun on a plane)
    np.testing.assert_allclose(L, 0.5 * 0.7 * e_sun[0] / np.pi, rtol=1e-6)


def test_coverage_is_checked_and_dropped_when_everything_is_opaque():
    v, t = scenes.plane(size=1.0, n=1)
    with pytest.raises(OvradError, match="alpha"):
        Surfaces.from_arrays(v, t, coverage=Coverage(np.array([1.2, 1.0])))
    with pytest.raises(OvradError, match="every triangle"):
        Surfaces.from_arrays(v, t, coverage=Coverage(np.ones(3)))
    assert Surfaces.from_arrays(v, t, coverage=Coverage(np.ones(2))).coverage is None
    opaque = Surfaces.from_arrays(v, t, coverage=Coverage(np.ones(2)))
    assert not isinstance(surface_rays(opaque), SeeThroughRays)
