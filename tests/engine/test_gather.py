"""The final gather (bake/gather.py) against exact answers: the furnace at face, edge and corner points,
the floor under a resting block, and Lambert's closed form for a point facing a uniform polygon."""

from dataclasses import replace

import numpy as np
import pytest

import scenes
from ovrad_addon.bake import gather as gather_module
from ovrad_addon.bake import lattice
from ovrad_addon.bake.gather import (
    Gather,
    gather_axis,
    gather_indirect,
    gather_unique,
    hemisphere_pattern,
    shared_normals,
    strata,
    unique_points,
)
from ovrad_addon.bake.lattice import CornerCache, NearField, inside
from ovrad_addon.bake.nodes import LatticeValues, TriangleFrames
from ovrad_addon.bake.points import BakeRequest, irradiance_at, radiance_at
from ovrad_addon.errors import OvradError
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.light.direct import direct_irradiance, triangle_normals
from ovrad_addon.light.lamps import Lamp
from ovrad_addon.light.sky import Sky
from ovrad_addon.radiosity.emission import patch_emission, sampled_emission
from ovrad_addon.radiosity.first_shot import direct_light, solve
from ovrad_addon.radiosity.problem import prepare
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, SolveSettings


def polygon_form_factor(point, normal, polygon):
    """Form factor from a differential area (point, unit normal) to a planar polygon (k, 3) wholly
    above its tangent plane: Lambert's contour integral (1 / 2 pi) sum_i gamma_i n . u_i."""
    r = np.asarray(polygon, float) - point
    total = 0.0
    for a, b in zip(r, np.roll(r, -1, axis=0), strict=True):
        c = np.cross(a, b)
        gamma = np.arctan2(np.linalg.norm(c), np.dot(a, b))
        total += gamma * np.dot(normal, c) / np.linalg.norm(c)
    return abs(total) / (2.0 * np.pi)


def block_on_floor(lamp_height=None):
    """A 4 x 4 floor (z = 0, rho 0.5) and a closed unit block [0, 1]^3 resting on it (rho 0.8)."""
    floor_v, floor_t = scenes.plane(size=4.0, n=4)
    parts = [(floor_v - [1.5, 1.5, 0.0], floor_t)] + scenes.box_faces((0, 0, 0), (1, 1, 1))
    v, t, o = scenes.merge(parts, obj=[0] + [1] * 6)
    rho = np.where(o[:, None] == 0, 0.5, 0.8) * np.ones((1, 3))
    s = Surfaces.from_arrays(v, t, o, rho, object_names=["floor", "block"])
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=600)))
    return s, problem


def floor_triangles(s, points):
    """The floor (object 0) triangle under each point (m, 3) on z = 0."""
    ids = np.flatnonzero(s.object_index == 0)
    c = s.corners[ids][None, :, :, :2]
    p = np.asarray(points)[:, None, :2]
    e1, e2, d = c[..., 1, :] - c[..., 0, :], c[..., 2, :] - c[..., 0, :], p - c[..., 0, :]
    det = e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0]
    u = (d[..., 0] * e2[..., 1] - d[..., 1] * e2[..., 0]) / det
    v = (e1[..., 0] * d[..., 1] - e1[..., 1] * d[..., 0]) / det
    inside = (u >= 0) & (v >= 0) & (u + v <= 1)
    return ids[np.argmax(inside, axis=1)]


@pytest.fixture(scope="module")
def block():
    return block_on_floor()


@pytest.fixture(scope="module")
def furnace():
    base = scenes.cube(inward=True)
    s = Surfaces.from_arrays(base.vertices, base.triangles, reflectance=[0.9] * 3, emission=[2.0] * 3)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=300)))
    return s, problem, solve(problem, settings=SolveSettings(tolerance=1e-5))


def test_pattern_is_a_full_grid_of_cosine_strata():
    for count in (1, 16, 64, 128, 256):
        na, nb = strata(count)
        assert na * nb == count and na <= nb
        d = hemisphere_pattern(count)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-12)
        assert np.all(d[:, 2] >= 0)
        # one direction per stratum of (u1, u2) = (1 - z^2, azimuth / 2 pi)
        u1 = 1.0 - d[:, 2] ** 2
        u2 = (np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi)) % 1.0
        cell = np.floor(u1 * na).astype(int) + na * np.floor(u2 * nb).astype(int)
        assert sorted(cell) == list(range(count))
    # a (0, m, 2)-net: one direction in every cell of every 2^a x 2^b grid with 2^(a+b) = 256
    d = hemisphere_pattern(256)
    u1, u2 = 1.0 - d[:, 2] ** 2, (np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi)) % 1.0
    for a in range(9):
        na, nb = 2**a, 2 ** (8 - a)
        cell = np.floor(u1 * na).astype(int) + na * np.floor(u2 * nb).astype(int)
        assert sorted(cell) == list(range(256))
    # the same pattern every time: results are repeatable
    np.testing.assert_array_equal(hemisphere_pattern(64), hemisphere_pattern(64))


@pytest.mark.parametrize("near_rays", [0, 16], ids=["patches", "second-gather"])
@pytest.mark.parametrize("rays", [16, 64])
def test_furnace_is_exact_at_faces_edges_and_corners(furnace, rays, near_rays):
    """...with the near hits' light from other surfaces read off the patches or gathered again at
    lattice nodes (NearField.second_rays): both give B = E / (1 - rho) in a furnace."""
    s, problem, state = furnace
    pts, tri = scenes.sample_surface(s, 1000, seed=4)
    # every triangle corner (cube corners, concave edges) and every edge midpoint
    c = s.corners
    edge = 0.5 * (c + np.roll(c, -1, axis=1))
    pts = np.concatenate([pts, c.reshape(-1, 3), edge.reshape(-1, 3)])
    tri = np.concatenate([tri, np.repeat(np.arange(len(c)), 3), np.repeat(np.arange(len(c)), 3)])
    light = direct_light(problem, (), SolveSettings(gather_rays=rays, near_gather_rays=near_rays))
    assert light.near_gather_rays == near_rays
    L = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
    # every ray from a point inside a closed room lands on it, and B = E / (1 - rho) = 20 pi there
    np.testing.assert_allclose(L, 2.0 / (1 - 0.9), rtol=1e-3)
    # the gathered irradiance itself: the large emitter is not sampled, so it counts in full
    H = irradiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
    np.testing.assert_allclose(H, 20.0, rtol=1e-3)


