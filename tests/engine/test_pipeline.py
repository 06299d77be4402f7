"""The whole engine solve (prepare -> solve -> reconstruct) against closed forms: lamps on a plane,
the furnace, and scale invariance of the Cornell box."""

from dataclasses import replace

import numpy as np
import pytest
from reference import analytic

import scenes
from ovrad_addon.bake.lattice import may_see_sky
from ovrad_addon.bake.points import BakeRequest, irradiance_at, radiance_at
from ovrad_addon.errors import OvradError
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.light.direct import direct_irradiance, triangle_normals
from ovrad_addon.light.lamps import Lamp, lamp_irradiance
from ovrad_addon.light.sky import Sky
from ovrad_addon.overlap.queries import alpha_at
from ovrad_addon.radiosity import first_shot, transport
from ovrad_addon.radiosity.emission import SKY_SHARE, patch_emission, sky_patches
from ovrad_addon.radiosity.first_shot import direct_light, solve
from ovrad_addon.radiosity.problem import prepare
from ovrad_addon.radiosity.transport import SKY_TEST_RAYS
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, SolveSettings

RHO = 0.8


@pytest.fixture(scope="module")
def lit_plane():
    """A 4 m x 4 m plane (rho 0.8, nothing else in the scene) with its prepared problem."""
    v, t = scenes.plane(size=4.0, n=4)
    s = Surfaces.from_arrays(v - [2.0, 2.0, 0.0], t, reflectance=[RHO] * 3)
    atlas = build_atlas(s, AtlasSettings(patch_count=1600))
    return s, prepare(s, atlas)


def central_points(count=400, half=1.2, seed=2):
    rng = np.random.default_rng(seed)
    p = np.zeros((count, 3))
    p[:, :2] = rng.uniform(-half, half, size=(count, 2))
    return p


def irradiance(problem, lamp, points):
    state = solve(problem, lamps=(lamp,))
    tri = problem.index.rays.closest_hit(points + [0, 0, 1e-3], np.tile([0, 0, -1.0], (len(points), 1)), 1.0)[
        1
    ]
    return np.pi * irradiance_at(problem, BakeRequest(state.radiosity), points, tri, 1)[:, 0], state


up = np.tile([0.0, 0.0, 1.0], (400, 1))
LAMPS = {
    "point": (
        Lamp("POINT", position=(0.3, -0.2, 1.0), power=500.0),
        lambda p: analytic.point_lamp_irradiance(500.0, (0.3, -0.2, 1.0), p, up),
    ),
    "spot": (
        Lamp(
            "SPOT",
            position=(0, 0, 1.5),
            direction=(0, 0, -1),
            power=800.0,
            spot_size=np.radians(120),
            spot_blend=1.0,
        ),
        lambda p: analytic.spot_lamp_irradiance(800.0, np.radians(120), 1.0, (0, 0, 1.5), (0, 0, -1), p, up),
    ),
    "sun": (
        Lamp("SUN", direction=(0.3, 0.1, -1.0), power=3.0),
        lambda p: analytic.sun_irradiance(3.0, -np.array([0.3, 0.1, -1.0]), up),
    ),
    "area": (
        Lamp(
            "AREA",
            position=(0, 0, 0.8),
            direction=(0, 0, -1),
            power=300.0,
            shape="RECTANGLE",
            size_x=0.6,
            size_y=0.4,
        ),
        lambda p: analytic.area_lamp_rect_irradiance(300.0, 0.6, 0.4, (0, 0, 0.8), p, up),
    ),
}


# Sources with a size: a sphere above the horizon lights a plane exactly as a point lamp of the
# same power, and a sun disk as a sun; only their shadows are soft (test_direct.py).
for _kind, _size in (("point", dict(radius=0.25)), ("spot", dict(radius=0.3)), ("sun", dict(angle=0.17))):
    LAMPS[f"{_kind} with a size"] = (replace(LAMPS[_kind][0], **_size), LAMPS[_kind][1])


@pytest.mark.parametrize("kind", sorted(LAMPS))
def test_lamp_model_matches_closed_form_irradiance(lit_plane, kind):
    s, problem = lit_plane
    lamp, exact = LAMPS[kind]
    pts = central_points()
    H, _ = lamp_irradiance((lamp,), pts, up, problem.index.rays, s.extent)
    # point, spot, sun (with or without a size) are exact; the area lamp's 8 x 8 stratified
    # samples are within 0.2 %
    np.testing.assert_allclose(H[:, 0], exact(pts), rtol=2e-3, atol=1e-12)


