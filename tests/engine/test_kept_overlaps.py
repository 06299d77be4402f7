"""C kept with the atlas (overlap/kept.py): Generate's C is the C a solve integrates, each atlas
object's block on its own, and a kept block is used only while it still fits."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.sparse import csr_matrix

import scenes
from ovrad_addon import settings as settings_mod
from ovrad_addon.generate.build import build_atlas_and_overlaps
from ovrad_addon.names import SHAPE_BALL
from ovrad_addon.overlap import contacts as contact_mod
from ovrad_addon.overlap.contacts import CUT, WHOLE, contact_flags, contacts
from ovrad_addon.overlap.contacts import contacts as find_contacts
from ovrad_addon.overlap.kept import KeptOverlaps, keep, kept_form, usable
from ovrad_addon.overlap.matrix import overlap_matrix
from ovrad_addon.radiosity.first_shot import solve
from ovrad_addon.radiosity.problem import attach_sheets, both_sides_index, locate, prepare
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import COARSE_QUADRATURE, FINE_QUADRATURE, AtlasSettings, SolveSettings

SETTINGS = AtlasSettings(patch_count=500)
QUADRATURE = SETTINGS.rule_order(SETTINGS.patch_count)  # a small atlas: the fine rule
FAST = SolveSettings(min_rays=0, rays_per_point=8, gather_rays=0)
NAMES = ["room", "box", "partition", "leaves", "ball", "lamp", "shade"]


def busy_room() -> Surfaces:
    """What C is hard on, in one room: a closed box standing on the floor (its bottom lies on the
    floor: coincident faces, patches dropped), an open partition standing on it (contact lines),
    clutter (small bent leaves: ball patches), a sphere (a curved sheet), an emitting quad, and a
    small box that receives no patches (an occluder only)."""
    rng = np.random.default_rng(3)
    parts, objs = list(scenes.box_faces((0, 0, 0), (2, 2, 2), inward=True)), [0] * 6
    box = scenes.box_faces((0.3, 0.3, 0.0), (0.8, 0.7, 0.6))
    parts += box
    objs += [1] * len(box)
    wall = scenes.quad((1.2, 0.2, 0.0), (1.2, 1.2, 0.0), (1.2, 1.2, 1.3), (1.2, 0.2, 1.3))
    parts.append(wall)
    objs.append(2)
    for _ in range(40):
        v, t = scenes.bent_leaf(rng, rng.uniform(0.01, 0.03), 0.3, 2)
        parts.append((v + rng.uniform([0.2, 1.3, 0.3], [0.9, 1.8, 1.5]), t))
        objs.append(3)
    sphere = scenes.sphere(0.2, 2)
    parts.append((sphere.vertices + [1.6, 1.5, 0.6], sphere.triangles))
    objs.append(4)
    parts.append(scenes.quad((0.8, 0.8, 1.95), (0.8, 1.2, 1.95), (1.2, 1.2, 1.95), (1.2, 0.8, 1.95)))
    objs.append(5)
    shade = scenes.box_faces((1.4, 0.3, 1.5), (1.7, 0.6, 1.6))
    parts += shade
    objs += [6] * len(shade)
    v, t, o = scenes.merge(parts, obj=objs)
    emission = np.where(o[:, None] == 5, 8.0, 0.0) * np.ones((1, 3))
    receiver = np.array([True] * 6 + [False])
    return Surfaces.from_arrays(v, t, o, [0.7] * 3, emission, NAMES, receiver)


def moved(s: Surfaces, obj: int, offset) -> Surfaces:
    """The surfaces with object `obj` moved by `offset` (its vertices are its own: merge copies)."""
    v = s.vertices.copy()
    own = np.unique(s.triangles[s.object_index == obj])
    v[own] += offset
    return replace(s, vertices=v)


def by_object(atlas, C):
    """The atlas and C with each object's patches together, as a solve concatenates atlas objects."""
    order = np.argsort(atlas.source_object, kind="stable")
    return atlas.select(order), C[order][:, order]


def blocks(s: Surfaces, atlas, C, flags=None) -> list[KeptOverlaps]:
    """One kept block per object holding patches, as Generate writes them (one atlas object each);
    atlas: by_object()'s; flags: the patches' contact flags (None: kept without, as before them)."""
    out, start = [], 0
    for o in np.unique(atlas.source_object):
        sel = np.flatnonzero(atlas.source_object == o)
        assert np.array_equal(sel, start + np.arange(len(sel))), "an object's patches are together"
        own = None if flags is None else flags[sel]
        out.append(keep(s, atlas.select(sel), C[sel][:, sel], QUADRATURE, SETTINGS.crease_angle, start, own))
        start += len(sel)
    return out


