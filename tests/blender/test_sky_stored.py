"""What a solve's transport learned of the sky is kept with the atlases: a bake after the file is
reopened (no transport in memory) casts sky rays where the bake right after the solve does, so it
gives the same light, and a closed room under a world casts none."""

from __future__ import annotations

import blender_scenes
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender


def grey_world(scene, strength=1.0):
    w = bpy.data.worlds.new("Grey")
    if w.node_tree is None:
        w.use_nodes = True  # Blender < 5.0
    bg = w.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.05, 0.05, 0.05, 1.0)
    bg.inputs["Strength"].default_value = strength
    scene.world = w


def lamp(energy, location):
    obj = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    obj.data.energy = energy
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)


def solve_and_bake(receivers):
    blender_scenes.select(*receivers)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    return bake(receivers)


def bake(receivers):
    blender_scenes.select(*receivers)
    assert bpy.ops.ovrad.bake_vertex(attribute="sky_test") == {"FINISHED"}
    return {o.name: blender_scenes.color_values(o.data, "sky_test")[:, :3].copy() for o in receivers}


def reopen(ovrad, path):
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    ovrad.operators.solution.clear_cache()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=str(path))


def test_a_bake_after_reopening_casts_sky_rays_where_the_solve_said(ovrad, fresh_scene, tmp_path):
    """A floor and a box under a dim grey world (sky irradiance 0.04 W/m^2), lit by a lamp (10 W/m^2
    below it, about 1 at the far corner): the patches near the lamp get under 1 % of their light
    from the sky and bake without sky rays, the far ones with; after reopening, the same."""
    scene = fresh_scene
    scene.ovrad.patch_count = 300
    grey_world(scene, strength=0.25)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=24, y_subdivisions=24, size=4.0)
    floor = bpy.context.active_object
    floor.name = "Floor"
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.3, 0.2, 0.5))
    box = bpy.context.active_object
    box.name = "Box"
    lamp(500.0, (0.5, -0.6, 2.0))
    before = solve_and_bake([floor, box])
    atlases = [o for o in bpy.data.objects if o.get("ovrad_source") in ("Floor", "Box")]
    sky = np.concatenate([_ints(o.data, "ovrad_sky") for o in atlases])
    # the stored choice is not trivial here: some patches cast sky rays, others do not
    assert 0 < sky.sum() < len(sky)
    assert all(o["ovrad_escaped"] > 0 for o in atlases)  # the scene is open
    reopen(ovrad, tmp_path / "open.blend")
    light = ovrad.operators.solution.load_solution(bpy.context).light
    assert light.sky is not None and light.sky_patches is not None
    np.testing.assert_array_equal(light.sky_patches.astype(int), sky)
    after = bake([bpy.data.objects["Floor"], bpy.data.objects["Box"]])
    top = max(v.max() for v in before.values())
    assert top > 0
    for name, values in before.items():
        # the same rules, the same rays: the same light (a reopened bake that did not read the
        # stored sky patches would cast sky rays at every patch and move vertices by up to the 1 %
        # share left out)
        np.testing.assert_allclose(after[name], values, rtol=1e-6, atol=1e-7 * top, err_msg=name)


def _ints(mesh, name):
    attr = mesh.attributes[name]
    out = np.empty(len(attr.data), np.int32)
    attr.data.foreach_get("value", out)
    return out


def test_a_closed_room_under_a_world_bakes_without_sky_after_reopening(ovrad, fresh_scene, tmp_path):
    scene = fresh_scene
    scene.ovrad.patch_count = 200
    grey_world(scene, strength=5.0)
    room = blender_scenes.closed_box("Room", cuts=2, mat=blender_scenes.principled("white"))
    lamp(100.0, (0.2, 0.1, 0.3))
    before = solve_and_bake([room])
    atlas = next(o.name for o in bpy.data.objects if o.get("ovrad_source") == "Room")
    assert bpy.data.objects[atlas]["ovrad_escaped"] == 0
    reopen(ovrad, tmp_path / "closed.blend")
    assert bpy.data.objects[atlas]["ovrad_escaped"] == 0
    light = ovrad.operators.solution.load_solution(bpy.context).light
    assert light.sky is None  # no transport ray left the room: its bakes cast no sky rays
    after = bake([bpy.data.objects["Room"]])
    np.testing.assert_allclose(after["Room"], before["Room"], rtol=1e-6, atol=1e-9)