@pytest.mark.parametrize("budget", ["default", "tight"])
@pytest.mark.parametrize("kind", sorted(LAMPS))
def test_every_lamp_lights_a_plane_as_its_closed_form(lit_plane, kind, budget, monkeypatch):
    s, problem = lit_plane
    lamp, exact = LAMPS[kind]
    pts = central_points()
    if budget == "tight":
        # a shadow-ray budget of 4 200 rays for 51 200 receiver points: lamps take fewer samples
        # at every point (not fewer points: first_shot.first_shot_points)
        monkeypatch.setattr(first_shot, "SHADOW_BUDGET", 5e-4)
    got, state = irradiance(problem, lamp, pts)
    want = exact(pts)
    # Baked light is a blend of patch averages (patches about 0.1 m here): measured 1.6-2.6 %
    # RMS for lamps 0.8-1.5 m above the plane, exact for the uniform sun; the tight budget is held
    # to the same bound.
    assert np.sqrt(np.mean((got - want) ** 2)) / np.sqrt(np.mean(want**2)) < 0.03
    # a lone plane reflects to nowhere: radiance is rho/pi times irradiance, no more
    L = radiance_at(problem, BakeRequest(state.radiosity), pts, np.zeros(len(pts), int), 1)[:, 0]
    np.testing.assert_allclose(L, RHO * got / np.pi, rtol=1e-9)


@pytest.fixture(params=["embree", "numpy"])
def backend(request):
    """Each ray backend (scene/rays.py) in turn; one that is not installed fails with its ImportError."""
    return request.param


def test_furnace_through_the_pipeline(backend):
    base = scenes.cube(inward=True)
    s = Surfaces.from_arrays(base.vertices, base.triangles, reflectance=[0.9] * 3, emission=[2.0] * 3)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=300), backend=backend), backend=backend)
    assert problem.index.rays.name == backend
    state = solve(problem, settings=SolveSettings(tolerance=1e-5))
    pts, tri = scenes.sample_surface(s, 5000, seed=4)
    L = radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1)
    np.testing.assert_allclose(L, 2.0 / (1 - 0.9), rtol=5e-3)


def test_patch_emission_is_computed_once_and_follows_new_surfaces():
    base = scenes.cube(inward=True)
    s = Surfaces.from_arrays(base.vertices, base.triangles, reflectance=[0.5] * 3, emission=[2.0] * 3)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=100)))
    E = patch_emission(problem)
    assert patch_emission(problem) is E and not E.flags.writeable  # kept, and not to be changed
    np.testing.assert_allclose(E, 2.0 * np.pi, rtol=1e-9)  # uniform radiance 2: exitance 2 pi
    np.testing.assert_allclose(patch_emission(problem, 0.5), np.pi, rtol=1e-9)
    # the same problem with brighter surfaces (an operator reuses form factors so): not the old values
    brighter = Surfaces.from_arrays(base.vertices, base.triangles, reflectance=[0.5] * 3, emission=[3.0] * 3)
    np.testing.assert_allclose(patch_emission(replace(problem, surfaces=brighter)), 3.0 * np.pi, rtol=1e-9)
    assert patch_emission(problem) is E


def test_cornell_box_radiance_is_independent_of_scale():
    base = scenes.cornell()
    out = []
    # powers of two, as in test_atlas_is_unchanged_by_scene_scale: atlases are rounded to float32
    for scale in (2.0**-10, 1.0, 2.0**10):
        s = Surfaces.from_arrays(
            base.vertices * scale,
            base.triangles,
            base.object_index,
            base.reflectance,
            base.emission,
            base.object_names,
        )
        problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=400)))
        state = solve(problem)
        pts, tri = scenes.sample_surface(base, 3000, seed=6)
        out.append(radiance_at(problem, BakeRequest(state.radiosity), pts * scale, tri, 1))
    # radiance is scale-free: same emitted radiance, same geometry up to scale
    np.testing.assert_allclose(out[0], out[1], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(out[2], out[1], rtol=1e-6, atol=1e-9)


def test_scene_without_light_is_refused(backend):
    v, t = scenes.plane()
    s = Surfaces.from_arrays(v, t)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=50), backend=backend), backend=backend)
    assert problem.index.rays.name == backend
    with pytest.raises(OvradError, match="no light"):
        solve(problem)