@pytest.fixture(scope="module")
def built():
    s = busy_room()
    out = build_atlas_and_overlaps(s, SETTINGS)
    assert out.quadrature == QUADRATURE == FINE_QUADRATURE
    return s, out


@pytest.fixture(scope="module")
def room(built):
    s, out = built
    return s, out.atlas, out.C


def test_the_scene_has_what_c_is_hard_on(room):
    s, atlas, C = room
    assert set(np.unique(atlas.source_object)) == {0, 1, 2, 3, 4, 5}  # the shade holds none
    assert np.any(atlas.shapes == SHAPE_BALL)
    cut = np.any(np.abs(atlas.anchor - atlas.centers) > 1e-6, axis=1)
    assert np.any(cut), "patches cut at a contact line"


def test_generate_integrates_the_c_a_solve_integrates(room):
    """On the stored atlas, re-attached to the index a solve builds: the same C (the dropped
    patches under the box are gone from both, and their neighbours' rows too), to rounding: 1e-12
    relative, as Generate integrates the rows in other chunks (by object, by degree), and numpy's
    reductions and vector loops may round a value otherwise in arrays of another shape, as the
    CPU's SIMD width decides. A row integrated with another rule or patch differs by 1e-6 or more."""
    s, atlas, C = room
    index = both_sides_index(s, atlas=atlas)
    again, support = overlap_matrix(
        attach_sheets(atlas, index), index, QUADRATURE, find_contacts(attach_sheets(atlas, index), index)
    )
    assert abs(again - C).max() <= 1e-12 * abs(C).max()
    np.testing.assert_allclose(support, atlas.support_area, rtol=1e-12)
    np.testing.assert_allclose(C.diagonal(), atlas.effective_area, rtol=1e-12)


def test_an_objects_rows_do_not_depend_on_the_other_objects(room):
    """Each object's block integrated with its own patches only, in a solve's order (the objects
    in another order): the block Generate integrated with all of them, to rounding (1e-12
    relative, as in the test above)."""
    s, atlas, C = room
    order = np.concatenate([np.flatnonzero(atlas.source_object == o) for o in (4, 2, 0, 3, 1)])
    shuffled = atlas.select(order)
    index = both_sides_index(s, atlas=shuffled)
    together, _ = overlap_matrix(
        attach_sheets(shuffled, index),
        index,
        QUADRATURE,
        find_contacts(attach_sheets(shuffled, index), index),
    )
    assert abs(together - C[order][:, order]).max() <= 1e-12 * abs(C).max()
    for o in (0, 3):
        sel = np.flatnonzero(atlas.source_object == o)
        alone = atlas.select(sel)
        index = both_sides_index(s, atlas=alone)
        block, _ = overlap_matrix(
            attach_sheets(alone, index), index, QUADRATURE, find_contacts(attach_sheets(alone, index), index)
        )
        assert abs(block - C[sel][:, sel]).max() <= 1e-12 * abs(C).max()


def test_the_stored_atlas_is_a_fixed_point(room):
    _, atlas, _ = room
    again = atlas.as_stored()
    for name in ("centers", "normals", "tangents", "radii", "thickness", "min_cos", "random", "anchor"):
        np.testing.assert_array_equal(getattr(again, name), getattr(atlas, name), err_msg=name)


def test_a_kept_block_comes_back_as_c_in_float32(room):
    s, atlas, C = room
    edges, values, diagonal = kept_form(C)
    assert np.all(edges[:, 0] < edges[:, 1])
    k = KeptOverlaps(0, len(atlas), "", edges, values, diagonal)
    back = k.matrix()
    assert back.nnz == C.nnz
    assert abs(back - C).max() <= 2.0**-24 * abs(C).max()


def test_a_block_without_overlaps_is_kept_too():
    # patches that overlap nothing (the environment atlas of a few small separate cubes): no edges
    C = csr_matrix(np.diag([0.5, 0.25, 0.125]))
    edges, values, diagonal = kept_form(C)
    assert edges.shape == (0, 2) and values.shape == (0, 2)
    back = KeptOverlaps(0, 3, "", edges, values, diagonal).matrix()
    assert abs(back - C).max() == 0.0