def subdivided(surfaces, times):
    """Each triangle cut into 4 by its edge midpoints, `times` over (vertices not shared)."""
    c = surfaces.corners
    for _ in range(times):
        a, b, d = c[:, 0], c[:, 1], c[:, 2]
        ab, bd, da = (a + b) / 2, (b + d) / 2, (d + a) / 2
        quads = ((a, ab, da), (ab, b, bd), (da, bd, d), (ab, bd, da))
        c = np.concatenate([np.stack(x, axis=1) for x in quads])
    return c.reshape(-1, 3), np.arange(len(c) * 3).reshape(-1, 3)


def test_furnace_is_exact_on_a_finely_meshed_room():
    """The same furnace with every face in 4.4 cm triangles, a fifth of the patch radius (22 cm):
    every gather hit reads the patches from its triangle's corners (CornerCache), and a convex mix of
    corner values that each reproduce the uniform radiosity reproduces it too."""
    v, t = subdivided(scenes.cube(inward=True), 5)
    s = Surfaces.from_arrays(v, t, reflectance=[0.9] * 3, emission=[2.0] * 3)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=50)))
    state = solve(problem, settings=SolveSettings(tolerance=1e-5))
    cache = CornerCache(problem, state.radiosity, None)
    sheets = problem.index.sheet_of(np.arange(len(t)), np.ones(len(t), np.int64))
    assert np.all(cache.size <= cache.alpha_size[sheets])  # every triangle reads its corners
    pts, tri = scenes.sample_surface(s, 400, seed=4)
    light = direct_light(problem, (), SolveSettings(gather_rays=64))
    L = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
    np.testing.assert_allclose(L, 2.0 / (1 - 0.9), rtol=1e-3)


def test_floor_under_a_resting_block_gets_nothing(block):
    s, problem = block
    lamp = Lamp(kind="POINT", position=(0.5, 0.5, 3.0), power=200.0)
    state = solve(problem, (lamp,))
    under = np.array([[0.5, 0.5, 0.0], [0.1, 0.2, 0.0], [0.9, 0.95, 0.0]])
    tri = floor_triangles(s, under)
    on = direct_light(problem, (lamp,), SolveSettings(gather_rays=64))
    off = direct_light(problem, (lamp,), SolveSettings(gather_rays=0))
    leak = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, off), under, tri, 1)
    got = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, on), under, tri, 1)
    assert leak.max() > 0  # patches reaching under the block carry light there
    np.testing.assert_array_equal(got, 0.0)
    H = gather_indirect(
        problem, Gather(state.radiosity, np.zeros_like(state.radiosity), 64), under, [[0, 0, 1.0]] * 3
    )
    np.testing.assert_array_equal(H, 0.0)


@pytest.mark.parametrize("where", [(0.5, -0.3, 0.0), (0.2, -0.05, 0.0), (0.5, -1.2, 0.0), (-0.4, -0.4, 0.0)])
def test_point_beside_the_block_matches_lambert(block, where):
    """Block patches radiate a uniform B, the floor's nothing: E = B F(point -> visible block faces)."""
    s, problem = block
    atlas = problem.atlas
    on_floor = (np.abs(atlas.centers[:, 2]) < 1e-9) & (atlas.normals[:, 2] > 0.5)
    B = np.where(on_floor[:, None], 0.0, [1.0, 2.0, 3.0])
    p = np.array(where, float)
    faces = {  # outward faces of the block a floor point at y < 0 (and maybe x < 0) can see
        "-y": [(0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)],
        "-x": [(0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)],
    }
    want = polygon_form_factor(p, [0, 0, 1.0], faces["-y"])
    if p[0] < 0:
        want += polygon_form_factor(p, [0, 0, 1.0], faces["-x"])
    tri = floor_triangles(s, p[None])
    H = gather_indirect(problem, Gather(B, np.zeros_like(B), 16384), p[None], [[0, 0, 1.0]], tri)
    # what is left is the pattern's own error on a face seen under 5-30 % of the cosine measure
    # (0.1-0.4 % with 16 384 directions, measured; every hit on the block is covered)
    np.testing.assert_allclose(H[0], want * np.array([1.0, 2.0, 3.0]), rtol=5e-3)


@pytest.mark.parametrize("h", [0.2, 1.0])
def test_point_facing_a_uniform_square(h):
    """A point under a lone 2 x 2 square of uniform radiosity, facing it: E = B F (closed form)."""
    v, t = scenes.plane(size=2.0, n=2, z=h)
    s = Surfaces.from_arrays(v[:, [1, 0, 2]], t)  # swapped axes: the square faces down
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=200)))
    p = np.array([[1.0, 1.0, 0.0], [0.3, 1.6, 0.0]])
    square = [(0, 0, h), (2, 0, h), (2, 2, h), (0, 2, h)]
    B = np.full((len(problem.atlas), 3), 5.0)
    H = gather_indirect(problem, Gather(B, np.zeros_like(B), 16384), p, [[0, 0, 1.0]] * 2)
    want = [5.0 * polygon_form_factor(q, [0, 0, 1.0], square) for q in p]
    np.testing.assert_allclose(H[:, 0], want, rtol=3e-3)
    # a point facing away from it gets nothing; the emission of the hit patches is left out
    np.testing.assert_array_equal(gather_indirect(problem, Gather(B, B, 64), p, [[0, 0, 1.0]] * 2), 0.0)
    np.testing.assert_array_equal(gather_indirect(problem, Gather(B, 0 * B, 64), p, [[0, 0, -1.0]] * 2), 0.0)


