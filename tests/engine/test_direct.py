"""Direct light at bake points (light/direct.py, bake.points.radiance_at with the first shot split off)
against closed forms: emitter sampling, shadow rays from concave edges, sharp shadows."""

from dataclasses import replace

import numpy as np
import pytest
from reference import analytic

import scenes
from ovrad_addon.bake import points
from ovrad_addon.bake.points import BakeRequest, irradiance_at, radiance_at
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.geometry import subtriangle_centroids
from ovrad_addon.light import direct, tree
from ovrad_addon.light import lamps as lights
from ovrad_addon.light import near as near_field
from ovrad_addon.light.direct import DirectLight, emitter_irradiance, triangle_normals
from ovrad_addon.light.emitters import polygon_irradiance
from ovrad_addon.light.lamps import Lamp, lamp_irradiance
from ovrad_addon.radiosity.first_shot import direct_light, emitter_sample_count, solve
from ovrad_addon.radiosity.problem import prepare
from ovrad_addon.scene.rays import make_rays
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, SolveSettings

RHO = 0.8


def near_emitter(monkeypatch, value: float) -> None:
    """Set the near field's reach in sample spacings: NEAR_EMITTER for the samples of each triangle
    (light/direct.py), and the reach of the light tree's cut nodes in their radii (tree.CUT_REACH,
    twice that; 0: no node is near, its samples alone)."""
    monkeypatch.setattr(direct, "NEAR_EMITTER", value)
    monkeypatch.setattr(tree, "CUT_REACH", 2.0 * value if value > 0 else -1e30)


def _emitter_over_plane(flip: bool):
    """A 1 m x 0.8 m emitting rectangle 0.5 m above a 4 m plane, facing down (or up, flipped)."""
    rect = np.array([[-0.5, -0.4, 0.5], [0.5, -0.4, 0.5], [0.5, 0.4, 0.5], [-0.5, 0.4, 0.5]])
    tri = np.array([[0, 2, 1], [0, 3, 2]]) if not flip else np.array([[0, 1, 2], [0, 2, 3]])
    pv, pt = scenes.plane(size=4.0, n=1)
    v = np.vstack([rect, pv - [2.0, 2.0, 0.0]])
    t = np.vstack([tri, pt + 4])
    emission = np.zeros((len(t), 3))
    emission[:2] = [2.0, 1.0, 0.5]
    s = Surfaces.from_arrays(v, t, object_index=[0, 0] + [1] * len(pt), emission=emission)
    return s, rect


@pytest.mark.parametrize("flip", [False, True])
def test_emitter_irradiance_matches_lambert_contour_form_factor(flip):
    # Emission shaders emit from both sides (as in Cycles): the winding must not matter.
    s, rect = _emitter_over_plane(flip)
    rng = np.random.default_rng(3)
    pts = np.zeros((200, 3))
    pts[:, :2] = rng.uniform(-1.2, 1.2, size=(200, 2))  # under the emitter and well beside it
    nrm = np.tile([0.0, 0.0, 1.0], (200, 1))
    rays = make_rays(s.vertices, s.triangles)
    exact = np.pi * analytic.ff_point_to_polygon(pts, nrm, rect)[:, None] * [2.0, 1.0, 0.5]
    errors = []
    for samples in (64, 256):
        H, cast = emitter_irradiance(s, rays, s.emission.sum(1) > 0, pts, nrm, samples)
        errors.append(np.abs(H / exact - 1.0).max())
        # the rule: each of the 2 triangles split into k^2 sub-triangles, k = ceil(sqrt(samples / 2))
        k = int(np.ceil(np.sqrt(samples / 2)))
        assert cast == 200 * 2 * k * k
    # a midpoint rule: second order, so 4x the points gives about 1/4 of the error
    # (measured 1.15 % and 0.29 %)
    assert errors[1] < 4e-3
    assert 3.0 < errors[0] / errors[1] < 5.0


def test_the_emitter_rule_is_made_once_per_emitters_and_count(monkeypatch):
    """A gather asks for the emitters' light at every chunk of its near hits: the EmitterRules a
    problem keeps make the rule once for the same emitters (an equal copy too) and count, again for
    others; plain surfaces keep nothing between calls."""
    s, _ = _emitter_over_plane(False)
    rays = make_rays(s.vertices, s.triangles)
    pts, nrm = np.zeros((5, 3)), np.tile([0.0, 0.0, 1.0], (5, 1))
    made = []
    real = direct.emitter_samples
    monkeypatch.setattr(direct, "emitter_samples", lambda *a, **k: made.append(1) or real(*a, **k))
    emitters = s.emission.sum(1) > 0
    rules = direct.EmitterRules(s)
    first, _ = emitter_irradiance(rules, rays, emitters, pts, nrm, 64)
    again, _ = emitter_irradiance(rules, rays, emitters.copy(), pts, nrm, 64)  # an equal copy
    assert len(made) == 1
    np.testing.assert_array_equal(first, again)
    emitter_irradiance(rules, rays, emitters, pts, nrm, 16)  # another count
    other = emitters.copy()
    other[np.flatnonzero(emitters)[0]] = False  # other emitters
    emitter_irradiance(rules, rays, other, pts, nrm, 64)
    assert len(made) == 3
    alone, _ = emitter_irradiance(s, rays, emitters, pts, nrm, 64)
    emitter_irradiance(s, rays, emitters, pts, nrm, 64)
    assert len(made) == 5
    np.testing.assert_array_equal(alone, first)


