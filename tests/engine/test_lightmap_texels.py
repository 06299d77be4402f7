"""Lightmap UV checks and image sizes from a texel density (bake/texels.py), against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from ovrad_addon import OvradError
from ovrad_addon import texels as bake

# A 2 x 3 m rectangle in the XY plane as two triangles, and a UV map of it.
WORLD = np.array([[[0, 0, 0], [2, 0, 0], [2, 3, 0]], [[0, 0, 0], [2, 3, 0], [0, 3, 0]]], float)


def uv_of(lo, hi):
    """The rectangle mapped onto the UV box lo..hi (corners in the same order as WORLD)."""
    (u0, v0), (u1, v1) = lo, hi
    return np.array([[[u0, v0], [u1, v0], [u1, v1]], [[u0, v0], [u1, v1], [u0, v1]]], float)


def test_density_size_is_the_density_times_the_world_over_uv_scale_rounded_up_to_four():
    # the whole unit square over 6 m^2: sqrt(6) m per UV unit; 10 texels/m -> 24.49 -> 28
    assert bake.density_size(uv_of((0, 0), (1, 1)), WORLD, 10.0) == 28
    # a quarter of the square (half per side): twice the texels per side -> 48.99 -> 52
    assert bake.density_size(uv_of((0, 0), (0.5, 0.5)), WORLD, 10.0) == 52
    assert bake.density_size(uv_of((0, 0), (1, 1)), WORLD, 10.0, multiple=1) == 25
    assert bake.density_size(uv_of((0, 0), (1, 1)), WORLD, 1e-3) == 4  # never below one step
    with pytest.raises(OvradError, match="positive"):
        bake.density_size(uv_of((0, 0), (1, 1)), WORLD, 0.0)
    with pytest.raises(OvradError, match="no area"):
        bake.density_size(np.zeros((2, 3, 2)), WORLD, 10.0)


def test_a_map_inside_the_square_without_overlap_is_fit():
    assert bake.lightmap_problem(uv_of((0, 0), (1, 1)), WORLD, 64, 64) is None
    assert bake.lightmap_problem(uv_of((0.1, 0.2), (0.6, 0.9)), WORLD, 64, 64) is None


def test_outside_the_square_overlapping_or_collapsed_maps_are_unfit():
    assert "outside the unit square" in bake.lightmap_problem(uv_of((0, 0), (3, 3)), WORLD, 64, 64)
    assert "not finite" in bake.lightmap_problem(uv_of((0, 0), (np.nan, 1)), WORLD, 64, 64)
    # two copies of the rectangle on the same UVs: every covered texel is covered twice
    both = np.concatenate([uv_of((0, 0), (1, 1))] * 2)
    why = bake.lightmap_problem(both, np.concatenate([WORLD, WORLD + [0, 0, 1]]), 64, 64)
    assert "overlap" in why and "100.0 %" in why
    # one triangle collapsed to a line in UV space: half of the area has no texels
    flat = uv_of((0, 0), (1, 1))
    flat[1] = [[0, 0], [0.5, 0.5], [1, 1]]
    assert "50.0 %" in bake.lightmap_problem(flat, WORLD, 64, 64)