def tilted(deg, axis):
    """A unit normal turned from +z by deg degrees about the x (axis 0) or y (axis 1) axis."""
    a = np.radians(deg)
    return np.array([0.0, -np.sin(a), np.cos(a)]) if axis == 0 else np.array([np.sin(a), 0.0, np.cos(a)])


def test_shared_normals_merge_a_smooth_vertex_and_keep_a_crease():
    smooth = [tilted(12, 0), tilted(-12, 0), tilted(12, 1), tilted(-12, 1)]
    crease = [[0, 0, 1.0], [1.0, 0, 0]]  # a box's edge: 45 degrees from their mean
    alone = [[0, 1.0, 0]]
    normals = np.array(smooth + crease + alone + smooth[:2])
    groups = np.array([0, 0, 0, 0, 1, 1, -1, 2, 2])
    weights = np.array([1.0, 2.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0])  # group 2 has no weight
    out = shared_normals(groups, normals, weights, np.radians(15.0))
    assert out.shape == (9, 4, 3)
    # every corner of the smooth vertex gathers for all four normals, weighted 1/5, 2/5, 1/5, 1/5
    want = rows_sorted(normals[:4] * (weights[:4] / 5.0)[:, None])
    for j in range(4):
        np.testing.assert_allclose(rows_sorted(out[j]), want, atol=1e-15)
    np.testing.assert_array_equal(out[4:, 0], normals[4:])  # the others alone, on their own
    np.testing.assert_array_equal(out[4:, 1:], 0.0)
    np.testing.assert_allclose(
        gather_axis(out[:1]), [gather_axis(normals[None, :4] * weights[None, :4, None])[0]]
    )
    # at a 10 degree limit the 12 degree tilts keep their own normals; so do groups over `most`
    np.testing.assert_array_equal(shared_normals(groups, normals, weights, np.radians(10.0))[:, 0], normals)
    assert shared_normals(groups, normals, weights, np.radians(15.0), most=3).shape == (9, 1, 3)
    # a normal repeated (a quad's two triangles) is one normal: its corners' weights add up
    twice = shared_normals(
        np.zeros(3, int), np.array([tilted(5, 0), tilted(5, 0), tilted(-5, 0)]), np.ones(3)
    )
    want = rows_sorted(np.array([tilted(5, 0), tilted(-5, 0)]) * np.array([[2 / 3], [1 / 3]]))
    assert twice.shape == (3, 2, 3)
    np.testing.assert_allclose(rows_sorted(twice[2]), want, atol=1e-15)


def rows_sorted(a):
    a = np.asarray(a)
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.parametrize("scene", ["square", "room"])
def test_one_gather_for_several_normals_is_the_mean_of_their_gathers(scene):
    """Under a uniform square (closed form: light from above every normal's horizon) and inside a
    uniform room (light from every direction: the same irradiance about any normal), one gather
    about the mean of normals 12 degrees apart either way, its rays weighted and the light below its
    horizon counted (gather_indirect's spread), equals the weighted mean of the irradiances about
    each normal."""
    normals = np.array([tilted(12, 0), tilted(-12, 0), tilted(12, 1), tilted(-10, 1)])
    weights = np.array([1.0, 2.0, 1.5, 0.5])
    if scene == "square":
        h = 1.0
        v, t = scenes.plane(size=2.0, n=2, z=h)
        s = Surfaces.from_arrays(v[:, [1, 0, 2]], t)
        problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=200)))
        square = [(0, 0, h), (2, 0, h), (2, 2, h), (0, 2, h)]
        p = np.array([0.6, 1.3, 0.0])
        each = np.array([polygon_form_factor(p, n, square) for n in normals])
    else:
        base = scenes.cube(inward=True)
        s = Surfaces.from_arrays(base.vertices, base.triangles, reflectance=[0.5] * 3)
        problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=200)))
        p = np.array([0.5, 0.4, 0.0])  # on the floor of the unit cube
        each = np.ones(4)
    want = np.average(each, weights=weights)
    B = np.ones((len(problem.atlas), 3))
    spread = shared_normals(np.zeros(4, int), normals, weights)
    axis = gather_axis(spread)
    H = gather_unique(problem, Gather(B, np.zeros_like(B), 16384), np.tile(p, (4, 1)), axis, spread=spread)
    np.testing.assert_allclose(H[:, 0], want, rtol=3e-3)
    # a pattern of a few rays has none under 20 degrees: its lowest one tells the light seen low
    few = gather_unique(problem, Gather(B, np.zeros_like(B), 4), np.tile(p, (4, 1)), axis, spread=spread)
    assert np.all(np.isfinite(few))
    # without the rays' weights, the gather about the mean normal alone
    plain = gather_unique(problem, Gather(B, np.zeros_like(B), 16384), p[None], axis[:1])[0, 0]
    if scene == "square":  # is 2 % too bright: the normals see the square 7 % apart
        assert np.ptp(each) / want > 0.05 and plain / want - 1 > 0.015
    else:  # scaled by the mean's length (exact for light from above all horizons), 2 % too dark
        length = np.linalg.norm(np.average(normals, axis=0, weights=weights))
        assert 1 - length * plain / want > 0.015