def test_shadow_ray_from_a_concave_edge_is_not_blocked_by_the_neighbouring_face():
    # A floor and a wall meeting at x = 0; points on the line where they meet lie in both planes.
    floor = scenes.quad([0, -1, 0], [2, -1, 0], [2, 1, 0], [0, 1, 0])
    wall = scenes.quad([0, -1, 0], [0, 1, 0], [0, 1, 2], [0, -1, 2])
    v = np.vstack([floor[0], wall[0]])
    t = np.vstack([floor[1], wall[1] + 4])
    rays = make_rays(v, t)
    pts = np.column_stack([np.zeros(9), np.linspace(-0.8, 0.8, 9), np.zeros(9)])
    to_sun = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    sun = Lamp("SUN", direction=tuple(-to_sun), power=3.0)
    for normal in ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]):  # as a floor point and as a wall point
        nrm = np.tile(normal, (9, 1))
        H, _ = lamp_irradiance((sun,), pts, nrm, rays, 2.0)
        np.testing.assert_allclose(H[:, 0], 3.0 * (nrm @ to_sun), rtol=1e-12)


def shadowed_plane_scene() -> tuple[Surfaces, Lamp]:
    """A 4 m plane (rho 0.8) under a point lamp, with a 0.6 m square pure occluder between."""
    pv, pt = scenes.plane(size=4.0, n=4)
    occ_v, occ_t = scenes.quad([-0.3, -0.3, 1.0], [0.3, -0.3, 1.0], [0.3, 0.3, 1.0], [-0.3, 0.3, 1.0])
    v = np.vstack([pv - [2.0, 2.0, 0.0], occ_v])
    t = np.vstack([pt, occ_t + len(pv)])
    obj = np.r_[np.zeros(len(pt), int), np.ones(len(occ_t), int)]
    s = Surfaces.from_arrays(v, t, object_index=obj, reflectance=[RHO] * 3, receiver=[True, False])
    return s, Lamp("POINT", position=(0.2, 0.1, 2.0), power=500.0)


@pytest.fixture(scope="module")
def shadowed_plane():
    s, lamp = shadowed_plane_scene()
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=400)))
    return problem, lamp, solve(problem, (lamp,))


def closed_form_direct(points, lamp_pos, power):
    """Point-lamp irradiance on the plane z = 0, zero where the segment to the lamp crosses the
    occluder square |x|, |y| <= 0.3 at z = 1; and how far each point is from the shadow's edge."""
    v = lamp_pos - points
    d2 = np.einsum("ij,ij->i", v, v)
    H = power / (4 * np.pi) * v[:, 2] / np.sqrt(d2) / d2
    s = (1.0 - points[:, 2]) / v[:, 2]  # where the segment meets z = 1
    cross = points[:, :2] + s[:, None] * v[:, :2]
    margin = np.abs(np.abs(cross) - 0.3).min(axis=1)
    shadow = np.all(np.abs(cross) < 0.3, axis=1)
    return np.where(shadow, 0.0, H), margin


def test_bake_points_get_the_exact_shadow_edge(shadowed_plane):
    # Only the plane receives and nothing reflects back onto it: the radiance at any point is
    # exactly rho x direct / pi, however sharp the shadow. The patches alone blur the edge.
    problem, lamp, state = shadowed_plane
    rng = np.random.default_rng(5)
    pts = np.zeros((3000, 3))
    pts[:, :2] = rng.uniform(-1.0, 1.0, size=(3000, 2))
    exact, margin = closed_form_direct(pts, np.array(lamp.position), lamp.power)
    pts, exact = pts[margin > 1e-6], exact[margin > 1e-6]
    tri = problem.index.rays.closest_hit(pts + [0, 0, 1e-3], np.tile([0, 0, -1.0], (len(pts), 1)), 1.0)[1]
    light = direct_light(problem, (lamp,), SolveSettings())
    sharp = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)[:, 0]
    np.testing.assert_allclose(sharp, RHO * exact / np.pi, rtol=1e-9, atol=1e-12)
    H = (
        np.pi
        * irradiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)[:, 0]
    )
    np.testing.assert_allclose(H, exact, rtol=1e-9, atol=1e-12)
    blurred = radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1)[:, 0]
    near_edge = margin[margin > 1e-6] < 0.05
    assert np.abs(blurred - RHO * exact / np.pi)[near_edge].max() > 0.1 * (RHO * exact / np.pi).max()