def test_sky_through_a_window_lights_what_sees_it_and_not_what_a_shelf_hides():
    """The window room open to a constant sky, a shelf low over the floor near the window: a floor
    point that sees the window gets E = pi L F(point -> window) directly (Lambert's contour
    formula), a point under the shelf none; the solve's first shot holds the sky's light."""
    room = scenes.window_room()
    shelf = scenes.quad((0.8, 0.3, 0.3), (1.6, 0.3, 0.3), (1.6, 1.0, 0.3), (0.8, 1.0, 0.3))
    v, t, o = scenes.merge([(room.vertices, room.triangles), shelf])
    s = Surfaces.from_arrays(v, t, reflectance=[0.75] * 3)
    L = np.array([0.6, 0.75, 1.0]) * 3.0
    sky = Sky(tuple(L))
    settings = SolveSettings(min_rays=1 << 18, sky_samples=256, bake_sky_samples=8192)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=400)), settings)
    state = solve(problem, settings=settings, sky=sky)
    light = direct_light(problem, settings=settings, sky=sky)
    assert light.sky is sky and light.sky_samples == 8192
    lit, hidden = np.array([1.2, 2.0, 0.0]), np.array([1.2, 0.6, 0.0])
    pts = np.array([lit, hidden])
    up = np.tile([0.0, 0.0, 1.0], (2, 1))
    H, _ = direct_irradiance(s, problem.index.rays, light, pts, up)
    window = np.array([(0.7, 0.0, 0.8), (1.7, 0.0, 0.8), (1.7, 0.0, 1.8), (0.7, 0.0, 1.8)])
    exact = np.pi * L * analytic.ff_point_to_polygon(lit, up[0], window)
    # the fixed rule's aliasing over a window of 0.08 sr: measured -2.5 / +1.2 / -2.2 / +0.5 /
    # +0.1 % with 1 024 / 4 096 / 8 192 / 16 384 / 65 536 directions
    np.testing.assert_allclose(H[0], exact, rtol=0.03)
    assert np.all(H[1] == 0.0)
    # the solve: the sky's light is in the first shot, and bounces reach the hidden point
    assert np.all(state.first_shot.max(axis=0) > 0)
    tri = problem.index.rays.closest_hit(pts + [0, 0, 0.01], -up, 0.1)[1]
    out = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
    # (in this white room the bounced light is most of it: measured 0.146 at the lit point, of
    # which 0.032 direct, and 0.077 under the shelf)
    assert np.all(out[0] > 0.75 * H[0] / np.pi) and np.all(out[1] > 0) and np.all(out[1] < 0.7 * out[0])


def test_sky_rays_are_cast_only_where_a_patch_saw_out_and_change_nothing():
    # the window room: patches on the window's own wall (and others hidden from it) cast no
    # transport ray out of the window, so points there cast no sky rays; the light is the same
    room = scenes.window_room()
    s = Surfaces.from_arrays(room.vertices, room.triangles, reflectance=[0.75] * 3)
    sky = Sky((1.0, 2.0, 3.0))
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=400)), SolveSettings(min_rays=1 << 18))
    seen = problem.transport.sky_seen
    assert 0.2 * len(seen) < seen.sum() < 0.95 * len(seen)
    pts, tri = scenes.sample_surface(s, 4000, seed=8)
    nrm = triangle_normals(s, tri)
    a = alpha_at(problem.atlas, problem.index, problem.contacts, pts, tri, 1)
    light = direct_light(problem, settings=SolveSettings(bake_sky_samples=1024), sky=sky)
    mask = may_see_sky(a, sky_patches(problem, light))
    H_all, rays_all = direct_irradiance(s, problem.index.rays, light, pts, nrm)
    H, rays = direct_irradiance(s, problem.index.rays, light, pts, nrm, mask)
    # every point left out gets no sky light anyway; exact, as sky_irradiance sums each point's
    # directions in one order (a running sum) whichever points it is given, on every CPU
    np.testing.assert_array_equal(H, H_all)
    assert np.any(H_all[mask] > 0) and rays < 0.9 * rays_all