def test_sampled_emitters_count_only_what_they_reflect():
    """A small emitter in a closed room: its emission reaches bake points as direct light only."""
    base = scenes.cube(inward=True)
    light_v, light_t = scenes.plane(size=0.2, n=1, z=0.99)
    v, t, o = scenes.merge(
        [(base.vertices, base.triangles), (light_v[:, [1, 0, 2]] + [0.4, 0.4, 0], light_t)]
    )
    em = np.where(o[:, None] == 1, 10.0, 0.0) * np.ones((1, 3))
    s = Surfaces.from_arrays(v, t, o, reflectance=[0.5] * 3, emission=em)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=400)))
    light = direct_light(problem, (), SolveSettings(gather_rays=64))
    assert np.any(light.emitters)
    own = sampled_emission(problem, light.emitters, 1.0)
    emitting = np.abs(problem.atlas.centers[:, 2] - 0.99) < 1e-6  # centres as stored: float32
    np.testing.assert_allclose(own[emitting], 10.0 * np.pi, rtol=1e-9)
    np.testing.assert_array_equal(own[~emitting], 0.0)
    state = solve(problem, settings=SolveSettings(tolerance=1e-5))
    # a point facing the emitter's back from below the ceiling: the light patches' reflected part
    p = np.array([[0.5, 0.5, 0.5]])
    with_light = gather_indirect(problem, Gather(state.radiosity, own, 1024), p, [[0, 0, 1.0]])
    without = gather_indirect(problem, Gather(state.radiosity, state.radiosity, 1024), p, [[0, 0, 1.0]])
    full = gather_indirect(problem, Gather(state.radiosity, 0 * own, 1024), p, [[0, 0, 1.0]])
    assert np.all(without == 0)
    assert np.all(with_light < full) and np.all(with_light > 0)


def test_unique_points_gather_once():
    base = scenes.cube(inward=True)
    s = Surfaces.from_arrays(base.vertices, base.triangles, reflectance=[0.5] * 3, emission=[1.0] * 3)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=100)))
    state = solve(problem)
    tri = np.repeat(np.arange(len(s.triangles)), 3)
    pts = s.corners.reshape(-1, 3)
    nrm = triangle_normals(s, tri)
    first, inverse = unique_points(pts, nrm, 1e-9)
    # a cube corner is shared by the triangles of 3 faces (3 normals); each face's corner appears
    # once per triangle using it
    assert len(first) == 24 * 3 // 3 or len(first) < len(pts)
    np.testing.assert_array_equal(pts[first][inverse], pts)
    zero = np.zeros_like(state.radiosity)
    a = gather_unique(problem, Gather(state.radiosity, zero, 64), pts, nrm, tri)
    b = gather_indirect(problem, Gather(state.radiosity, zero, 64), pts[first], nrm[first], tri[first])[
        inverse
    ]
    np.testing.assert_array_equal(a, b)


def test_gather_rays_is_validated():
    with pytest.raises(OvradError, match="gather_rays"):
        SolveSettings(gather_rays=-1)
    with pytest.raises(OvradError, match="gather_rays"):
        SolveSettings(gather_rays=1 << 20)


def wall_foot_irradiance(z, power, rho, lamp=(0.0, 1.0, 1.0), shadow=(0.02, 0.06), n=400):
    """Irradiance at (0, 0, z) on a wall (the plane y = 0, facing +y) from a lit floor (z = 0, y > 0,
    |x| <= 1, y <= 2): the floor's radiosity is rho x the point lamp's irradiance, zero on the shadow
    band shadow[0] <= y <= shadow[1]. Independent of the engine: Gauss-Legendre in x and y on
    intervals graded towards the wall's foot (the kernel y z / (pi r^4) peaks within z of it) and
    split at the shadow's edges."""
    g, w = np.polynomial.legendre.leggauss(24)

    def rule(cuts):
        pts, wts = [], []
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            pts.append(0.5 * (b - a) * g + 0.5 * (a + b))
            wts.append(0.5 * (b - a) * w)
        return np.concatenate(pts), np.concatenate(wts)

    grade = z * 2.0 ** np.arange(-6, 12)
    ycuts = np.unique(np.clip(np.concatenate([[0.0, 2.0], grade, shadow]), 0.0, 2.0))
    xcuts = np.unique(np.clip(np.concatenate([[-1.0, 1.0], grade, -grade]), -1.0, 1.0))
    y, wy = rule(ycuts)
    x, wx = rule(xcuts)
    X, Y = np.meshgrid(x, y, indexing="ij")
    L = np.asarray(lamp, float)
    d2 = (L[0] - X) ** 2 + (L[1] - Y) ** 2 + L[2] ** 2
    E_lamp = power / (4 * np.pi) * L[2] / d2**1.5
    lit = (Y < shadow[0]) | (Y > shadow[1])
    B = rho * E_lamp * lit
    r2 = X**2 + Y**2 + z**2
    kernel = Y * z / (np.pi * r2**2)
    return float(np.einsum("i,j,ij->", wx, wy, B * kernel))