def test_split_keeps_the_furnace_exact():
    # A closed cube with uniform emission: large emitters stay in the patch solution (no split),
    # so the reconstruction with the split arguments equals L_e / (1 - rho).
    s = scenes.cube(inward=True)
    s = Surfaces.from_arrays(s.vertices, s.triangles, reflectance=[0.5] * 3, emission=[1.0, 1.0, 1.0])
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=300)))
    state = solve(problem)
    light = direct_light(problem, (), SolveSettings())
    assert not np.any(light.emitters)
    pts, tri = scenes.sample_surface(s, 2000, seed=1)
    L = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
    np.testing.assert_allclose(L, analytic.furnace_radiance(1.0, 0.5), rtol=1e-3)


def test_triangle_normals_are_unit_and_zero_for_degenerate_triangles():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 0], [2, 0, 0]], float)
    s = Surfaces.from_arrays(v, [[0, 1, 2], [0, 1, 3]])
    np.testing.assert_allclose(triangle_normals(s, np.array([0, 1])), [[0, 0, 1], [0, 0, 0]])


def test_only_emitters_with_patches_are_shot():
    # An emitter without an atlas (a pure occluder) gives no light: the operators warn about it.
    s, _ = _emitter_over_plane(False)
    for receiver, expected in (([True, True], 2), ([False, True], 0)):
        t = Surfaces.from_arrays(
            s.vertices, s.triangles, s.object_index, emission=s.emission, receiver=receiver
        )
        atlas = build_atlas(t, AtlasSettings(patch_count=100))
        problem = prepare(t, atlas, SolveSettings(rays_per_point=4))
        assert int(direct_light(problem).emitters.sum()) == expected


def test_an_emitter_of_more_triangles_than_samples_is_cut_from_its_light_tree():
    # A 1 m square emitter as 800 triangles, 0.5 m above the points: with 16 to 256 samples its
    # light tree's cut of that many nodes of equal power gives one sample each (a few points within
    # reach of a node walk its subtree); with 1 024 every triangle gets its own point.
    pv, pt = scenes.plane(size=1.0, n=20, z=0.5)
    s = Surfaces.from_arrays(pv - [0.5, 0.5, 0.0], pt, emission=[1.0, 1.0, 1.0])
    rect = np.array([[-0.5, -0.5, 0.5], [0.5, -0.5, 0.5], [0.5, 0.5, 0.5], [-0.5, 0.5, 0.5]])
    rng = np.random.default_rng(3)
    pts = np.zeros((200, 3))
    pts[:, :2] = rng.uniform(-1.2, 1.2, size=(200, 2))
    nrm = np.tile([0.0, 0.0, 1.0], (200, 1))
    exact = np.pi * analytic.ff_point_to_polygon(pts, nrm, rect)
    rays = make_rays(s.vertices, s.triangles)
    # measured worst point: 4.3 %, 2.1 %, 0.83 %, 0.12 % (picked triangle centroids gave 30 %, 6.8 %,
    # 1.3 %); the total within 0.3 %
    for samples, worst in ((16, 0.06), (64, 0.03), (256, 0.012), (1024, 2e-3)):
        H, cast = emitter_irradiance(s, rays, np.ones(len(pt), bool), pts, nrm, samples)
        assert 200 * min(samples, len(pt)) <= cast < 2 * 200 * min(samples, len(pt))
        assert np.abs(H[:, 0] / exact - 1.0).max() < worst
        assert abs(H[:, 0].sum() / exact.sum() - 1.0) < 3e-3


def test_the_first_shots_budget_keeps_picked_emitter_samples():
    """Under a binding shadow-ray budget the first shot takes fewer samples per point, but not
    for emitters whose samples are picked on power (more triangles than samples): fewer picks
    stand farther apart and widen the light tree's near field, which casts the rays back."""
    panel = {}
    for n in (1, 20):  # 2 triangles (each gets its own samples), 800 triangles (picked)
        pv, pt = scenes.plane(size=1.0, n=n, z=0.5)
        panel[n] = Surfaces.from_arrays(pv, pt, emission=[1.0, 1.0, 1.0])
    light = DirectLight(emitters=np.ones(len(panel[20].triangles), bool))
    assert direct.picked(panel[20], light.emitters, 16) and not direct.picked(panel[20], light.emitters, 1024)
    assert emitter_sample_count(panel[20], light, 16, 4) == 16
    assert emitter_sample_count(panel[1], replace(light, emitters=np.ones(2, bool)), 16, 4) == 4
    assert emitter_sample_count(panel[20], replace(light, emitters=None), 16, 4) == 4
    assert emitter_sample_count(panel[20], light, 16, 16) == 16