def test_a_closed_room_under_a_sky_is_refused_as_unlit():
    s = scenes.cube(inward=True)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=50)), SolveSettings(min_rays=1 << 16))
    with pytest.raises(OvradError, match="world emits, and its light reaches no surface"):
        solve(problem, sky=Sky((1.0, 1.0, 1.0)))


def test_a_sky_no_ray_escapes_to_is_left_out_of_the_direct_light():
    # a closed room lit by its own glow under a bright world: no transport ray escapes, so neither
    # the first shot nor the bakes cast sky rays; an open box keeps its sky
    sky = Sky((5.0, 5.0, 5.0))
    base = scenes.cube(inward=True)
    closed = Surfaces.from_arrays(base.vertices, base.triangles, reflectance=[0.5] * 3, emission=[1.0] * 3)
    problem = prepare(
        closed, build_atlas(closed, AtlasSettings(patch_count=100)), SolveSettings(min_rays=1 << 16)
    )
    assert problem.transport.escaped == 0 and problem.transport.rays >= 1 << 16
    assert direct_light(problem, sky=sky).sky is None
    state = solve(problem, settings=SolveSettings(tolerance=1e-6), sky=sky)
    pts, tri = scenes.sample_surface(closed, 2000, seed=5)
    np.testing.assert_allclose(
        radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1), 1.0 / (1 - 0.5), rtol=5e-3
    )
    open_box = Surfaces.from_arrays(base.vertices, base.triangles[2:], reflectance=[0.5] * 3)  # a face less
    problem = prepare(
        open_box, build_atlas(open_box, AtlasSettings(patch_count=100)), SolveSettings(min_rays=1 << 16)
    )
    assert problem.transport.escaped > 0
    assert direct_light(problem, sky=sky).sky is sky


def test_patches_that_cast_few_rays_are_tested_for_sky_and_a_closed_room_sees_none(monkeypatch):
    # patches that cast fewer than SKY_TEST_RAYS transport rays get occlusion rays to complete
    # them, so a closed room's patches all tell they see no sky (untested, they would count as
    # seeing it), and a lone floor's see nothing but sky. Under a budget that leaves
    # every patch short, the test would cost more than the transport: it is skipped, and each
    # patch's cell of patches tells instead (pooled over SKY_TEST_RAYS rays; untested, they would all
    # keep the sky).
    budget = SolveSettings(max_rays=20_000, min_rays=0)
    closed = scenes.cube(inward=True)
    atlas = build_atlas(closed, AtlasSettings(patch_count=200))
    t = prepare(closed, atlas, budget).transport
    assert t.rays / len(atlas) < SKY_TEST_RAYS
    assert not np.any(t.sky_seen) and np.all(t.sky_fraction == 0.0)
    monkeypatch.setattr(transport, "SKY_TEST_SHARE", 100.0)
    t = prepare(closed, atlas, budget).transport
    assert not np.any(t.sky_seen) and np.all(t.sky_fraction == 0.0)
    v, tr = scenes.plane(size=2.0, n=2)
    floor = Surfaces.from_arrays(v, tr, reflectance=[0.5] * 3)
    problem = prepare(floor, build_atlas(floor, AtlasSettings(patch_count=200)), budget)
    t = problem.transport
    has_points = np.bincount(t.points.owner, minlength=len(problem.atlas)) > 0
    assert has_points.sum() > 0.9 * len(has_points)
    np.testing.assert_array_equal(t.sky_fraction[has_points], 1.0)
    assert np.all(t.sky_seen)


