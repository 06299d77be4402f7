"""Clutter: many small separate pieces are covered by a few ball patches (clutter.py), the patch
count follows the settings instead of the piece count, and the light stays exact."""

from __future__ import annotations

import numpy as np
import pytest

import scenes
from ovrad_addon import names
from ovrad_addon.atlas.clutter import clutter_from_atlas
from ovrad_addon.bake.points import BakeRequest, radiance_at
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.overlap.contacts import contacts as find_contacts
from ovrad_addon.overlap.matrix import overlap_matrix
from ovrad_addon.overlap.queries import alpha_at
from ovrad_addon.radiosity.first_shot import solve
from ovrad_addon.radiosity.problem import both_sides_index, prepare
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, SolveSettings


def cluttered_room(leaves: int = 200, cubes: int = 60, seed: int = 5) -> Surfaces:
    """A closed 2 m room (inward faces) holding open bent leaves and separate tiny closed cubes
    floating apart from each other: objects room, leaves, cubes."""
    rng = np.random.default_rng(seed)
    parts, objs = list(scenes.box_faces((-1, -1, 0), (1, 1, 2), inward=True)), [0] * 6
    for _ in range(leaves):
        size = rng.uniform(0.01, 0.03)  # at most 6 cm across: far below the spacing
        v, t = scenes.bent_leaf(rng, size, 0.3, 2)
        parts.append((v + rng.uniform([-0.8, -0.8, 0.2], [0.8, 0.8, 1.8]), t))
        objs.append(1)
    # cubes on a lattice, so none touches another or a leaf's cube of space
    cells = rng.choice(5 * 5 * 5, size=cubes, replace=False)
    for cell in cells:
        lo = np.array([cell % 5, (cell // 5) % 5, cell // 25]) * 0.3 + [-0.7, -0.7, 0.3]
        box = scenes.box_faces(lo, lo + rng.uniform(0.01, 0.04))
        parts += box
        objs += [2] * len(box)
    v, t, o = scenes.merge(parts, obj=objs)
    return Surfaces.from_arrays(
        v, t, o, reflectance=[0.9] * 3, emission=[2.0] * 3, object_names=["room", "leaves", "cubes"]
    )


@pytest.fixture(scope="module")
def room():
    return cluttered_room()


@pytest.fixture(scope="module")
def atlas(room):
    return build_atlas(room, AtlasSettings(patch_count=300))


def test_the_patch_count_follows_the_settings_not_the_pieces(room, atlas):
    # 200 leaves and 60 cubes make 560 charts; one patch per chart would be far above 300
    index = both_sides_index(room, atlas=atlas)
    assert index.charts.count > 500
    assert len(atlas) < 2 * 300
    ball = atlas.shapes == names.SHAPE_BALL
    assert set(atlas.source_object[ball]) == {1, 2}
    assert not np.any(ball[atlas.source_object == 0])
    # every leaf and cube chart is clutter at Solve, read back from the atlas alone
    clutter = clutter_from_atlas(index, atlas)
    chart_obj = np.zeros(index.charts.count, np.int64)
    ok = index.charts.chart >= 0
    chart_obj[index.charts.chart[ok]] = room.object_index[ok]
    np.testing.assert_array_equal(clutter, chart_obj > 0)


def points_on_pieces(room: Surfaces, count: int, seed: int):
    """Uniform points on random triangles of the leaves and cubes, and a side: either side of a
    leaf (open), the outside of a cube."""
    rng = np.random.default_rng(seed)
    tri = rng.choice(np.flatnonzero(room.object_index > 0), count)
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    c = room.corners[tri]
    pts = c[:, 0] + u[:, None] * (c[:, 1] - c[:, 0]) + v[:, None] * (c[:, 2] - c[:, 0])
    leaves = room.object_index[tri] == 1
    return pts, tri, np.where(leaves & (rng.random(count) < 0.5), -1, 1)


def test_alpha_sums_to_one_on_the_pieces_and_c_holds_their_area(room, atlas):
    index = both_sides_index(room, atlas=atlas)
    problem_atlas = prepare(room, atlas).atlas
    pts, tri, side = points_on_pieces(room, 4000, seed=2)
    a = alpha_at(problem_atlas, index, find_contacts(problem_atlas, index), pts, tri, side)
    np.testing.assert_allclose(np.asarray(a.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    # trace of C over the balls = the area they cover: both sides of every leaf, the outside
    # of every cube (a closed separate cube: its inside is not part of any support)
    C, support = overlap_matrix(problem_atlas, index, 12, find_contacts(problem_atlas, index))
    ball = problem_atlas.shapes == names.SHAPE_BALL
    k = room.corners
    tri_area = 0.5 * np.linalg.norm(np.cross(k[:, 1] - k[:, 0], k[:, 2] - k[:, 0]), axis=1)
    leaves_area = tri_area[room.object_index == 1].sum()
    cubes_area = tri_area[room.object_index == 2].sum()
    expected = 2 * leaves_area + cubes_area
    assert C.diagonal()[ball].sum() == pytest.approx(expected, rel=1e-9)
    np.testing.assert_allclose(np.asarray(C.sum(axis=1)).ravel()[ball], support[ball], rtol=1e-9)


def test_furnace_with_clutter_is_exact(room, atlas):
    problem = prepare(room, atlas)
    state = solve(problem, settings=SolveSettings(tolerance=1e-5))
    pts, tri = scenes.sample_surface(room, 3000, seed=9)
    L = radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1)
    np.testing.assert_allclose(L, 2.0 / (1 - 0.9), rtol=5e-3)
    pts, tri, side = points_on_pieces(room, 3000, seed=3)
    L = radiance_at(problem, BakeRequest(state.radiosity), pts, tri, side)
    np.testing.assert_allclose(L, 2.0 / (1 - 0.9), rtol=5e-3)


def small_cluttered_room(leaves: int = 300, seed: int = 5) -> Surfaces:
    """A closed 40 cm room holding 300 bent leaves of 1-3 cm: at a few hundred patches their
    charts are about the grid's spacing, so how many get a grid changes with it."""
    room, where = ((-0.2, -0.2, 0), (0.2, 0.2, 0.4)), ([-0.15, -0.15, 0.05], [0.15, 0.15, 0.35])
    v, t, o = scenes.leaves_in_a_room(room, leaves, (0.01, 0.03), 0.3, 2, where, seed)
    return Surfaces.from_arrays(
        v, t, o, reflectance=[0.9] * 3, emission=[2.0] * 3, object_names=["room", "leaves"]
    )


@pytest.mark.parametrize("target", [700, 800])
def test_the_patch_count_comes_near_the_target_where_small_charts_bend_the_count(target):
    # the count goes about as 1 / spacing here, not 1 / spacing^2: one correction assuming the
    # square left 828 and 896 patches (18 and 12 % over); corrections with the measured exponent
    # reach 750 and 836
    atlas = build_atlas(small_cluttered_room(), AtlasSettings(patch_count=target))
    assert abs(len(atlas) / target - 1.0) <= 0.1


def curled_strips(count: int = 12, seed: int = 3) -> Surfaces:
    """A closed 2 m room (inward faces) and open strips curled three quarters round (1.5 cm radius,
    3 cm long: 21 cm^2, a seventh of a grid cell at 1 500 patches), floating apart."""
    rng = np.random.default_rng(seed)
    parts, objs = list(scenes.box_faces((-1, -1, 0), (1, 1, 2), inward=True)), [0] * 6
    a = np.linspace(-0.75 * np.pi, 0.75 * np.pi, 13)
    ring = np.column_stack([0.015 * np.cos(a), 0.015 * np.sin(a)])
    v0 = np.concatenate([np.column_stack([ring, np.full(len(a), z)]) for z in (0.0, 0.03)])
    m = len(a)
    lower = [[i, i + 1, m + i + 1] for i in range(m - 1)]
    t0 = np.array(lower + [[i, m + i + 1, m + i] for i in range(m - 1)])
    for k in range(count):
        turn = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(turn), -np.sin(turn), 0], [np.sin(turn), np.cos(turn), 0], [0, 0, 1]])
        parts.append((v0 @ rot.T + [-0.6 + 0.1 * k, 0.2 * (k % 3), 0.8], t0))
        objs.append(1)
    v, t, o = scenes.merge(parts, obj=objs)
    return Surfaces.from_arrays(v, t, o, reflectance=[0.5] * 3, object_names=["room", "strips"])


def test_a_small_curved_piece_is_clutter_so_no_part_of_it_hides_from_its_patch(monkeypatch):
    """A patch on a curved sheet holds the points it meets along its normal: a piece smaller than a
    grid cell that curls round (here three quarters of a tube) hides its flanks behind its own front,
    and its one disk's support left them out (the production room's BoomBox: a knob's front patch
    held nothing, was dropped, and the knob baked black). Curved charts under a quarter cell are clutter
    now: the balls' supports hold the whole of each strip, both sides."""
    from ovrad_addon.atlas import clutter

    s = curled_strips()
    k = s.corners[s.object_index == 1]
    both_sides = np.linalg.norm(np.cross(k[:, 1] - k[:, 0], k[:, 2] - k[:, 0]), axis=1).sum()
    held = []
    for share in (clutter.CURVED_CLUTTER_AREA, clutter.CLUTTER_AREA):  # the rule, then curved as flat
        monkeypatch.setattr(clutter, "CURVED_CLUTTER_AREA", share)
        atlas = prepare(s, build_atlas(s, AtlasSettings(patch_count=1500))).atlas
        strips = atlas.source_object == 1
        assert np.all(atlas.shapes[strips] == names.SHAPE_BALL) == (share > clutter.CLUTTER_AREA)
        # the trace of C over a sheet's patches is the area they cover
        held.append(atlas.effective_area[strips].sum() / both_sides)
    assert held[0] == pytest.approx(1.0, rel=1e-9)
    # curved as flat: one disk per side of each strip, whose support misses the hidden flanks
    # (measured: 67 % of the strips' area held)
    assert held[1] < 0.9


def test_a_patch_far_larger_than_its_piece_still_receives_and_sends_light():
    """Bent leaves a little over the clutter threshold get a disk of their own, about twice their
    size: the transport's coarse rule (two rings of points at 46 and 89 % of the radius) missed all
    but three of them, which then received no light, sent none, and broke the furnace everywhere
    (leaves at E alone, 6.28 against 62.8; the room 49.9-54.7). Finer rings find every one."""
    rng = np.random.default_rng(2)
    parts, objs = list(scenes.box_faces((-1, -1, 0), (1, 1, 2), inward=True)), [0] * 6
    for k in range(12):
        at = np.array([-0.7 + 0.45 * (k % 4), -0.5 + 0.5 * ((k // 4) % 3), 0.6 + 0.1 * (k % 3)])
        v, t = scenes.bent_leaf(rng, 0.08, 0.3, 3)
        parts.append((v + at, t))
        objs.append(1)
    v, t, o = scenes.merge(parts, obj=objs)
    room = Surfaces.from_arrays(
        v, t, o, reflectance=[0.9] * 3, emission=[2.0] * 3, object_names=["room", "leaves"]
    )
    atlas = build_atlas(room, AtlasSettings(patch_count=300))
    problem = prepare(room, atlas)
    leaves = problem.atlas.source_object == 1
    assert leaves.sum() == 24 and not np.any(problem.atlas.shapes[leaves] == names.SHAPE_BALL)
    assert np.all(problem.atlas.radii[leaves] > 2 * 0.08)  # each disk reaches well past its leaf
    points = np.bincount(problem.transport.points.owner, minlength=len(problem.atlas))
    supported = problem.atlas.support_area > 0
    assert np.all(points[supported] > 0)
    B = solve(problem, settings=SolveSettings(tolerance=1e-7)).radiosity
    furnace = np.pi * 2.0 / (1.0 - 0.9)  # B = E / (1 - rho), E the exitance pi x 2
    assert np.allclose(B[supported], furnace, rtol=1e-5)