def test_a_solve_with_the_kept_c_is_the_solve_that_integrates_it(room):
    s, atlas, C = room
    atlas, C = by_object(atlas, C)
    kept = blocks(s, atlas, C)
    fresh = prepare(s, atlas, FAST)
    reused = prepare(s, atlas, FAST, kept=kept)
    assert (fresh.kept, reused.kept) == (0, len(atlas))
    assert abs(reused.C - fresh.C).max() <= 1e-6 * abs(fresh.C).max()
    # the support areas are the kept C's row sums: exactly, as the integrated C's are to rounding
    np.testing.assert_allclose(
        reused.atlas.support_area, np.asarray(reused.C.sum(axis=1)).ravel(), rtol=1e-15
    )
    np.testing.assert_allclose(reused.atlas.support_area, fresh.atlas.support_area, rtol=1e-6)
    a = solve(fresh, settings=FAST).radiosity
    b = solve(reused, settings=FAST).radiosity
    assert np.abs(a).max() > 0
    np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-8 * np.abs(a).max())  # 1e-8 measured


def test_stale_blocks_are_integrated_again(room):
    s, atlas, C = room
    atlas, C = by_object(atlas, C)
    kept = blocks(s, atlas, C)
    n = len(atlas)
    assert usable(s, atlas, kept)[0].all()
    # an occluder moved (it holds no patch, yet rays meet it): every block is stale
    assert not usable(moved(s, 6, [0.0, 0.0, -0.01]), atlas, kept)[0].any()
    # another rule
    assert not usable(s, atlas, [replace(k, quadrature=k.quadrature + 1) for k in kept])[0].any()
    # one patch of the partition edited: its block only
    k = int(np.flatnonzero(atlas.source_object == 2)[0])
    radii = atlas.radii.copy()
    radii[k] *= 1.001
    known, _ = usable(s, replace(atlas, radii=radii), kept)
    np.testing.assert_array_equal(known, atlas.source_object != 2)
    # a kept value changed, or a block for other patches (another atlas object's place)
    values = kept[0].values.copy()
    values[0, 0] *= 1.5
    known, _ = usable(s, atlas, [replace(kept[0], values=values), *kept[1:]])
    np.testing.assert_array_equal(known, atlas.source_object != 0)
    known, _ = usable(s, atlas, [replace(kept[0], start=kept[1].start)])
    assert not known.any()
    # what prepare() does with a partly stale set: it integrates the rest, as it would all of C
    problem = prepare(s, replace(atlas, radii=radii), FAST, kept=kept)
    assert problem.kept == n - int(np.sum(atlas.source_object == 2))
    index = both_sides_index(s, atlas=atlas)
    full, _ = overlap_matrix(
        attach_sheets(replace(atlas, radii=radii), index),
        index,
        QUADRATURE,
        find_contacts(attach_sheets(replace(atlas, radii=radii), index), index),
    )
    assert abs(problem.C - full).max() <= 1e-6 * abs(full).max()


def test_generate_gives_the_contacts_a_solve_finds(built):
    """The contact flags Generate integrated C with are those a solve's index finds for the stored
    atlas, patch for patch (overlap.contacts.contacts), in a scene with cut patches (the partition)."""
    s, out = built
    index = both_sides_index(s, atlas=out.atlas)
    found = contacts(attach_sheets(out.atlas, index), index)
    np.testing.assert_array_equal(contact_flags(found), out.contacts)
    assert np.any(out.contacts & CUT) and np.any(out.contacts & WHOLE)
    np.testing.assert_array_equal(found.anchor, out.atlas.anchor)


def test_a_solve_takes_the_kept_contacts(built, monkeypatch):
    """With every kept block fitting, a solve finds no contact again (the rule contacts() casts is
    never called) and its contacts are those found afresh; with one block stale, that block's
    patches' contacts are found again and the others kept, the same as all found afresh."""
    s, out = built
    order = np.argsort(out.atlas.source_object, kind="stable")
    atlas, C, flags = out.atlas.select(order), out.C[order][:, order], out.contacts[order]
    kept = blocks(s, atlas, C, flags)

    def fresh(a):
        index = both_sides_index(s, atlas=a)
        return contacts(attach_sheets(a, index), index)

    def same(c, d):
        for f in ("anchor", "lift", "cut", "whole", "covered"):
            np.testing.assert_array_equal(getattr(c, f), getattr(d, f), err_msg=f)

    expected = fresh(atlas)
    with monkeypatch.context() as m:
        m.setattr(contact_mod, "coarse_rule", lambda *a, **k: pytest.fail("contacts found again"))
        problem = prepare(s, atlas, FAST, kept=kept)
        assert problem.kept == len(atlas)
        same(problem.contacts, expected)
        # a bake of a reopened file (locate) takes them too
        located = locate(s, atlas, kept=kept)
        same(located.contacts, expected)
    # one patch of the partition edited: its block is integrated, its contacts found, again
    k = int(np.flatnonzero(atlas.source_object == 2)[0])
    radii = atlas.radii.copy()
    radii[k] *= 1.001
    edited = replace(atlas, radii=radii)
    problem = prepare(s, edited, FAST, kept=kept)
    assert problem.kept == len(atlas) - int(np.sum(atlas.source_object == 2))
    same(problem.contacts, fresh(edited))
    # kept flags edited: that block no longer fits
    bad = kept[2].contacts.copy()
    bad[0] ^= CUT
    known, _ = usable(s, atlas, [*kept[:2], replace(kept[2], contacts=bad), *kept[3:]])
    np.testing.assert_array_equal(known, atlas.source_object != atlas.source_object[kept[2].start])