def test_pooled_sky_share_of_a_box_open_on_one_side_matches_its_view_factors():
    # a unit cube less one face, under a budget of ~100 rays per patch: too few for the sky test,
    # so each patch's share of the sky is pooled over its cell of patches. Every remaining face
    # sees the opening with the closed-form view factor of two unit squares, 0.19982 (parallel)
    # and 0.20004 (at right angles); the patches' mean on each face comes within 0.03 of it
    # (about 4 standard deviations of ~3 500 cosine-distributed rays per face)
    base = scenes.cube(inward=True)
    box = Surfaces.from_arrays(base.vertices, base.triangles[2:], reflectance=[0.5] * 3)
    atlas = build_atlas(box, AtlasSettings(patch_count=200))
    t = prepare(box, atlas, SolveSettings(max_rays=20_000, min_rays=0)).transport
    assert t.rays / len(atlas) < SKY_TEST_RAYS and np.all(np.isfinite(t.sky_fraction))
    # the missing face's axis: the one fewer patches face along
    facing = [np.sum(np.abs(atlas.normals[:, a]) > 0.9) for a in range(3)]
    open_axis = int(np.argmin(facing))
    faces = 0
    for axis in range(3):
        for sign in (-1.0, 1.0):
            on = sign * atlas.normals[:, axis] > 0.9
            if on.sum() > 10:
                faces += 1
                exact = 0.19982 if axis == open_axis else 0.20004  # parallel to the opening, or not
                assert abs(np.mean(t.sky_fraction[on]) - exact) < 0.03, (axis, sign)
    assert faces == 5


def test_sky_rays_are_left_out_where_the_sky_is_under_a_hundredth_of_the_light():
    # the window room lit by a bright lamp under a dim sky: patches whose escaped rays say the sky
    # brings them under 1 % of their light cast no sky rays; the direct light at points everywhere
    # moves by less than that share of all the light arriving there (measured 0.15 %) from casting
    # sky rays at every point
    room = scenes.window_room()
    s = Surfaces.from_arrays(room.vertices, room.triangles, reflectance=[0.75] * 3)
    sky = Sky((1.0, 1.0, 1.0))
    lamp = Lamp(kind="POINT", position=(1.2, 1.8, 1.6), power=400.0)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=400)), SolveSettings(min_rays=1 << 18))
    state = solve(problem, (lamp,), SolveSettings(tolerance=1e-5), sky=sky)
    light = direct_light(problem, (lamp,), SolveSettings(bake_sky_samples=1024), sky=sky)
    seen = sky_patches(problem, light)
    kept = sky_patches(problem, light, state.radiosity - patch_emission(problem))
    assert kept.sum() < 0.8 * seen.sum() and kept.sum() > 0  # the rule drops some, keeps the window's
    pts, tri = scenes.sample_surface(s, 4000, seed=8)
    nrm = triangle_normals(s, tri)
    a = alpha_at(problem.atlas, problem.index, problem.contacts, pts, tri, 1)
    H_all, rays_all = direct_irradiance(s, problem.index.rays, light, pts, nrm)
    H, rays = direct_irradiance(s, problem.index.rays, light, pts, nrm, may_see_sky(a, kept))
    assert rays < 0.5 * rays_all
    # against all the light arriving there (direct and bounced, H = pi x irradiance_at)
    total = np.pi * irradiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
    err = np.sqrt(np.sum((H - H_all) ** 2) / np.sum(total**2))
    assert err < SKY_SHARE, err


def test_the_first_shot_under_a_tight_budget_thins_its_points_and_bakes_the_same(monkeypatch):
    """The Cornell box at 2 000 patches, its light's 2 triangles picked on power by 2 samples (an
    emitter of as many triangles as samples; the light tree takes its near field): a shadow-ray
    budget 4 000 times smaller leaves the first shot a quarter of each patch's ~30 receiver
    points (MIN_FIRST_SHOT_SHARE), each with its 2 samples: 3.9 times fewer rays. Its light feeds
    the bounces; a final-gather bake computes its own direct light: it moves by 0.016 % RMS, the
    patches' own reconstruction by 0.3 % (measured)."""
    s = scenes.cornell()
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=2000)))
    settings = SolveSettings(light_samples=2)
    pts, tri = scenes.sample_surface(s, 3000, seed=3)
    light = direct_light(problem, (), SolveSettings())
    out = {}
    for budget in (first_shot.SHADOW_BUDGET, 1e-3):
        monkeypatch.setattr(first_shot, "SHADOW_BUDGET", budget)
        state = solve(problem, settings=settings)
        baked = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
        out[budget] = (
            state.rays - problem.rays,
            baked,
            radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1),
        )
    (full_rays, full, full_p), (thin_rays, thin, thin_p) = out.values()
    assert thin_rays < full_rays / 2
    assert np.sqrt(np.sum((thin - full) ** 2) / np.sum(full**2)) < 1e-3
    assert np.sqrt(np.sum((thin_p - full_p) ** 2) / np.sum(full_p**2)) < 1e-2
