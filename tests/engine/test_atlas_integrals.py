"""Partition of unity, overlap coefficients and reconstruction against exact answers."""

from dataclasses import replace

import numpy as np
import pytest

import scenes
from ovrad_addon.atlas.index import index_surfaces
from ovrad_addon.atlas.patches import Atlas
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.overlap.contacts import contacts as find_contacts
from ovrad_addon.overlap.matrix import overlap_matrix
from ovrad_addon.overlap.queries import alpha_at, patch_average, reconstruct
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import FINE_QUADRATURE, AtlasSettings


def surface_area(s: Surfaces) -> float:
    c = s.corners
    return float(0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1).sum())


def lens_area(r: float, d: float) -> float:
    """Area common to two circles of radius r whose centres are d apart (closed form)."""
    return 2 * r * r * np.arccos(d / (2 * r)) - 0.5 * d * np.sqrt(4 * r * r - d * d)


def two_disks(r: float, d: float, beta: str):
    """Two coplanar disks on a large plane, built by hand (not by the placement code)."""
    v, t = scenes.plane(size=4.0)
    s = Surfaces.from_arrays(v, t)
    settings = AtlasSettings(patch_size=1.0, beta=beta)
    index = index_surfaces(s, settings)
    n = 2
    atlas = Atlas(
        centers=np.array([[2.0 - d / 2, 2.0, 0.0], [2.0 + d / 2, 2.0, 0.0]]),
        normals=np.tile([0.0, 0.0, 1.0], (n, 1)),
        tangents=np.tile([1.0, 0.0, 0.0], (n, 1)),
        radii=np.full(n, r),
        shapes=np.zeros(n, np.int8),
        sheet=np.zeros(n, np.int64),
        source_object=np.zeros(n, np.int64),
        thickness=np.full(n, 1e-3 * r),
        min_cos=np.full(n, 0.9),
        support_area=np.zeros(n),
        effective_area=np.zeros(n),
        overlap_count=np.zeros(n, np.int64),
        random=np.array([0.1, 0.7]),
        beta=beta,
    )
    return atlas, index


SCENES = {
    "cube": scenes.cube,
    "sphere": scenes.sphere,
    "cornell": scenes.cornell,
    "thin_wall": scenes.thin_wall_rooms,
}


def test_two_box_disks_overlap_coefficient_is_half_the_lens_area():
    r, d = 0.5, 0.6
    atlas, index = two_disks(r, d, "box")
    lens = lens_area(r, d)
    # box beta: alpha = 1/2 in the lens, so c_12 = lens / 2 and c_11 = pi r^2 - lens / 2. Each disk's
    # rays are turned by its own random value: the lens's rim falls between them differently at each
    # turn, so each turn's error is the angular rule's (about 2 %), and the turns' mean is unbiased.
    found = []
    for turn in np.arange(10) / 10:
        turned = replace(atlas, random=np.array([turn, (turn + 0.35) % 1]))
        C, support = overlap_matrix(turned, index, FINE_QUADRATURE, find_contacts(turned, index))
        found.append([C[0, 1], C[1, 0], C[0, 0]])
        np.testing.assert_allclose(support, np.pi * r * r, rtol=1e-12)
    found = np.array(found)
    expected = np.array([lens / 2, lens / 2, np.pi * r * r - lens / 2])
    np.testing.assert_allclose(found, np.tile(expected, (10, 1)), rtol=2.5e-2)
    np.testing.assert_allclose(found.mean(axis=0), expected, rtol=2e-3)


def test_paper_figure3_box_beta_averages_and_smooth_beta_blends():
    r, d = 0.5, 0.6
    red_green = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    x = np.linspace(2.0 - d / 2 - r + 1e-6, 2.0 + d / 2 + r - 1e-6, 801)
    pts = np.stack([x, np.full_like(x, 2.0), np.zeros_like(x)], 1)
    lens = np.abs(x - 2.0) < r - d / 2
    for beta in ("box", "smooth"):
        atlas, index = two_disks(r, d, beta)
        a = alpha_at(
            atlas, index, find_contacts(atlas, index), pts, np.zeros(len(x), np.int64), np.ones(len(x))
        )
        colour = reconstruct(a, red_green)
        np.testing.assert_allclose(colour.sum(axis=1), 1.0, atol=1e-12)
        left_only = x < 2.0 + d / 2 - r
        np.testing.assert_allclose(colour[left_only], np.tile([1.0, 0, 0], (left_only.sum(), 1)), atol=1e-12)
        if beta == "box":
            np.testing.assert_allclose(colour[lens], np.tile([0.5, 0.5, 0], (lens.sum(), 1)), atol=1e-12)
        else:
            red = colour[lens, 0]
            assert np.all(np.diff(red) < 0), "smooth beta blends monotonically from red to green"
            assert red[0] > 0.99 and red[-1] < 0.01
            assert np.abs(np.diff(colour[:, 0])).max() < 0.02, "no jump anywhere along the line"