@pytest.mark.parametrize("cuts", [8, 64])
def test_near_hits_resolve_a_shadow_at_a_walls_foot(cuts):
    """A black wall standing on a floor lit by a point lamp; a black strip overhead casts a 4 cm
    shadow band along the wall's foot. A wall point a few cm up sees mostly that band: read from the
    floor's patches (9 cm radius) the band is smeared out; with the near field (the default) hits
    within about a patch radius get their direct light where they land, and with a longer reach the
    gathered light converges to the integral of the floor's exact radiosity. The floor in 8 x 8
    squares (35 cm triangles) has every near hit cast shadow rays; in 64 x 64 (4.4 cm), hits
    beyond 70 cm (18 cm at 256 rays) take their light from their triangle's corners (CornerCache)."""
    floor_v, floor_t = scenes.plane(size=2.0, n=cuts)
    floor_v = floor_v - [1.0, 0.0, 0.0]  # |x| <= 1, 0 <= y <= 2
    wall = scenes.quad((1, 0, 0), (-1, 0, 0), (-1, 0, 1), (1, 0, 1))  # faces +y (checked below)
    strip = scenes.quad((-1, 0.51, 0.5), (1, 0.51, 0.5), (1, 0.53, 0.5), (-1, 0.53, 0.5))
    v, t, o = scenes.merge([(floor_v, floor_t), wall, strip], obj=[0, 1, 2])
    rho = np.where(o[:, None] == 0, 0.5, 0.0) * np.ones((1, 3))
    s = Surfaces.from_arrays(v, t, o, rho, object_names=["floor", "wall", "strip"])
    wall_tri = np.flatnonzero(o == 1)
    assert np.allclose(triangle_normals(s, wall_tri), [0, 1, 0])
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=600, beta="box")))
    assert np.median(problem.atlas.radii) > 0.08  # patches far wider than the shadow band
    lamp = Lamp(kind="POINT", position=(0.0, 1.0, 1.0), power=300.0)
    state = solve(problem, (lamp,), SolveSettings(tolerance=1e-6))
    heights = np.array([0.01, 0.02, 0.04])  # (the patches' B: their means over 16-32 receiver points)
    pts = np.column_stack([np.zeros(3), np.zeros(3), heights])
    tri = np.full(3, wall_tri[0])  # (1, 0, 0), (-1, 0, 0), (-1, 0, 1) holds x = 0 up to z = 0.5
    normals = np.tile([0.0, 1.0, 0.0], (3, 1))
    want = np.array([wall_foot_irradiance(z, 300.0, 0.5) for z in heights])
    light = direct_light(problem, (lamp,), SolveSettings(gather_rays=4096))
    assert light.near_field  # on by default
    E = patch_emission(problem)
    indirect = state.radiosity - state.first_shot - E
    zero = np.zeros_like(E)

    def signed(reach, size=NearField.corner_size):
        near = None if reach is None else NearField(light, indirect, zero, reach=reach, corner_size=size)
        H = gather_indirect(problem, Gather(state.radiosity, zero, 4096, near=near), pts, normals, tri)
        return H[:, 0] / want - 1

    def error(reach, size=NearField.corner_size):
        return np.abs(signed(reach, size))

    patches, default, far = error(None), error(NearField.reach), error(4.0)
    # measured (heights 1, 2, 4 cm): patches only 0.03 / 22 / 21 %, default reach 3.9-4.1 / 8.1 /
    # 11 %; reach 4: 0.36 / 0.19 / 0.01 % (8 cuts), 0.56 / 0.19 / 0.11 % (64 cuts)
    assert np.sqrt(np.mean(patches**2)) > 0.1
    assert np.sqrt(np.mean(default**2)) < 0.6 * np.sqrt(np.mean(patches**2))
    assert np.all(far < (5e-3 if cuts == 8 else 1e-2))
    if cuts == 64:
        # 4 096 rays land 4 x closer together than the default 256: corner light at the size the
        # default uses at 256 rays (0.25 x the distance) moves the light by under 0.2 % (0.62 / 0.10
        # / 0.27 %); twice that smears the band (1.1 / 1.4 / 2.7 %)
        assert np.all(np.abs(error(4.0, size=4 * NearField.corner_size) - far) < 3e-3)
    # what the bake computes is the default near field
    H = irradiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
    H_direct = irradiance_at(
        problem, BakeRequest(state.radiosity, state.first_shot, replace(light, gather_rays=0)), pts, tri, 1
    )
    np.testing.assert_allclose(np.pi * (H - H_direct)[:, 0] / want - 1, signed(NearField.reach), atol=1e-9)


def barycentric(corners, points):
    """The three weights TriangleFrames gives points (k, 3) on triangles (k, 3, 3)."""
    vw = TriangleFrames(corners).coordinates(np.arange(len(corners)), points)
    return np.column_stack([1.0 - vw.sum(axis=1), vw])


def test_barycentric_weights():
    tri = np.array([[[0.0, 0, 0], [2, 0, 0], [0, 1, 0]]] * 4)
    pts = np.array([[0.0, 0, 0], [2, 0, 0], [0.5, 0.25, 0], [-1, -1, 0]])
    w = barycentric(tri, pts)
    np.testing.assert_allclose(w[:2], [[1, 0, 0], [0, 1, 0]], atol=1e-12)
    np.testing.assert_allclose(w[2], [0.5, 0.25, 0.25])  # reproduces the point
    np.testing.assert_allclose(np.einsum("kc,kcj->kj", w[2:3], tri[2:3]), pts[2:3])
    np.testing.assert_allclose(w[3], [1, 0, 0])  # outside: clipped onto the triangle
    flat = np.array([[[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]])
    np.testing.assert_allclose(barycentric(flat, np.zeros((1, 3))), [[1 / 3] * 3])


def test_corner_light_interpolates_exact_corner_values():
    """A point lamp 1 m over a floor in 2 x 2 squares: the corner light of a triangle equals the
    lamp's closed form I cos / d^2 at its corners (stepped inside), and a hit inside gets their
    barycentric mix; both sides are kept apart (the floor's underside gets nothing)."""
    v, t = scenes.plane(size=2.0, n=2)
    s = Surfaces.from_arrays(v, t, reflectance=[0.5] * 3)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=100)))
    lamp = Lamp(kind="POINT", position=(0.7, 0.9, 1.0), power=400.0)
    light = direct_light(problem, (lamp,))
    E = patch_emission(problem)
    near = NearField(light, np.zeros_like(E), np.zeros_like(E))
    corners = CornerCache(problem, np.zeros_like(E), near)
    tri = np.arange(len(t))
    w = np.array([0.2, 0.3, 0.5])
    pts = np.einsum("c,tcj->tj", w, s.corners[tri])
    got = corners.light_at(pts, tri, np.ones(len(tri), np.int64))
    at = inside(s, s.corners[tri].reshape(-1, 3), np.repeat(tri, 3)).reshape(-1, 3, 3)
    d = np.asarray(lamp.position) - at
    r2 = np.einsum("tcj,tcj->tc", d, d)
    closed = 400.0 / (4 * np.pi) * d[..., 2] / r2**1.5  # I cos / d^2 with cos = dz / d
    np.testing.assert_allclose(got[:, 0], closed @ w, rtol=1e-9)
    assert np.all(corners.light_at(pts, tri, -np.ones(len(tri), np.int64)) == 0.0)