@pytest.mark.parametrize("cuts, want", [(1, 8), (20, 16)])  # a quad: 2 triangles; 800 (picked)
def test_a_gathers_near_hits_keep_16_picked_emitter_samples(cuts, want, monkeypatch):
    """Near gather hits take 8 emitter samples (bake.gather.NEAR_LIGHT_SAMPLES), but 16 of an emitter
    of many triangles, whose samples are picked on power (bake.gather.NEAR_PICKED_SAMPLES)."""
    ev, et = scenes.plane(size=1.0, n=cuts, z=0.5)
    fv, ft = scenes.plane(size=3.0, n=2)
    v = np.vstack([ev[:, [0, 1, 2]] - [0.5, 0.5, 0.0], fv - [1.5, 1.5, 0.0]])
    t = np.vstack([et[:, ::-1], ft + len(ev)])  # the panel faces down, the floor up
    emission = np.zeros((len(t), 3))
    emission[: len(et)] = 4.0
    s = Surfaces.from_arrays(v, t, reflectance=[0.5] * 3, emission=emission)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=300)))
    state = solve(problem)
    seen = []
    original = points.NearField

    def recording(light, *args, **kwargs):
        seen.append(light)
        return original(light, *args, **kwargs)

    monkeypatch.setattr(points, "NearField", recording)
    pts, tri = scenes.sample_surface(s, 50, seed=2)
    floor = tri >= len(et)
    light = direct_light(problem, (), SolveSettings())
    radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts[floor], tri[floor], 1)
    assert len(seen) == 1 and seen[0].samples == 8
    assert (seen[0].emitter_samples or seen[0].samples) == want


@pytest.mark.parametrize("side", [1, -1])
def test_points_close_to_an_emitter_of_more_triangles_than_samples_get_its_exact_light(side, monkeypatch):
    """The same 800-triangle square, points 1 mm to 5 cm off it on either side (its back emits
    too), under its interior: the 64 samples picked on power stand 12.5 cm apart, so alone they
    are singular there; the triangles within two spacings give their exact light instead."""
    pv, pt = scenes.plane(size=1.0, n=20, z=0.5)
    s = Surfaces.from_arrays(pv - [0.5, 0.5, 0.0], pt, emission=[1.0, 1.0, 1.0])
    rect = np.array([[-0.5, -0.5, 0.5], [0.5, -0.5, 0.5], [0.5, 0.5, 0.5], [-0.5, 0.5, 0.5]])
    rays = make_rays(s.vertices, s.triangles)
    rng = np.random.default_rng(5)
    pts = np.zeros((200, 3))
    pts[:, :2] = rng.uniform(-0.45, 0.45, size=(200, 2))
    nrm = np.tile([0.0, 0.0, side], (200, 1))
    worst = {}
    for near in (direct.NEAR_EMITTER, 0.0):
        near_emitter(monkeypatch, near)
        for h in (1e-3, 1e-2, 5e-2):
            pts[:, 2] = 0.5 - side * h
            exact = np.pi * analytic.ff_point_to_polygon(pts, nrm, rect)
            H, _ = emitter_irradiance(s, rays, np.ones(len(pt), bool), pts, nrm, 64)
            worst[near, h] = np.abs(H[:, 0] / exact - 1.0).max()
    # measured: at most 0.03 % at 1 cm and 0.7 % at 5 cm; the samples alone: 50 % at 1 cm and
    # 280 % at 5 cm (a point right under a sample)
    assert max(v for (near, _), v in worst.items() if near > 0) < 0.015
    assert worst[0.0, 1e-2] > 0.3 and worst[0.0, 5e-2] > 1.0
    # the near points go in blocks (memory): any block size gives the same light
    near_emitter(monkeypatch, 2.0)
    whole, _ = emitter_irradiance(s, rays, np.ones(len(pt), bool), pts, nrm, 64)
    monkeypatch.setattr(near_field, "NEAR_POINTS", 7)
    blocks, _ = emitter_irradiance(s, rays, np.ones(len(pt), bool), pts, nrm, 64)
    np.testing.assert_allclose(blocks, whole, rtol=1e-12, atol=0)


@pytest.fixture(scope="module")
def half_shadowed_floor():
    """A 4 m floor at z = 0 and a pure occluder over its half x < 0 at z = 1."""
    pv, pt = scenes.plane(size=4.0, n=4)
    occ_v, occ_t = scenes.quad([-3.0, -3.0, 1.0], [0.0, -3.0, 1.0], [0.0, 3.0, 1.0], [-3.0, 3.0, 1.0])
    v = np.vstack([pv - [2.0, 2.0, 0.0], occ_v])
    t = np.vstack([pt, occ_t + len(pv)])
    return make_rays(v, t), float(np.ptp(v, axis=0).max())


SOFT = {
    # sphere of radius 0.3 at height 2 over the occluder's edge: penumbra about 0.3 m each side
    "sphere": (Lamp("POINT", position=(0.0, 0.0, 2.0), power=400.0, radius=0.3), 0.45),
    # sun straight down, 10 degrees wide: penumbra tan(5 deg) x 1 m = 0.09 m each side
    "sun disk": (Lamp("SUN", direction=(0.0, 0.0, -1.0), power=3.0, angle=np.radians(10.0)), 0.15),
}


