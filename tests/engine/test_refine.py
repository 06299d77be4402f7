"""Adaptive patches (generate/refine.py): refining keeps alpha a partition of unity, C's row sums, the
furnace exact, and lowers the error where the solution varies (a lamp's shadow edge, against its
closed form)."""

import numpy as np
import pytest
from test_contact import two_rooms
from test_direct import RHO, closed_form_direct, shadowed_plane_scene

import scenes
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.generate.refine import children, indicator, refine, solve_adaptive
from ovrad_addon.overlap.queries import alpha_at, reconstruct
from ovrad_addon.radiosity.problem import prepare
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, SolveSettings


def test_children_cover_their_parent():
    s = scenes.cube()
    atlas = build_atlas(s, AtlasSettings(patch_count=200, shapes="AUTO", beta="smooth"))
    kids = children(atlas, np.arange(len(atlas)))
    rng = np.random.default_rng(1)
    for shape in (0, 1):
        parent = int(np.flatnonzero(atlas.shapes == shape)[0])
        r = atlas.radii[parent]
        # points over the parent's support, in its plane
        u = rng.uniform(-1, 1, (4000, 2)) * r
        if shape == 0:
            u = u[np.hypot(u[:, 0], u[:, 1]) <= r]
        p = atlas.centers[parent] + u[:, :1] * atlas.tangents[parent] + u[:, 1:] * atlas.bitangents[parent]
        k = slice(5 * parent, 5 * parent + 4)  # the four quadrant children (the fifth: the middle)
        rel = p[:, None, :] - kids.centers[k][None]
        x = np.einsum("mkj,kj->mk", rel, kids.tangents[k])
        y = np.einsum("mkj,kj->mk", rel, kids.bitangents[k])
        rk = kids.radii[k][None]
        inside = (
            np.maximum(np.abs(x), np.abs(y)) <= rk * (1 + 1e-12)
            if shape == 1
            else x * x + y * y <= rk**2 * (1 + 1e-12)
        )
        assert np.all(inside.any(axis=1))
        assert np.allclose(kids.radii[k], r / 2 if shape == 1 else r / np.sqrt(2))
        assert np.isclose(kids.radii[5 * parent + 4], r / 2)
        assert np.allclose(kids.centers[5 * parent + 4], atlas.centers[parent])


@pytest.mark.parametrize("beta", ["box", "smooth"])
def test_refined_atlas_is_a_partition_of_unity_with_exact_row_sums(beta):
    s = two_rooms()  # planar sheets, contact lines, a doorway
    problem = prepare(
        s, build_atlas(s, AtlasSettings(patch_count=500, beta=beta)), SolveSettings(min_rays=1 << 16)
    )
    rng = np.random.default_rng(2)
    B = rng.uniform(0.1, 1.0, (len(problem.atlas), 3))
    finer, k = refine(problem.atlas, problem.index, B, threshold=0.2, budget=0.3, C=problem.C)
    # with C the patches are compared by their supports' mean radiosity (C B)_h / A_h, which averages
    # coefficient noise away: on random coefficients the indicator is far lower than on raw ones
    with_c, without = indicator(problem.atlas, B, problem.C), indicator(problem.atlas, B)
    assert np.mean(with_c) < 0.6 * np.mean(without)
    assert 0.1 * len(problem.atlas) < k <= 0.3 * len(problem.atlas)
    refined = prepare(s, finer, SolveSettings(min_rays=1 << 16), drop_unsupported=True)
    assert len(refined.atlas) > len(problem.atlas) + 2 * k
    pts, tri = scenes.sample_surface(s, 50_000, seed=5)
    on = refined.index.sheet_of(tri, np.ones(len(tri), np.int64)) >= 0
    a = alpha_at(
        refined.atlas, refined.index, refined.contacts, pts[on], tri[on], np.ones(on.sum(), np.int64)
    )
    total = np.asarray(a.sum(axis=1)).ravel()
    assert total.min() > 0.5  # no hole opened by removing the parents
    np.testing.assert_allclose(total, 1.0, atol=1e-9)
    C = refined.C
    np.testing.assert_allclose(np.asarray(C.sum(axis=1)).ravel(), refined.atlas.support_area, rtol=1e-9)
    assert np.all(refined.atlas.support_area > 0)


