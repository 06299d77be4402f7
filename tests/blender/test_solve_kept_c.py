"""C integrated once: Generate keeps each atlas's overlap matrix on its edges, the file keeps it, and a
solve after reloading uses it and gives the solve that integrates it again; a stale one is not used."""

from __future__ import annotations

import blender_scenes
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

KEY = "ovrad_overlap_key"
CONTACTS = "ovrad_contacts"
RECEIVERS = ("Floor", "Box")


def build():
    """A lit floor with a closed box standing on it (its bottom lies on the floor) and a card above
    that has no atlas (the solve gives it an environment atlas)."""
    scene = bpy.context.scene
    scene.ovrad.patch_count = 250
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    floor = bpy.context.active_object
    floor.name = "Floor"
    floor.data.materials.append(blender_scenes.principled("grey", base=(0.6, 0.6, 0.6)))
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.6, 0.2, 0.5))
    box = bpy.context.active_object
    box.name = "Box"
    box.data.materials.append(blender_scenes.principled("white", base=(0.8, 0.8, 0.8)))
    bpy.ops.mesh.primitive_plane_add(size=1.5, location=(-0.8, -0.5, 1.6))
    bpy.context.active_object.name = "Card"
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.data.energy = 300.0
    lamp.location = (0.5, -0.5, 2.5)
    scene.collection.objects.link(lamp)
    blender_scenes.select(floor, box)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}


def atlas_objects():
    return sorted((o for o in bpy.data.objects if "ovrad_source" in o), key=lambda o: o.name)


def solve(ovrad):
    """Solve as after opening the file (no prepared problem in memory); (stats, radiosity per atlas)."""
    ovrad.operators.solution.clear_cache()
    jobs = []
    remove = ovrad.operators.solve.add_listener(jobs.append)
    try:
        assert bpy.ops.ovrad.solve() == {"FINISHED"}
    finally:
        remove()
    out = {o.name: blender_scenes.color_values(o.data, "ovrad_radiosity")[:, :3] for o in atlas_objects()}
    return jobs[-1].stats(), out


def patches(*names):
    return sum(len(bpy.data.objects[n].data.vertices) for n in names)


def load(path):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=str(path))


def reopen(path):
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    load(path)


@pytest.fixture
def integrated(ovrad, monkeypatch):
    """The rows of C each solve integrates (radiosity.problem's overlap_matrix: the rows it is
    asked for, the whole atlas when none are named); a kept C's rows are not integrated again."""
    problem = ovrad.ovrad_addon.radiosity.problem
    calls, real = [], problem.overlap_matrix

    def counted(atlas, *args, rows=None, **kwargs):
        calls.append(len(atlas) if rows is None else len(rows))
        return real(atlas, *args, rows=rows, **kwargs)

    monkeypatch.setattr(problem, "overlap_matrix", counted)
    return calls


@pytest.fixture
def saved(ovrad, fresh_scene, tmp_path, integrated):
    """The scene generated, saved, solved once (which adds the environment atlas), saved again."""
    build()
    path = tmp_path / "kept.blend"
    reopen(path)
    stats, _ = solve(ovrad)
    # the receivers' C kept by Generate, the environment's from its building in this solve
    assert stats["overlaps_kept"] == patches("Floor_ovrad_atlas", "Box_ovrad_atlas", "ovrad_environment")
    assert sum(integrated) == 0  # the environment atlas's C was built with it
    integrated.clear()
    reopen(path)
    return path


def test_the_kept_c_gives_the_solve_that_integrates_it_again(saved, ovrad, integrated):
    kept_stats, kept = solve(ovrad)
    n = sum(len(v) for v in kept.values())
    assert len(kept) == 3 and kept_stats["overlaps_kept"] == n and not kept_stats["form_factors_reused"]
    assert sum(integrated) == 0
    # the same file without the kept C (as an atlas made before it was kept): integrated again
    for obj in atlas_objects():
        del obj.data[KEY]
    fresh_stats, fresh = solve(ovrad)
    assert fresh_stats["overlaps_kept"] == 0
    assert sum(integrated) == n  # every patch's row integrated, in one call or several
    top = max(np.abs(v).max() for v in fresh.values())
    assert top > 0
    for name, values in fresh.items():
        # float32 attributes both; the kept C moves the answer by about 1e-8 of it
        np.testing.assert_allclose(kept[name], values, rtol=1e-5, atol=1e-6 * top, err_msg=name)