@pytest.mark.parametrize("name", sorted(SOFT))
def test_soft_shadow_of_a_half_plane(half_shadowed_floor, name):
    """Under the occluder's edge, directly below the source's centre, exactly half of the source
    is hidden (the vertical plane through the edge halves it and its cosine weights): half the
    closed-form irradiance. Beyond the penumbra, full light or none; across it, light grows."""
    rays, extent = half_shadowed_floor
    lamp, reach = SOFT[name]
    x = np.linspace(-1.0, 1.0, 401)
    pts = np.stack([x, np.zeros_like(x), np.zeros_like(x)], 1)
    up = np.tile([0.0, 0.0, 1.0], (len(x), 1))
    if lamp.kind == "SUN":
        full = np.full(len(x), lamp.power)
    else:
        full = analytic.point_lamp_irradiance(lamp.power, lamp.position, pts, up)
    H = lamp_irradiance((lamp,), pts, up, rays, extent, samples=64)[0][:, 0]
    below = np.flatnonzero(x == 0.0)
    np.testing.assert_allclose(H[below], 0.5 * full[below], rtol=1e-9)
    np.testing.assert_allclose(H[x > reach], full[x > reach], rtol=1e-9)
    assert np.all(H[x < -reach] == 0.0)
    pen = np.abs(x) < reach
    assert np.all(np.diff(H[pen] / full[pen]) >= -0.05)  # up to the 64-sample quadrature's steps
    assert (0.0 < H[pen] / full[pen]).sum() > 10 and (H[pen] / full[pen] < 1.0).sum() > 10  # soft, not hard


@pytest.mark.parametrize("height", [1e-3, 1e-2, 5e-2])
def test_emitter_irradiance_close_over_an_emitter(height):
    """Points just over the back of the emitter, facing it (a ceiling over a lamp quad): its 64
    samples are 10 cm apart, a midpoint rule there is singular (near nothing between the samples,
    thousands right over one), so those points take the exact form factor of the triangles near them."""
    s, rect = _emitter_over_plane(False)
    rng = np.random.default_rng(7)
    xy = rng.uniform([-0.5, -0.4], [0.5, 0.4], (300, 2))
    pts = np.column_stack([xy, np.full(300, 0.5 + height)])
    nrm = np.tile([0.0, 0.0, -1.0], (300, 1))
    rays = make_rays(s.vertices, s.triangles)
    H, _ = emitter_irradiance(s, rays, s.emission.sum(1) > 0, pts, nrm, 64)
    exact = np.pi * analytic.ff_point_to_polygon(pts, nrm, rect)[:, None] * [2.0, 1.0, 0.5]
    # measured 1e-6 / 1e-4 / 0.19 % at 1 mm / 1 cm / 5 cm: what is farther than NEAR_EMITTER
    # spacings from a point still comes from the samples
    np.testing.assert_allclose(H, exact, rtol=3e-3)


def test_midpoint_rule_alone_fails_close_over_an_emitter(monkeypatch):
    """The same points 1 cm over the emitter with the near-field form factor switched off: the fixed
    rule alone is off by far more than the test above allows (measured: up to 96 %)."""
    near_emitter(monkeypatch, 0.0)
    s, rect = _emitter_over_plane(False)
    xy = np.random.default_rng(7).uniform([-0.5, -0.4], [0.5, 0.4], (300, 2))
    pts = np.column_stack([xy, np.full(300, 0.51)])
    nrm = np.tile([0.0, 0.0, -1.0], (300, 1))
    H, _ = emitter_irradiance(s, make_rays(s.vertices, s.triangles), s.emission.sum(1) > 0, pts, nrm, 64)
    exact = np.pi * analytic.ff_point_to_polygon(pts, nrm, rect)[:, None] * [2.0, 1.0, 0.5]
    assert np.abs(H / exact - 1).max() > 0.3


def test_polygon_irradiance_clips_to_the_points_hemisphere():
    """Against a quadrature of the triangle (600^2 sub-triangles), cos clipped at 0 on the
    receiver's side: points around a unit triangle with normals at random, many crossing its plane."""
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.2, 0.9, 0.0]])
    rng = np.random.default_rng(11)
    k = 40
    pts = rng.uniform([-0.3, -0.3, 0.2], [1.2, 1.1, 0.6], (k, 3))
    pts[:, 2] *= rng.choice([-1.0, 1.0], k)  # above and below the triangle
    nrm = rng.normal(size=(k, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    got = polygon_irradiance(pts, nrm, np.repeat(tri[None], k, axis=0))
    uv = subtriangle_centroids(600)
    q = tri[0] + uv[:, :1] * (tri[1] - tri[0]) + uv[:, 1:] * (tri[2] - tri[0])
    area = 0.5 * np.linalg.norm(np.cross(tri[1] - tri[0], tri[2] - tri[0])) / len(q)
    want = np.empty(k)
    for i in range(k):
        v = q - pts[i]
        d2 = np.einsum("sj,sj->s", v, v)
        cos_r = np.maximum(v @ nrm[i], 0.0) / np.sqrt(d2)
        want[i] = np.sum(cos_r * np.abs(v[:, 2]) / np.sqrt(d2) / d2) * area
    assert np.any(want == 0) or np.any((want > 0) & (want < 0.9 * np.max(want)))
    np.testing.assert_allclose(got, want, rtol=2e-4, atol=1e-6)


def test_a_lamp_quad_just_under_a_ceiling_does_not_ring():
    """A closed 2 m room lit only by a black 0.5 m lamp quad 1 cm under its ceiling (as the
    production room's): the ceiling over the quad gets its back face's light, and the first
    shot's projection onto the patches stays a light distribution, not a ringing one (with the
    fixed rule alone, spikes over its samples drove patches to large negative radiosity)."""
    v, t, o = scenes.merge(
        scenes.box_faces((0, 0, 0), (2, 2, 2), inward=True)
        + [scenes.quad((0.75, 0.75, 1.99), (0.75, 1.25, 1.99), (1.25, 1.25, 1.99), (1.25, 0.75, 1.99))],
        obj=[0] * 6 + [1],
    )
    emission = np.where(o[:, None] == 1, [10.0, 10.0, 10.0], 0.0)
    rho = np.where(o[:, None] == 1, 0.0, 0.7) * np.ones((1, 3))
    s = Surfaces.from_arrays(v, t, o, rho, emission, object_names=["room", "lamp"])
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=300)))
    state = solve(problem, (), SolveSettings())
    room = problem.atlas.source_object == 0
    B = state.radiosity[room, 0]
    # measured -0.054 x (the sharp edge of the light on the ceiling, projected); -0.40 x with the
    # fixed rule alone
    assert B.min() > -0.1 * B.max()
    light = direct_light(problem, (), SolveSettings())
    over = np.array([[1.0, 1.0, 2.0 - 1e-4]])
    H, _ = direct.direct_irradiance(s, problem.index.rays, light, over, np.array([[0.0, 0.0, -1.0]]))
    quad = np.array([[0.75, 0.75, 1.99], [0.75, 1.25, 1.99], [1.25, 1.25, 1.99], [1.25, 0.75, 1.99]])
    exact = np.pi * analytic.ff_point_to_polygon(over, np.array([[0.0, 0.0, -1.0]]), quad) * 10.0
    np.testing.assert_allclose(H[:, 0], exact, rtol=1e-4)