def test_reciprocity_survives_refinement_in_the_classical_limit():
    """Box-beta squares tiling a cube without overlap, a third of them refined (their four children
    tile them): still a tiling, and G stays symmetric within binomial noise (A_h F_hk = A_k F_kh),
    as test_form_factors checks on the unrefined atlas."""
    s = scenes.cube(inward=True)
    atlas = build_atlas(s, AtlasSettings(patch_size=0.25, overlap=1.0, beta="box", shapes="SQUARES"))
    problem = prepare(s, atlas, SolveSettings(min_rays=1 << 18))
    B = np.random.default_rng(3).uniform(0.1, 1.0, (len(problem.atlas), 3))
    finer, k = refine(problem.atlas, problem.index, B, threshold=-1.0, budget=0.35, C=problem.C)
    assert k > 0.3 * len(problem.atlas)
    # per pair, not per cluster: a cluster link spreads a hit over its patches by area
    refined = prepare(s, finer, SolveSettings(min_rays=1 << 22, cluster_angle=0.0), drop_unsupported=True)
    n = len(refined.atlas)
    assert n == len(problem.atlas) + 3 * k
    C = refined.C.tocsr()
    assert abs(C - C.multiply(np.eye(n) > 0)).sum() < 1e-6 * C.diagonal().sum()  # no overlaps
    T = refined.transport
    G = T.geometric.toarray()
    A = refined.atlas.support_area
    rays = np.bincount(T.points.owner, minlength=n) * (T.rays / len(T.points.owner))
    F = G / A[:, None]
    var = A[:, None] ** 2 * F * (1 - F) / rays[:, None]
    # pairs where both directions expect 25 hits or more: there the binomial counts are near
    # normal (a pair of far small patches expecting 2 hits is not; with 16 M rays instead of 4 M
    # every pair measured z < 3.5, so those tails were counting noise, not bias)
    hits = F * rays[:, None]
    both = (hits > 25) & (hits.T > 25)
    z = np.abs(G - G.T)[both] / np.sqrt(var + var.T)[both]
    assert both.sum() > 10000  # faces see each other: most pairs are compared
    assert z.max() < 4.5


def test_furnace_stays_exact_with_refinement():
    base = scenes.cube(inward=True)
    s = Surfaces.from_arrays(base.vertices, base.triangles, reflectance=[0.9] * 3, emission=[2.0] * 3)
    atlas = build_atlas(s, AtlasSettings(patch_count=200))
    problem, state, replaced = solve_adaptive(
        s, atlas, settings=SolveSettings(tolerance=1e-6), passes=1, threshold=-1.0, budget=0.4
    )
    assert replaced[0] > 0.3 * len(atlas) and len(problem.atlas) > len(atlas)
    pts, tri = scenes.sample_surface(s, 5000, seed=6)
    a = alpha_at(problem.atlas, problem.index, problem.contacts, pts, tri, np.ones(len(tri), np.int64))
    # radiance B / pi = L_e / (1 - rho) everywhere, children and untouched patches alike
    np.testing.assert_allclose(reconstruct(a, state.radiosity) / np.pi, 2.0 / (1 - 0.9), rtol=2e-4)


@pytest.mark.parametrize("beta", ["box", "smooth"])
def test_refining_at_a_shadow_edge_lowers_the_error_there(beta):
    """A plane under a point lamp with a square occluder between (the sharp shadow of
    test_direct): the radiosity from the patches alone (the paper's reconstruction) against the
    closed form rho H / pi, within 10 cm of the shadow's edge. Three passes refine the patches on
    the edge (measured: 400 patches 27 / 25 % (box / smooth); refined to about 2 200, 16 / 15 %;
    1 600 uniform patches, 21 / 11 %: smooth beta blends the large patches next to the refined
    ones into them)."""
    s, lamp = shadowed_plane_scene()
    rng = np.random.default_rng(7)
    pts = np.column_stack([rng.uniform(-1.2, 1.2, 20000), rng.uniform(-1.2, 1.2, 20000), np.zeros(20000)])
    exact, margin = closed_form_direct(pts, np.array(lamp.position), lamp.power)
    want = RHO * exact / np.pi
    edge = margin < 0.1  # within 10 cm of the shadow's edge (the occluder's plane)

    def run(count, passes):
        atlas = build_atlas(s, AtlasSettings(patch_count=count, beta=beta))
        problem, state, _ = solve_adaptive(s, atlas, (lamp,), SolveSettings(min_rays=1 << 18), passes=passes)
        tri = problem.index.rays.closest_hit(pts + [0, 0, 1e-3], np.tile([0, 0, -1.0], (len(pts), 1)), 1.0)[1]
        a = alpha_at(problem.atlas, problem.index, problem.contacts, pts, tri, np.ones(len(pts), np.int64))
        got = reconstruct(a, state.radiosity)[:, 0] / np.pi
        error = np.sqrt(np.mean((got[edge] - want[edge]) ** 2)) / np.sqrt(np.mean(want**2))
        return error, problem.atlas

    coarse, before = run(400, 0)
    adaptive, after = run(400, 3)
    assert adaptive < 0.7 * coarse
    # the new patches went to the edge: small ones lie near it, the far field kept its patches
    small = after.radii < 0.75 * before.radii.min()
    _, near_edge = closed_form_direct(after.centers, np.array(lamp.position), lamp.power)
    assert small.sum() > 100 and np.median(near_edge[small]) < 0.15
    assert len(after) < 8 * len(before)
