"""Numerical stability on the hard cases of docs/method.md §4, each against the furnace's closed form
L = L_e / (1 - rho) (tests/reference/analytic.py): coincident patches (C singular), nested
patches, rho = 0.999, and zero-area triangles in the mesh."""

from dataclasses import replace

import numpy as np
import pytest
from reference import analytic

import scenes
from ovrad_addon.atlas.patches import Atlas
from ovrad_addon.bake.points import BakeRequest, radiance_at
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.radiosity.first_shot import solve
from ovrad_addon.radiosity.problem import prepare
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, SolveSettings

LE = 1.0


def furnace(rho: float, extra_triangles: bool = False) -> Surfaces:
    s = scenes.cube(inward=True)
    v, t = s.vertices, s.triangles
    if extra_triangles:  # zero-area triangles: a repeated vertex, and three collinear points
        v = np.vstack([v, [[0.2, 0.3, 0.0], [0.4, 0.3, 0.0], [0.6, 0.3, 0.0]]])
        n = len(s.vertices)
        t = np.vstack([t, [[0, 0, 1], [n, n + 1, n + 2]]])
    return Surfaces.from_arrays(v, t, reflectance=[rho] * 3, emission=[LE] * 3)


def reconstructed(s: Surfaces, atlas: Atlas, settings: SolveSettings | None = None) -> np.ndarray:
    settings = settings or SolveSettings()
    problem = prepare(s, atlas, settings)
    state = solve(problem, (), settings)
    pts, tri = scenes.sample_surface(s, 5000, seed=4)  # by area: never on a zero-area triangle
    return radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1)


@pytest.mark.parametrize("beta", ["box", "smooth"])
def test_coincident_patches_leave_the_furnace_exact(beta):
    # Two copies of the same patch make C singular; B_i - B_j is then undetermined, but the
    # reconstructed radiance is not, and must stay the closed form.
    s = furnace(0.9)
    atlas = build_atlas(s, AtlasSettings(patch_count=150, beta=beta))
    doubled = Atlas.concatenate([atlas, atlas.select(np.arange(0, len(atlas), 7))])
    L = reconstructed(s, doubled)
    assert np.all(np.isfinite(L))
    np.testing.assert_allclose(L, analytic.furnace_radiance(LE, 0.9), rtol=1e-2)


def test_nested_patches_leave_the_furnace_exact():
    # A patch of half the radius at the centre of every fifth patch: nested supports.
    s = furnace(0.9)
    atlas = build_atlas(s, AtlasSettings(patch_count=150, beta="smooth"))
    inner = atlas.select(np.arange(0, len(atlas), 5))
    inner = replace(inner, radii=inner.radii * 0.5)
    L = reconstructed(s, Atlas.concatenate([atlas, inner]))
    np.testing.assert_allclose(L, analytic.furnace_radiance(LE, 0.9), rtol=1e-2)


def test_reflectance_0_999_stays_finite_and_close():
    # L = 1000 L_e: any closure error is amplified about rho / (1 - rho) = 999 times.
    s = furnace(0.999)
    L = reconstructed(s, build_atlas(s, AtlasSettings(patch_count=150)), SolveSettings(tolerance=1e-4))
    assert np.all(np.isfinite(L)) and L.min() > 0
    np.testing.assert_allclose(L, analytic.furnace_radiance(LE, 0.999), rtol=0.05)


def test_zero_area_triangles_change_nothing():
    s = furnace(0.5, extra_triangles=True)
    L = reconstructed(s, build_atlas(s, AtlasSettings(patch_count=150)))
    np.testing.assert_allclose(L, analytic.furnace_radiance(LE, 0.5), rtol=1e-3)
