"""Locating an atlas for reconstruction, and the one rule for which side of a triangle a bake
reconstructs (vertex and image bakes alike)."""

import numpy as np

import scenes
from ovrad_addon.bake.points import bake_sides
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.radiosity.problem import locate
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, ObjectSettings


def two_sided_card():
    """An open 2 m x 2 m card (8 triangles) with patches on both of its sides."""
    v, t = scenes.plane(size=2.0, n=2)
    s = Surfaces.from_arrays(v - [1.0, 1.0, 0.0], t, reflectance=[0.5] * 3)
    atlas = build_atlas(s, AtlasSettings(patch_count=60, objects=(ObjectSettings(sides="BOTH"),)))
    return s, atlas


def test_locate_attaches_every_patch_to_a_sheet_without_form_factors():
    s, atlas = two_sided_card()
    problem = locate(s, atlas)
    assert problem.C is None and problem.transport is None and problem.rays == 0
    assert len(problem.atlas) == len(atlas) and np.all(problem.atlas.sheet >= 0)
    # Both sides of the card are sheets of the index, and patches lie on both.
    assert set(problem.index.sheet_side[problem.atlas.sheet]) == {1, -1}


def test_bakes_use_the_front_where_it_has_patches_else_the_back():
    s, atlas = two_sided_card()
    triangles = np.arange(len(s.triangles))
    both = locate(s, atlas)
    back = both.index.sheet_side[both.atlas.sheet] < 0
    assert np.all(bake_sides(both, triangles) == 1)
    assert np.all(bake_sides(locate(s, atlas.select(~back)), triangles) == 1)
    # Patches on the back only (an open mesh seen from behind): the back, on every triangle.
    assert np.all(bake_sides(locate(s, atlas.select(back)), triangles) == -1)


def test_a_triangle_without_area_is_baked_lit_as_blender_shades_it_facing_up():
    """Three points on a line (a zero-area triangle, common in messy meshes) have no normal of their
    own; Blender gives such a face +Z. Its bake points must get the light of a point facing +Z (a
    point lamp's closed form: the floor lies under them, out of their view), not 0 (they were left black:
    no sheet holds them, and the bake read their back)."""
    from dataclasses import replace

    from reference import analytic

    from ovrad_addon.bake.points import BakeRequest, irradiance_at
    from ovrad_addon.light.lamps import Lamp
    from ovrad_addon.radiosity.first_shot import direct_light, solve
    from ovrad_addon.radiosity.problem import prepare
    from ovrad_addon.settings import SolveSettings

    floor_v, floor_t = scenes.plane(size=4.0, n=4)
    line = np.array([[0.25, -0.125, 0.5], [0.375, 0.0, 0.625], [0.5, 0.125, 0.75]])  # exactly on a line
    v, t, obj = scenes.merge([(floor_v - [2.0, 2.0, 0.0], floor_t), (line, np.array([[0, 1, 2]]))])
    s = Surfaces.from_arrays(v, t, object_index=obj, reflectance=[0.5] * 3)
    settings = SolveSettings(gather_rays=64)
    problem = prepare(s, build_atlas(s, AtlasSettings(patch_count=100)), settings)
    degenerate = len(t) - 1
    assert problem.index.charts.chart[degenerate] < 0  # no chart, no sheet, no patch
    lamp = Lamp("POINT", position=(0.1, 0.3, 1.6), power=400.0)
    state = solve(problem, lamps=(lamp,), settings=settings)
    light = replace(direct_light(problem, (lamp,), settings), gather_rays=64)
    tri = np.full(3, degenerate)
    sides = bake_sides(problem, tri)
    assert np.all(sides == 1)
    got = (
        np.pi
        * irradiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), line, tri, sides)[
            :, 0
        ]
    )
    up = np.tile([0.0, 0.0, 1.0], (3, 1))
    want = analytic.point_lamp_irradiance(400.0, (0.1, 0.3, 1.6), line, up)
    np.testing.assert_allclose(got, want, rtol=1e-3)