def lamp_over_floor(block, seed: int):
    """The block scene solved under a point lamp, its near field, and about 300 floor points
    (seeded) off the block's footprint with their triangles and up normals."""
    s, problem = block
    lamp = Lamp(kind="POINT", position=(2.0, 0.5, 2.5), power=300.0)
    state = solve(problem, (lamp,), SolveSettings())
    light = direct_light(problem, (lamp,))
    E = patch_emission(problem)
    near = NearField(light, state.radiosity - state.first_shot - E, np.zeros_like(E))
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(-1.4, 2.4, 300), rng.uniform(-1.4, 2.4, 300), np.zeros(300)])
    pts = pts[(pts[:, 0] < -0.01) | (pts[:, 0] > 1.01) | (pts[:, 1] < -0.01) | (pts[:, 1] > 1.01)]
    tri = floor_triangles(s, pts)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    return problem, state, E, near, pts, tri, normals


@pytest.mark.parametrize("second", [0, 16], ids=["patches", "second-gather"])
def test_near_field_does_not_depend_on_threads_or_chunks(block, second):
    """Corner light (and the second gather's irradiance at lattice nodes) is filled by whichever
    chunk asks first; the result must not depend on it (to rounding: 1e-12 relative, as numpy's
    reductions and vector loops may round a value otherwise in arrays of another shape, as the CPU's
    SIMD width decides; a node filled from other rays would differ by the gather's noise, a percent)."""
    problem, state, E, near, pts, tri, normals = lamp_over_floor(block, seed=5)
    near = replace(near, second_rays=second)
    one = gather_indirect(problem, Gather(state.radiosity, E, 64, near=near, workers=1), pts, normals, tri)
    many = gather_indirect(
        problem, Gather(state.radiosity, E, 64, near=near, chunk_rays=640, workers=2), pts, normals, tri
    )
    assert np.any(one > 0)
    np.testing.assert_allclose(many, one, rtol=1e-12, atol=1e-12 * one.max())


def test_second_gather_nodes_hold_a_gather_of_the_far_values(block):
    """With NearField.second_rays, a near hit's light from other surfaces is the irradiance at its
    triangle's lattice nodes from a second gather that reads only the far values. At a triangle's
    first corner the lattice gives that node's value alone: it equals an independent gather without
    near field from the corner (the same directions, SECOND_SEED), to rounding. The near hits then
    differ from the patches' indirect light (the floor beside the block is not its patches' mean)."""
    problem, state, E, near, pts, tri, normals = lamp_over_floor(block, seed=11)
    second = replace(near, second_rays=16)
    shared: dict = {}
    with_second = gather_indirect(
        problem, Gather(state.radiosity, E, 64, near=second, corner_cache=shared), pts, normals, tri
    )
    (cache,) = shared.values()
    assert cache.second_nodes is not None and cache.second_nodes.count > 0
    floor = np.unique(tri)
    corner = problem.surfaces.corners[floor, 0]
    up = np.ones(len(floor), np.int64)
    got, _ = cache.second_at(corner, floor, up)
    want = gather_indirect(
        problem,
        Gather(state.radiosity, E, 16, near=None, seed=gather_module.SECOND_SEED),
        corner,
        np.tile([0.0, 0.0, 1.0], (len(floor), 1)),
        floor,
    )
    assert np.any(want > 0)  # the corners that see the lit block get its light
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * want.max())
    patches = gather_indirect(problem, Gather(state.radiosity, E, 64, near=near), pts, normals, tri)
    assert np.max(np.abs(with_second - patches)) > 1e-2 * patches.max()


def test_calls_sharing_a_corner_cache_give_what_one_call_gives(block):
    """A bake's receivers and chunks gather in separate calls; with one corner_cache dict they share
    one CornerCache (built once, its nodes filled once for all) and give what one call over all
    their points gives, to rounding (1e-12 relative: see the test above)."""
    problem, state, E, near, pts, tri, normals = lamp_over_floor(block, seed=8)
    whole = gather_indirect(problem, Gather(state.radiosity, E, 64, near=near), pts, normals, tri)
    shared: dict = {}
    half = len(pts) // 2
    parts = [
        gather_indirect(
            problem,
            Gather(state.radiosity, E, 64, near=near, corner_cache=shared),
            pts[sl],
            normals[sl],
            tri[sl],
        )
        for sl in (slice(0, half), slice(half, None))
    ]
    assert len(shared) == 1
    (cache,) = shared.values()
    filled = cache.patch_nodes.count
    assert filled > 0 and np.any(whole > 0)
    np.testing.assert_allclose(np.concatenate(parts), whole, rtol=1e-12, atol=1e-12 * whole.max())
    # asked again, every node is there already
    again = gather_indirect(
        problem, Gather(state.radiosity, E, 64, near=near, corner_cache=shared), pts, normals, tri
    )
    assert cache.patch_nodes.count == filled
    np.testing.assert_allclose(again, whole, rtol=1e-12, atol=1e-12 * whole.max())