@pytest.mark.parametrize("name", sorted(SCENES))
@pytest.mark.parametrize("beta", ["box", "smooth"])
def test_alpha_is_a_partition_of_unity_and_atlas_covers_every_point(name, beta):
    s = SCENES[name]()
    settings = AtlasSettings(patch_count=800, beta=beta)
    atlas = build_atlas(s, settings)
    index = index_surfaces(s, settings)
    pts, tri = scenes.sample_surface(s, 100_000, seed=3)
    checked = 0
    for side in (1, -1):
        sides = np.full(len(tri), side)
        on = index.sheet_of(tri, sides) >= 0
        if not on.any():
            continue
        a = alpha_at(atlas, index, find_contacts(atlas, index), pts[on], tri[on], sides[on])
        total = np.asarray(a.sum(axis=1)).ravel()
        assert total.min() > 0.5, f"{(total < 0.5).sum()} sampled points are in no patch (holes)"
        np.testing.assert_allclose(total, 1.0, atol=1e-9)
        checked += on.sum()
    assert checked >= 100_000


@pytest.mark.parametrize("name", sorted(SCENES))
def test_overlap_rows_sum_to_support_area_and_effective_areas_to_surface_area(name):
    s = SCENES[name]()
    settings = AtlasSettings(patch_count=800)
    atlas = build_atlas(s, settings)
    index = index_surfaces(s, settings)
    C, support = overlap_matrix(atlas, index, settings.rule_order(len(atlas)), find_contacts(atlas, index))
    np.testing.assert_allclose(np.asarray(C.sum(axis=1)).ravel(), support, rtol=1e-9)
    # every patch sheet is one side of the surface: sum of c_kk = area of the covered sides
    sides = (index.sheet_table >= 0).sum(axis=1)
    covered = float(
        (index.charts.areas * sides[np.maximum(index.charts.chart, 0)] * (index.charts.chart >= 0)).sum()
    )
    assert atlas.effective_area.sum() == pytest.approx(covered, rel=5e-3)
    assert np.all(atlas.effective_area > 0)
    if name == "cube":
        assert covered == pytest.approx(surface_area(s), rel=1e-12)


def test_support_areas_match_closed_forms_on_a_cube():
    atlas = build_atlas(scenes.cube(), AtlasSettings(patch_count=600))
    disk = atlas.shapes == 0
    square = ~disk
    assert disk.any() and square.any()
    # interior disks lie wholly on their face; squares are pulled inside the face: no clipping
    np.testing.assert_allclose(atlas.support_area[disk], np.pi * atlas.radii[disk] ** 2, rtol=1e-3)
    np.testing.assert_allclose(atlas.support_area[square], 4 * atlas.radii[square] ** 2, rtol=1e-3)


