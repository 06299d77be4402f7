"""Locating an atlas for reconstruction, and the one rule for which side of a triangle a bake
reconstructs (vertex and image bakes alike)."""

import numpy as np

import scenes
from ovrad_addon.atlas import build_atlas
from ovrad_addon.pipeline import bake_sides, locate
from ovrad_addon.settings import AtlasSettings, ObjectSettings
from ovrad_addon.surfaces import Surfaces


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
