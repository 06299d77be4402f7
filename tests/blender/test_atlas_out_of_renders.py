"""Atlas objects are tools of the viewport: a render, a Cycles bake or a glTF export of the file
is the same with them as without them, and files whose atlases still render are mended."""

from __future__ import annotations

import json

import blender_scenes
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

WIDTH, HEIGHT = 48, 36


def _room():
    """A closed grey room lit by a point lamp, a red block on its floor, a camera inside."""
    mat = blender_scenes.principled("grey", (0.7, 0.7, 0.7))
    room = blender_scenes.closed_box("Room", cuts=2, mat=mat)
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(0.3, 0.2, -0.75))
    block = bpy.context.active_object
    block.data.materials.append(blender_scenes.principled("red", (0.8, 0.1, 0.1)))
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.data.energy = 200.0
    lamp.location = (0.0, 0.0, 0.6)
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    cam.location = (0.0, -0.9, 0.0)
    cam.rotation_euler = (np.pi / 2, 0.0, 0.0)
    for obj in (lamp, cam):
        bpy.context.scene.collection.objects.link(obj)
    bpy.context.scene.camera = cam
    return room, block


def _render(path) -> np.ndarray:
    """The scene rendered by Cycles on the CPU with a fixed seed, as float pixels (h, w, 4)."""
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 4
    scene.cycles.seed = 7
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.render.resolution_x, scene.render.resolution_y = WIDTH, HEIGHT
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(path))
    pixels = np.array(image.pixels[:], np.float32).reshape(HEIGHT, WIDTH, 4)
    bpy.data.images.remove(image)
    return pixels


def _atlas_objects(ovrad):
    return ovrad.operators.attributes.atlas_objects()


def test_generate_solve_and_bake_leave_the_render_as_it_was(ovrad, fresh_scene, tmp_path):
    room, block = _room()
    before = _render(tmp_path / "before.png")
    blender_scenes.select(room, block)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}  # Preview stays off
    atlases = _atlas_objects(ovrad)
    assert len(atlases) == 2 and all(not o.hide_get() for o in atlases)  # still shown in the viewport
    after = _render(tmp_path / "after.png")
    assert before.max() > 0.05  # the render sees the lit room, not black
    np.testing.assert_array_equal(after, before)


def test_a_gltf_export_holds_no_ovrad_object(ovrad, fresh_scene, tmp_path):
    room, block = _room()
    blender_scenes.select(room, block)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    path = tmp_path / "scene.gltf"
    assert bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLTF_SEPARATE") == {"FINISHED"}
    exported = {n.get("name") for n in json.loads(path.read_text())["nodes"]}
    assert {"Room", "Block" if "Block" in exported else block.name} <= exported
    atlas_names = {o.name for o in _atlas_objects(ovrad)}
    assert atlas_names and not (atlas_names & exported)
    assert not any("ovrad" in name for name in exported)


def test_atlases_of_an_older_file_are_mended_by_the_next_operator(ovrad, fresh_scene):
    room, block = _room()
    blender_scenes.select(room, block)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    names = ovrad.operators.attributes.NOT_EXPORTED
    for obj in _atlas_objects(ovrad):  # as a file saved by a version that left atlases renderable
        obj.hide_render = False
        bpy.data.collections[names].objects.unlink(obj)
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    for obj in _atlas_objects(ovrad):
        assert obj.hide_render and bpy.data.collections[names].objects.get(obj.name) is obj