def test_the_kept_contacts_are_taken(saved, ovrad, monkeypatch):
    """Each atlas keeps its patches' contact flags beside its C, under its key; a solve of the
    reopened file takes them (overlap/contacts.py's rule is never cast). With them removed by hand the kept
    C no longer fits (as with a kept value changed): C is integrated and the contacts found again,
    and the solve is the same. (Blocks kept before the flags were, with keys made without them,
    still fit: test_kept_overlaps.py.)"""
    for obj in atlas_objects():
        attr = obj.data.attributes.get(CONTACTS)
        assert attr is not None and (attr.domain, attr.data_type) == ("POINT", "INT"), obj.name
        assert len(attr.data) == len(obj.data.vertices)
    engine = ovrad.ovrad_addon.overlap.contacts
    rule, cast = engine.coarse_rule, []
    monkeypatch.setattr(engine, "coarse_rule", lambda *a, **k: cast.append(1) or rule(*a, **k))
    kept_stats, kept = solve(ovrad)
    n = sum(len(v) for v in kept.values())
    assert kept_stats["overlaps_kept"] == n and not cast
    for obj in atlas_objects():
        obj.data.attributes.remove(obj.data.attributes[CONTACTS])
    fresh_stats, fresh = solve(ovrad)
    assert fresh_stats["overlaps_kept"] == 0 and cast
    top = max(np.abs(v).max() for v in fresh.values())
    for name, values in fresh.items():
        np.testing.assert_allclose(kept[name], values, rtol=1e-5, atol=1e-6 * top, err_msg=name)


def test_an_edited_atlas_or_moved_geometry_is_integrated_again(saved, ovrad):
    env = patches("ovrad_environment")
    # one floor patch moved a little along the floor: the floor's C only
    floor = bpy.data.objects["Floor_ovrad_atlas"].data
    floor.vertices[0].co.x += 0.01
    floor.update()
    stats, _ = solve(ovrad)
    assert stats["overlaps_kept"] == patches("Box_ovrad_atlas") + env
    # the card moved (it has no atlas, but rays meet it): every C is stale, and the environment
    # atlas is built again (its C with it)
    load(saved)
    bpy.data.objects["Card"].location.z += 0.05
    stats, _ = solve(ovrad)
    assert stats["overlaps_kept"] == patches("ovrad_environment")
    # a kept value changed by hand: that atlas's C only
    load(saved)
    box = bpy.data.objects["Box_ovrad_atlas"].data
    c = box.attributes["ovrad_c"].data
    c[0].vector = (c[0].vector[0] * 2.0, c[0].vector[1])
    stats, _ = solve(ovrad)
    assert stats["overlaps_kept"] == patches("Floor_ovrad_atlas") + env


def test_generating_again_replaces_the_kept_c(saved, ovrad):
    before = {o.name: o.data[KEY] for o in atlas_objects()}
    bpy.context.scene.ovrad.patch_count = 180
    blender_scenes.select(bpy.data.objects["Floor"])
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    after = {o.name: o.data[KEY] for o in atlas_objects()}
    assert after["Floor_ovrad_atlas"] != before["Floor_ovrad_atlas"]
    assert after["Box_ovrad_atlas"] == before["Box_ovrad_atlas"]
    stats, _ = solve(ovrad)
    assert stats["overlaps_kept"] == sum(len(o.data.vertices) for o in atlas_objects())


def test_a_coarser_rule_is_kept_with_its_c_through_the_file(ovrad, fresh_scene, tmp_path, monkeypatch):
    """An atlas large enough for the coarse rule (here: every atlas, AtlasSettings.rule_order) keeps
    that rule beside its C; after reopening, a solve whose own choice is the fine rule uses it."""
    rules = ovrad.ovrad_addon.settings
    monkeypatch.setattr(rules, "COARSE_FROM", 1)
    build()
    for name in RECEIVERS:
        mesh = bpy.data.objects[name + "_ovrad_atlas"].data
        assert mesh["ovrad_overlap_quadrature"] == rules.COARSE_QUADRATURE
    monkeypatch.setattr(rules, "COARSE_FROM", 10**9)
    reopen(tmp_path / "coarse.blend")
    stats, _ = solve(ovrad)
    # the environment atlas is built in this solve, its C kept from its building
    assert stats["overlaps_kept"] == patches("Floor_ovrad_atlas", "Box_ovrad_atlas", "ovrad_environment")
    # the rule's record removed: read as the fine rule, the key no longer fits
    for name in RECEIVERS:
        del bpy.data.objects[name + "_ovrad_atlas"].data["ovrad_overlap_quadrature"]
    stats, _ = solve(ovrad)
    assert stats["overlaps_kept"] == patches("ovrad_environment")