def test_lattice_reproduces_linear_values_and_fills_each_node_once():
    """Values linear in position are reproduced exactly anywhere on a triangle (each lattice cell
    interpolates linearly between its nodes); each node is computed once, whatever the order asked;
    the two sides are kept apart; a lattice of n cuts holds (n + 1)(n + 2) / 2 nodes."""
    corners = np.array([[[0.0, 0, 0], [3, 0, 0], [0.5, 2, 0]], [[0.0, 0, 1], [1, 0, 1], [0, 1, 1]]])
    asked = []

    def fill(tri, side, pts):
        asked.append(len(tri))
        return np.column_stack([pts @ [1.0, -2.0, 0.5] + 3 * tri + side, np.ones(len(tri))])

    lattice = LatticeValues(TriangleFrames(corners), np.array([[7, 1], [5, 0]]), 2, np.float64, fill)
    rng = np.random.default_rng(3)
    w = rng.dirichlet([1, 1, 1], 500)
    w[:6] = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0], [0, 0.5, 0.5], [1 / 3, 1 / 3, 1 / 3]]
    for tri, side in ((0, 1), (1, 1), (0, -1), (0, 1)):
        pts = np.einsum("kc,cj->kj", w, corners[tri])
        k = len(pts)
        got = lattice.at(pts, np.full(k, tri), np.full(k, side))
        want = pts @ [1.0, -2.0, 0.5] + 3 * tri + side
        np.testing.assert_allclose(got[:, 0], want, atol=1e-12)
        np.testing.assert_allclose(got[:, 1], 1.0, atol=1e-12)
    assert lattice.used == 36 + 3 + 21  # slots for the three sides asked, none for the fourth
    assert sum(asked) == lattice.count <= lattice.used  # the repeated side asked nothing new
    assert len(asked) == 3


def test_lattice_near_a_contact_matches_alpha_at_every_hit(block, monkeypatch):
    """Points on a block's face 0.5-8 cm above the floor it rests on, the lamp on the block's other
    side: their rays meet the floor at the block's foot, where the floor's patches step (hidden
    under the block, in its shadow, lit further out). Read from the lattice there, that step is
    smeared over cells seen under a large angle: 5.1 % of the points' mean light off (measured).
    Hits within LATTICE_REACH radii read alpha where they land, and the gather agrees with alpha at
    every hit (corner_alpha=0) within 0.2 % of the mean (measured)."""
    s, problem = block
    lamp = Lamp(kind="POINT", position=(2.0, 0.5, 2.5), power=300.0)
    state = solve(problem, (lamp,), SolveSettings())
    P = np.array([[x, 0.0, z] for x in (0.2, 0.5, 0.8) for z in (0.005, 0.01, 0.02, 0.04, 0.08)])
    N = np.tile([0.0, -1.0, 0.0], (len(P), 1))  # the block's -y face, facing out
    zero = np.zeros_like(state.radiosity)
    exact = gather_indirect(problem, Gather(state.radiosity, zero, 256, corner_alpha=0), P, N)[:, 0]
    scale = np.abs(exact).mean()
    assert exact.max() > 0.1
    assert CornerCache(problem, state.radiosity, None).patch_nodes.divisions.max() > 1  # a lattice
    got = gather_indirect(problem, Gather(state.radiosity, zero, 256), P, N)[:, 0]
    assert np.abs(got - exact).max() < 0.01 * scale
    monkeypatch.setattr(lattice, "LATTICE_REACH", 0.0)
    smeared = gather_indirect(problem, Gather(state.radiosity, zero, 256), P, N)[:, 0]
    assert np.abs(smeared - exact).max() > 0.03 * scale


@pytest.fixture(scope="module")
def sky_block():
    """The block on its floor under a constant sky (no lamp), solved, and its near field with a
    second gather."""
    s, problem = block_on_floor()
    sky = Sky((0.6, 0.6, 0.6))
    state = solve(problem, sky=sky)
    light = direct_light(problem, (), SolveSettings(), sky=sky)
    E = patch_emission(problem)
    near = NearField(light, state.radiosity - state.first_shot - E, np.zeros_like(E), second_rays=16)
    return s, problem, state, E, near


def test_near_hits_take_the_skys_light_from_the_second_gathers_lattice(sky_block):
    """With a second gather, a near hit's sky light is read from the lattice of that gather, whose
    nodes hold the sky's direct irradiance as direct_irradiance gives it there: at a triangle's
    first corner, the sky-only rule at the corner stepped inside, to rounding. The floor round the
    block's foot (its gather rays land on the block's sides close by) gets what near hits casting
    sky rays where they land give, within 1 % (measured 0.04 % RMS; 24 % off with no sky at
    the near hits)."""
    s, problem, state, E, near = sky_block
    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.uniform(-0.3, 1.3, 400), rng.uniform(-0.3, 1.3, 400), np.zeros(400)])
    pts = pts[(pts[:, 0] < -0.01) | (pts[:, 0] > 1.01) | (pts[:, 1] < -0.01) | (pts[:, 1] > 1.01)]
    tri = floor_triangles(s, pts)
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    shared: dict = {}
    lattice = gather_indirect(
        problem, Gather(state.radiosity, E, 64, near=near, corner_cache=shared), pts, normals, tri
    )
    exact = gather_indirect(
        problem, Gather(state.radiosity, E, 64, near=replace(near, sky_nodes=False)), pts, normals, tri
    )
    (cache,) = shared.values()
    assert cache.sky_nodes and not np.any(cache.hit_light.sky)
    floor = np.unique(tri)
    corner = problem.surfaces.corners[floor, 0]
    up = np.ones(len(floor), np.int64)
    _, sky_light = cache.second_at(corner, floor, up)
    sky_only = replace(near.light, lamps=(), emitters=None)
    want = direct_irradiance(
        problem.emitter_rules,
        problem.index.rays,
        sky_only,
        inside(s, corner, floor),
        np.tile([0.0, 0.0, 1.0], (len(floor), 1)),
    )[0]
    np.testing.assert_allclose(sky_light, want, rtol=1e-12, atol=1e-12 * want.max())
    off = np.any((corner[:, :2] < 0.0) | (corner[:, :2] > 1.0), axis=1)  # off the block's footprint
    assert off.sum() >= 3 and np.all(want[off] > 0.2 * np.pi * 0.6)  # the sky less what the block hides
    rel = np.sqrt(np.sum((lattice - exact) ** 2) / np.sum(exact**2))
    assert rel < 0.01, rel