def test_rows_of_repeated_configurations_are_copied_without_losing_accuracy():
    # On the Cornell box (blocks resting on the floor, next to walls) the rows of plain interior
    # disks that repeat a configuration are copied from one integrated member: C is as close to a
    # finer rule's (q = 24, integrated row by row) as integrating every row, and every support
    # area stays within a sliver of its own integral (a footprint the coarse test missed).
    from ovrad_addon.radiosity.problem import attach_sheets

    s = scenes.cornell()
    settings = AtlasSettings(patch_count=6000)
    index = index_surfaces(s, settings)
    atlas = attach_sheets(build_atlas(s, settings), index)
    C_copy, A_copy = overlap_matrix(atlas, index, 12, find_contacts(atlas, index), reuse=True)
    C_all, A_all = overlap_matrix(atlas, index, 12, find_contacts(atlas, index), reuse=False)
    C_fine, _ = overlap_matrix(atlas, index, 24, find_contacts(atlas, index), reuse=False)

    def error(C):
        return np.sqrt((C - C_fine).power(2).sum() / C_fine.power(2).sum())

    assert error(C_copy) < 1.05 * error(C_all)
    np.testing.assert_allclose(A_copy, A_all, rtol=0.01)
    np.testing.assert_allclose(np.asarray(C_copy.sum(axis=1)).ravel(), A_copy, rtol=1e-12, atol=1e-15)
    # a good share of the rows was copied; they differ from their own integrals by the rule's turn only
    from ovrad_addon.overlap.matrix import neighbour_pairs, repeated_rows

    h, i = neighbour_pairs(atlas)
    copied = sum(
        len(b.member)
        for b in repeated_rows(
            atlas, index, find_contacts(atlas, index), h, i, np.searchsorted(h, np.arange(len(atlas) + 1))
        )
    )
    assert copied > 0.3 * len(atlas)
    same = np.isclose(A_copy, A_all, rtol=1e-9)
    assert same.mean() > 0.999


def strip_area(r: float, w: float) -> float:
    """Area of a circle of radius r within a strip of width w through its centre (closed form)."""
    y = w / 2
    return 2 * (y * np.sqrt(r * r - y * y) + r * r * np.arcsin(y / r))


@pytest.mark.parametrize("width", [0.05, 0.1, 0.3])
def test_support_of_a_disk_on_a_strip_narrower_than_its_rule_matches_the_closed_form(width):
    # a disk of radius 0.5 centred on a strip 0.05-0.3 wide: the support is cut on nearly every
    # rule ray, at a tenth of the radius for the narrowest, inside the coarse rule's first ring.
    # The cuts found along each ray (overlap.cuts.support_cuts) give the area to the angular rule's
    # error per turn of the rays (about 6 % at the narrowest), and the turns' mean within 0.5 %
    # (splitting the cut rays into 2q rings instead was 2.6-3.1 % off on average at 0.05 and 0.1)
    r = 0.5
    v = np.array([[0, -width / 2, 0], [4, -width / 2, 0], [4, width / 2, 0], [0, width / 2, 0]], float)
    s = Surfaces.from_arrays(v, np.array([[0, 1, 2], [0, 2, 3]]))
    index = index_surfaces(s, AtlasSettings(patch_size=1.0))
    atlas = Atlas(
        centers=np.array([[2.0, 0.0, 0.0]]),
        normals=np.array([[0.0, 0.0, 1.0]]),
        tangents=np.array([[1.0, 0.0, 0.0]]),
        radii=np.array([r]),
        shapes=np.zeros(1, np.int8),
        sheet=np.zeros(1, np.int64),
        source_object=np.zeros(1, np.int64),
        thickness=np.array([1e-3 * r]),
        min_cos=np.array([0.9]),
        support_area=np.zeros(1),
        effective_area=np.zeros(1),
        overlap_count=np.zeros(1, np.int64),
        random=np.array([0.0]),
        beta="smooth",
    )
    exact = strip_area(r, width)
    q = FINE_QUADRATURE
    turns = [replace(atlas, random=np.array([t])) for t in np.arange(10) / 10]
    found = [overlap_matrix(a, index, q, find_contacts(a, index))[1][0] for a in turns]
    np.testing.assert_allclose(found, exact, rtol=0.07)
    np.testing.assert_allclose(np.mean(found), exact, rtol=5e-3)


def test_patch_average_of_a_field_on_a_few_sheets_skips_only_patches_it_cannot_reach():
    """The Cornell box's emission is on its lamp only, so patch_average integrates the lamp's
    sheets alone; shifted by 1 everywhere, every patch is integrated: the two must differ by
    exactly 1 on every patch (a patch left out wrongly would read 0 against its mean - 1)."""
    s = scenes.cornell()
    atlas = build_atlas(s, AtlasSettings(patch_count=300))
    index = index_surfaces(s, AtlasSettings(patch_count=300))
    lamp = s.emission
    assert 0 < np.count_nonzero(lamp.any(axis=1)) < len(lamp) // 10
    few = patch_average(atlas, index, find_contacts(atlas, index), lamp)
    every = patch_average(atlas, index, find_contacts(atlas, index), lamp + 1.0)
    np.testing.assert_allclose(every - 1.0, few, atol=1e-12)
    assert np.count_nonzero(few.any(axis=1)) > 0