def test_a_large_atlas_keeps_the_coarser_rule_it_was_integrated_with(monkeypatch):
    """Generate integrates a large atlas's C with the coarse rule (AtlasSettings.rule_order; here
    every atlas counts as large) and keeps that rule with the block; a solve uses the block, checked
    with its own rule, even where its own choice for the atlas would be the fine one."""
    s = scenes.cornell()
    monkeypatch.setattr(settings_mod, "COARSE_FROM", 1)
    atlas, C, quadrature, _ = build_atlas_and_overlaps(s, AtlasSettings(patch_count=300))
    assert quadrature == COARSE_QUADRATURE
    index = both_sides_index(s, atlas=atlas)
    coarse, _ = overlap_matrix(
        attach_sheets(atlas, index),
        index,
        COARSE_QUADRATURE,
        find_contacts(attach_sheets(atlas, index), index),
    )
    fine, _ = overlap_matrix(
        attach_sheets(atlas, index), index, FINE_QUADRATURE, find_contacts(attach_sheets(atlas, index), index)
    )
    assert abs(coarse - C).max() <= 1e-12 * abs(C).max()  # to rounding (other chunks)
    assert abs(fine - C).max() > 1e-6 * abs(C).max()  # the rules differ
    kept = [keep(s, atlas, C, quadrature, SETTINGS.crease_angle)]
    monkeypatch.setattr(settings_mod, "COARSE_FROM", 10**9)
    problem = prepare(s, atlas, FAST, kept=kept)
    assert problem.kept == len(atlas)
    assert abs(problem.C - C).max() <= 2.0**-24 * abs(C).max()  # the block, back from float32
    # without it, the solve integrates C with its own choice, the fine rule
    alone = prepare(s, atlas, FAST)
    assert alone.kept == 0
    assert abs(alone.C - fine).max() <= 1e-12 * abs(fine).max()


def test_patches_holding_almost_none_of_their_support_are_dropped(monkeypatch):
    """Generate drops a patch whose alpha averages under MIN_OWN_SHARE over its support (c_kk /
    A_k: it hangs almost wholly off its piece and others hold the light where it lies; its B is
    left free to ring in the solve). With the share raised to catch some in the busy room (smooth
    beta): none kept is under it, some were dropped, and the C kept is the one a solve integrates
    on the stored atlas, its dropped patches' neighbours integrated again without them."""
    from ovrad_addon.generate import build as atlas_mod

    s = busy_room()
    settings = replace(SETTINGS, beta="smooth")
    monkeypatch.setattr(atlas_mod, "MIN_OWN_SHARE", 0.0)
    plain = build_atlas_and_overlaps(s, settings)
    share = plain.C.diagonal() / plain.atlas.support_area
    assert share.min() < 0.12 < np.percentile(share, 5)  # few patches hold so little
    monkeypatch.setattr(atlas_mod, "MIN_OWN_SHARE", 0.12)
    out = build_atlas_and_overlaps(s, settings)
    assert len(out.atlas) < len(plain.atlas) - np.sum(share < 0.12) // 2
    assert np.all(out.C.diagonal() >= 0.12 * out.atlas.support_area)
    index = both_sides_index(s, atlas=out.atlas)
    again, support = overlap_matrix(
        attach_sheets(out.atlas, index),
        index,
        out.quadrature,
        find_contacts(attach_sheets(out.atlas, index), index),
    )
    assert abs(again - out.C).max() <= 1e-12 * abs(out.C).max()  # to rounding (other chunks)
    np.testing.assert_allclose(support, out.atlas.support_area, rtol=1e-12)