def test_a_bake_reports_the_diffuse_share_of_the_reflected_light_and_all_the_emission():
    """Surfaces.bake_weight scales what a bake point reflects (direct, gathered and the patches'
    light alike), not what it emits, and leaves the solve alone: a floor under a lamp with a weight
    of 0.9 bakes 0.9 x the floor without one; an emitting floor keeps its emission."""
    v, t = scenes.plane(size=2.0, n=2)
    lamp = Lamp(kind="POINT", position=(0.3, 0.2, 1.5), power=300.0)
    pts = np.array([[0.2, 0.3, 0.0], [1.1, 1.6, 0.0], [1.8, 0.4, 0.0]])
    em = 0.25
    baked = []
    for weight in (None, np.full(len(t), 0.9)):
        s = Surfaces.from_arrays(v, t, reflectance=[0.6] * 3, emission=[em] * 3, bake_weight=weight)
        problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=80)))
        state = solve(problem, (lamp,), SolveSettings())
        light = replace(direct_light(problem, (lamp,)), gather_rays=64)
        request = BakeRequest(state.radiosity, state.first_shot, light)
        baked.append(radiance_at(problem, request, pts, floor_triangles(s, pts)))
    plain, weighted = baked
    emitted = em  # radiance: L_e, the floor's own
    assert np.all(plain > emitted + 0.5)  # lit well above its emission
    np.testing.assert_allclose(weighted - emitted, 0.9 * (plain - emitted), rtol=1e-12)
    with pytest.raises(OvradError, match="bake_weight"):
        Surfaces.from_arrays(v, t, bake_weight=np.full(len(t), 1.5))


def test_a_surface_that_reflects_nothing_bakes_its_emission_and_asks_no_light(monkeypatch):
    """An emitter with no diffuse reflectance (an Emission shader) bakes exactly its emission, and
    neither its bake points nor the gather hits landing on it ask for light (no shadow rays, no
    gather): a 4 000-triangle emissive sphere's vertices cast 200 000 gather rays whose hits under
    it each walked the light tree. The floor beside it still gets its light."""
    floor_v, floor_t = scenes.plane(size=4.0, n=4)
    parts = [(floor_v - [1.5, 1.5, 0.0], floor_t)] + scenes.box_faces((0, 0, 0), (1, 1, 1))
    v, t, o = scenes.merge(parts, obj=[0] + [1] * 6)
    rho = np.where(o[:, None] == 0, 0.5, 0.0) * np.ones((1, 3))
    L_e = 3.0
    em = np.where(o[:, None] == 1, L_e, 0.0) * np.ones((1, 3))
    s = Surfaces.from_arrays(v, t, o, rho, em, object_names=["floor", "glow"])
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=400)))
    lamp = Lamp(kind="POINT", position=(2.0, 0.5, 2.0), power=200.0)
    state = solve(problem, (lamp,), SolveSettings(tolerance=1e-5))
    light = replace(direct_light(problem, (lamp,)), gather_rays=64, near_field=True, near_gather_rays=16)
    request = BakeRequest(state.radiosity, state.first_shot, light)
    asked = []
    for module in (gather_module, __import__("ovrad_addon.bake.points", fromlist=["x"])):
        real = module.direct_irradiance

        def spy(source, rays, lt, points, *args, _real=real, **kw):
            asked.append(np.asarray(points).reshape(-1, 3).copy())
            return _real(source, rays, lt, points, *args, **kw)

        monkeypatch.setattr(module, "direct_irradiance", spy)
    hits = []
    real_near = gather_module._near_values

    def near_spy(problem, near, cache, points, *args):
        hits.append(np.asarray(points).copy())
        return real_near(problem, near, cache, points, *args)

    monkeypatch.setattr(gather_module, "_near_values", near_spy)
    on_glow = np.array([[0.5, 0.5, 1.0], [0.2, 0.7, 1.0], [1.0, 0.4, 0.6]])  # top, top, the +x side
    tri = np.array(
        [
            np.flatnonzero((o == 1) & np.isclose(s.corners[:, :, 2], 1.0).all(axis=1))[0],
            np.flatnonzero((o == 1) & np.isclose(s.corners[:, :, 2], 1.0).all(axis=1))[1],
            np.flatnonzero((o == 1) & np.isclose(s.corners[:, :, 0], 1.0).all(axis=1))[0],
        ]
    )
    glow = radiance_at(problem, request, on_glow, tri, 1)
    np.testing.assert_allclose(glow, L_e, rtol=1e-12)
    assert not asked  # nothing asked at the emitter's own points
    beside = np.array([[1.02, 0.5, 0.0], [1.3, 0.8, 0.0]])
    floor = radiance_at(problem, request, beside, floor_triangles(s, beside), 1)
    assert np.all(floor > 0.1) and np.all(np.isfinite(floor))

    def on_block(p):
        return np.all((p > -1e-6) & (p < 1 + 1e-6), axis=1) & (p[:, 2] > 1e-6)

    assert np.sum(on_block(np.concatenate(hits))) > 10  # the floor points' near hits on the glow ...
    assert not np.any(on_block(np.concatenate(asked)))  # ... asked no light