def _blob(rng: np.random.Generator, bend: float) -> np.ndarray:
    """(m, 3, 3) a random subset of a unit square's 8 x 8 x 2 grid triangles, bent by up to `bend`
    x^2 out of its plane, turned at random."""
    pv, pt = scenes.plane(size=1.0, n=8)
    tris = (pv - [0.5, 0.5, 0.0])[pt[rng.random(len(pt)) < rng.uniform(0.3, 1.0)]]
    tris[..., 2] += rng.uniform(0.0, bend) * tris[..., 0] ** 2
    turn, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return tris @ turn.T


@pytest.mark.parametrize("bend", [0.0, 0.1])
def test_a_far_node_of_the_light_tree_is_its_contour_integral(bend, monkeypatch):
    """Beyond NEAR_EXACT x its radius (wholly above the point's horizon, seen from one side) a node
    of emitting triangles gives its light as one point corrected to second order for its extent (its
    second moment of area, tree.second_order): random blobs of grid triangles, flat or bent (up to
    6 degrees between normals), at NEAR_EXACT to 1.5 NEAR_EXACT radii from random points whose
    horizon they lie over, against the sum of Lambert's contour integral over their triangles (the
    reference's analytic.ff_point_to_polygon). Errors in units of the blob's area over distance
    squared (its light face-on), as edge-on blobs, whose light is faint, would make relative errors
    meaningless."""
    from ovrad_addon.scene.surfaces import triangle_geometry

    near_emitter(monkeypatch, 1e3)  # every triangle near: the tree alone
    rng = np.random.default_rng(11)
    err, one_point = [], []
    for _ in range(60):
        tris = _blob(rng, bend)
        area, normal = triangle_geometry(tris)
        centre = (tris.mean(axis=1) * area[:, None]).sum(axis=0) / area.sum()
        radius = np.linalg.norm(tris - centre, axis=2).max()
        s = Surfaces.from_arrays(
            tris.reshape(-1, 3), np.arange(tris.size // 3).reshape(-1, 3), emission=[1.0] * 3
        )
        toward = rng.normal(size=(40, 3))
        toward /= np.linalg.norm(toward, axis=1, keepdims=True)
        dist = radius * rng.uniform(near_field.NEAR_EXACT * 1.01, near_field.NEAR_EXACT * 1.5, 40)
        pts = centre - dist[:, None] * toward
        nrm = rng.normal(size=(40, 3))
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm *= np.where(np.einsum("ij,ij->i", nrm, toward) < 0, -1.0, 1.0)[:, None]
        above = np.einsum("kcj,pj->pkc", tris, nrm).min(axis=(1, 2)) > np.einsum("pj,pj->p", pts, nrm)
        pts, nrm, dist = pts[above], nrm[above], dist[above]
        rays = make_rays(s.vertices, s.triangles)
        H, _ = emitter_irradiance(s, rays, np.ones(len(tris), bool), pts, nrm, 4)
        exact = np.pi * sum(analytic.ff_point_to_polygon(pts, nrm, t) for t in tris)
        scale = area.sum() / dist**2
        err.append((H[:, 0] - exact) / scale)
        # the one-point rule alone: the area-weighted normals (turned to one side) at the centroid
        turned = normal * np.where(normal @ normal[np.argmax(area)] < 0, -1.0, 1.0)[:, None]
        u = centre - pts
        rule = np.einsum("pj,pj->p", u, nrm) * np.abs(u @ (area[:, None] * turned).sum(axis=0)) / dist**4
        one_point.append((rule - exact) / scale)
    err, one_point = np.abs(np.concatenate(err)), np.abs(np.concatenate(one_point))
    assert len(err) > 1500
    # measured, flat: 0.014 % on average, 0.07 % at the 99th percentile (the one-point rule alone:
    # 0.47 %, 2.1 %); bent: 0.11 %, 0.5 % (0.50 %, 2.2 %)
    mean, p99 = (0.0005, 0.002) if bend == 0 else (0.003, 0.01)
    assert err.mean() < mean and np.percentile(err, 99) < p99
    assert np.percentile(one_point, 99) > 4 * np.percentile(err, 99)


def _convex_light(corners, pts, nrm) -> np.ndarray:
    """The unoccluded irradiance (m,) at points (m, 3) with normals (m, 3) from a convex polyhedron
    of unit radiance (its faces (T, 3, 3) wound outwards): the sum of Lambert's contour integral over
    the faces each point sees (it is on their outer side; the inner sides of the others are hidden)."""
    outward = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    exact = np.zeros(len(pts))
    for k in range(len(pts)):
        sees = np.einsum("ij,ij->i", pts[k] - corners[:, 0], outward) > 0
        at = np.tile(pts[k], (sees.sum(), 1))
        exact[k] = polygon_irradiance(at, np.tile(nrm[k], (sees.sum(), 1)), corners[sees]).sum()
    return exact


@pytest.mark.parametrize("distance", [1.05, 1.3, 2.0, 12.0])
def test_the_light_tree_gives_a_glowing_sphere_its_exact_light(distance, monkeypatch):
    """A glowing icosphere (1 280 triangles, 64 samples picked on power) seen from outside, every
    triangle made near (the light tree alone): against the sum of Lambert's contour integral over
    the faces the point sees (the polyhedron is convex: a face is seen iff the point is on its outer
    side; the inner sides of the others are hidden). Its nodes are curved: a node's centroid lies
    inside the sphere, and a node holding faces of both sides (the whole sphere, seen from 12 radii
    away) must be opened, not taken as one point."""
    s = scenes.sphere(1.0, 3)
    s = Surfaces.from_arrays(s.vertices, s.triangles, emission=[1.5, 1.0, 0.5])
    rays = make_rays(s.vertices, s.triangles)
    rng = np.random.default_rng(7)
    toward = rng.normal(size=(150, 3))
    toward /= np.linalg.norm(toward, axis=1, keepdims=True)
    pts = distance * toward
    nrm = -toward + 0.4 * rng.normal(size=(150, 3))  # tilted: the sphere crosses some horizons
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    c = s.corners
    exact = _convex_light(c, pts, nrm)
    near_emitter(monkeypatch, 100.0)
    H, _ = emitter_irradiance(s, rays, np.ones(len(c), bool), pts, nrm, 64)
    np.testing.assert_allclose(H / [1.5, 1.0, 0.5], np.repeat(H[:, :1] / 1.5, 3, axis=1), rtol=1e-9)
    # measured: at most 0.3 % of the brightest point's light, the total within 0.09 %
    rel = np.abs(H[:, 0] / 1.5 - exact) / exact.max()
    assert rel.max() < 0.005
    assert abs(H[:, 0].sum() / 1.5 / exact.sum() - 1.0) < 0.002


def test_point_hash_depends_on_the_point_only_and_spreads_over_the_unit_square():
    rng = np.random.default_rng(3)
    pts = rng.uniform(-5.0, 5.0, (20_000, 3))
    h = lights.point_hash(pts)
    assert h.shape == (20_000, 2) and np.all((h >= 0.0) & (h < 1.0))
    np.testing.assert_array_equal(lights.point_hash(pts[::-1]), h[::-1])  # order and chunking do not matter
    counts = np.histogram2d(h[:, 0], h[:, 1], bins=4, range=[[0, 1], [0, 1]])[0]
    assert counts.min() > 0.85 * len(pts) / 16 and counts.max() < 1.15 * len(pts) / 16
    # neighbouring points (a gather's hits a hair apart) get unrelated offsets
    near = lights.point_hash(pts[:1] + np.array([[0.0, 0.0, 1e-9]]))
    assert np.all(np.abs(near - h[:1]) > 1e-3)


def test_a_jittered_area_lamp_rule_averages_to_the_exact_penumbra(half_shadowed_floor):
    """3 x 3 points of a 0.6 m square lamp at z = 2, over an occluder edge at z = 1: a floor point at
    x0 sees the lamp's part x > -x0 (a rectangle: its closed form). The fixed rule puts every
    point on the same step of it; jittered per point (light.lamps.jittered_area_samples) the steps fall
    elsewhere at each point, and the mean over many points is the closed form."""
    rays, extent = half_shadowed_floor
    lamp = Lamp("AREA", position=(0.0, 0.0, 2.0), power=300.0, size_x=0.6, size_y=0.6)
    x0 = 0.05
    y = np.linspace(-0.2, 0.2, 4001)
    pts = np.stack([np.full_like(y, x0), y, np.zeros_like(y)], 1)
    up = np.tile([0.0, 0.0, 1.0], (len(y), 1))
    width = 0.3 + x0  # the visible part: x in [-x0, 0.3], radiance unchanged
    exact = analytic.area_lamp_rect_irradiance(
        300.0 * width / 0.6, width, 0.6, (0.3 - width / 2, 0, 2), pts, up
    )
    jittered = lamp_irradiance((lamp,), pts, up, rays, extent, samples=8, jittered=True)[0][:, 0]
    fixed = lamp_irradiance((lamp,), pts, up, rays, extent, samples=2)[0][:, 0]  # area_side(2): 3 x 3
    assert lights.jittered_area_side(8) == 3 and lights.area_side(2) == 3
    assert np.ptp(jittered / exact) > 0.1  # each point on a step of its own
    assert abs(jittered.mean() / exact.mean() - 1.0) < 0.01
    assert abs(fixed.mean() / exact.mean() - 1.0) > 0.05  # every point on the same step
    # Unshadowed, each point's estimate is a stratified Monte Carlo one of the whole lamp: 1.5 m
    # aside, its integrand (cos cos / d^2) falls by about 30 % across the lamp, so about 10 % across
    # a stratum; a uniform jitter there spreads a stratum's value by 10 / sqrt(3) % and the mean of
    # 9 independent strata by about 2 %: within 8 % (4 sigma) at every point, unbiased on average.
    far = pts + [1.5, 0.0, 0.0]
    full = analytic.area_lamp_rect_irradiance(300.0, 0.6, 0.6, (0, 0, 2), far, up)
    got = lamp_irradiance((lamp,), far, up, rays, extent, 8, jittered=True)[0][:, 0]
    rel = got / full - 1.0
    assert np.abs(rel).max() < 0.08 and np.sqrt(np.mean(rel**2)) < 0.03
    assert abs(got.mean() / full.mean() - 1.0) < 0.002


@pytest.mark.parametrize("samples", [16, 64])
def test_a_glowing_spheres_far_light_comes_from_its_light_trees_cut(samples):
    """A glowing icosphere (1 280 triangles) seen from 3 to 15 radii away, beyond its cut nodes'
    reach: each cut node is one sample with its power vector and the spread of its normals
    (emitters.front_cosine), against the sum of Lambert's contour integral over the faces each point
    sees. Triangle centroids picked on power (the rule before the cut) measured 67 % RMS with 16
    samples and 73 % with 64 here (the picks fall in clusters along this mesh's triangle order), and
    4.6 % with 64 on a UV sphere; the cut keeps its normals within 26 degrees of their axis whatever
    was asked (56 shadow rays a point where 16 samples are asked)."""
    s = scenes.sphere(1.0, 3)
    s = Surfaces.from_arrays(s.vertices, s.triangles, emission=[1.0, 1.0, 1.0])
    rays = make_rays(s.vertices, s.triangles)
    src, cut = direct.EmitterRules(s).rule(np.ones(len(s.triangles), bool), samples, 1.0)
    assert cut is not None and samples <= len(src.area) <= tree.CUT_MOST * samples
    rng = np.random.default_rng(17)
    toward = rng.normal(size=(300, 3))
    toward /= np.linalg.norm(toward, axis=1, keepdims=True)
    pts = rng.uniform(3.0, 15.0, (300, 1)) * toward
    nrm = -toward
    c = s.corners
    exact = _convex_light(c, pts, nrm)
    H, cast = emitter_irradiance(s, rays, np.ones(len(c), bool), pts, nrm, samples)
    assert cast < 2 * len(pts) * len(src.area)  # the cut's samples, hardly any near field
    ratio = H[:, 0] / exact
    # measured: 1.3 / 1.0 % RMS, 3.1 / 2.7 % at worst (16 / 64 samples)
    assert np.sqrt(np.mean((ratio - 1.0) ** 2)) < 0.02
    assert np.abs(ratio - 1.0).max() < 0.05


def test_a_triangle_sends_no_light_to_points_on_itself():
    """A point on an emitting triangle (a bake point of a glowing mesh that also reflects: a
    Principled emitter) lies in its plane: the triangle sends it nothing. With the corners' heights
    over the point's plane left at the rounding error's +4e-17, the triangle read as wholly above
    it, the point inside its contour, and gave it the light of a whole hemisphere (pi): a UV
    sphere's bake points 35 % brighter than their emission."""
    rng = np.random.default_rng(23)
    corners = rng.uniform(-1.0, 1.0, (2000, 3, 3)) * [1.0, 1.0, 0.3] + [0.4, 2.0, 0.7]
    corners = corners.astype(np.float32).astype(np.float64)
    w = rng.dirichlet([1.0, 1.0, 1.0], 2000)
    pts = np.einsum("kc,kcj->kj", w, corners)
    nrm = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    for side in (1.0, -1.0):
        got = polygon_irradiance(pts, side * nrm, corners)
        assert np.all(got < 1e-9), (got > 1e-9).sum()
