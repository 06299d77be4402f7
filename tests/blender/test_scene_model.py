"""Real scenes: instances (collection, geometry nodes) and meshes without an atlas reflect and
shadow, linked duplicates bake once or are skipped, and one bad object never stops a bake."""

from __future__ import annotations

import sys
from pathlib import Path

import blender_scenes
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[2]
BATCH = ROOT / "scripts" / "ovrad_batch.py"


select = blender_scenes.select


def colors(mesh, name):
    return blender_scenes.color_values(mesh, name)[:, :3]


def floor(size=4.0, cuts=15):
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=cuts, y_subdivisions=cuts, size=size)
    obj = bpy.context.active_object
    obj.name = "Floor"
    obj.data.materials.append(blender_scenes.principled("grey", (0.5, 0.5, 0.5)))
    return obj


def box_mesh(name, size):
    import bmesh

    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=2, use_grid_fill=True)
    for v in bm.verts:
        v.co.x, v.co.y, v.co.z = v.co.x * size[0], v.co.y * size[1], (v.co.z + 0.5) * size[2]
    bm.to_mesh(mesh)
    bm.free()
    mesh.materials.append(blender_scenes.principled("white", (0.9, 0.9, 0.9)))
    return mesh


def point_lamp(location, power=300.0):
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    lamp.data.energy = power
    lamp.data.shadow_soft_size = 0.0
    lamp.location = location
    bpy.context.scene.collection.objects.link(lamp)
    return lamp


def sun(strength=3.0):
    lamp = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    lamp.data.energy = strength
    bpy.context.scene.collection.objects.link(lamp)
    return lamp


def bake_floor(scene, pillar: str) -> np.ndarray:
    """The floor's baked radiance (POINT) with a pillar at x = 1 as 'none', 'object' (a scene
    object) or 'instance' (an empty instancing a collection excluded from the view layer)."""
    scene.ovrad.patch_count = 250
    scene.ovrad.min_rays = 400_000
    fl = floor()
    point_lamp((0.0, 0.0, 2.0))
    if pillar != "none":
        obj = bpy.data.objects.new("Pillar", box_mesh("Pillar", (0.4, 0.4, 1.5)))
        if pillar == "object":
            obj.location = (1.0, 0.0, 0.0)
            scene.collection.objects.link(obj)
        else:
            coll = bpy.data.collections.new("Pillars")
            scene.collection.children.link(coll)
            coll.objects.link(obj)
            bpy.context.view_layer.layer_collection.children["Pillars"].exclude = True
            empty = bpy.data.objects.new("Row", None)
            empty.instance_type, empty.instance_collection = "COLLECTION", coll
            empty.location = (1.0, 0.0, 0.0)
            scene.collection.objects.link(empty)
    select(fl)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    co = np.array([v.co for v in fl.data.vertices])
    return co, colors(fl.data, "ovrad_radiance")


@pytest.mark.versions
def test_a_collection_instance_shadows_and_reflects_like_the_same_real_object(ovrad, fresh_scene):
    co, bare = bake_floor(fresh_scene, "none")
    _, real = bake_floor(blender_env_reset(), "object")
    _, inst = bake_floor(blender_env_reset(), "instance")
    env = env_object()
    assert len(env.data.vertices) > 20 and env.hide_render  # the pillar's patches, hidden
    # Equal within the solve's noise: the same surfaces, read once as an object, once as an instance.
    rel = np.sqrt(np.mean((inst - real) ** 2)) / np.sqrt(np.mean(real**2))
    assert rel < 0.02
    # Behind the pillar (lamp at the origin): its shadow.
    behind = np.argmin(np.linalg.norm(co - (1.6, 0.0, 0.0), axis=1))
    assert inst[behind, 0] < 0.5 * bare[behind, 0]
    # Between the lamp and the pillar, out of its shadow: the pillar's lit face adds light.
    front = np.argmin(np.linalg.norm(co - (0.6, 0.0, 0.0), axis=1))
    assert inst[front, 0] > 1.03 * bare[front, 0]
    assert real[front, 0] > 1.03 * bare[front, 0]


def env_object():
    return next((o for o in bpy.context.scene.objects if "ovrad_environment_key" in o), None)


def blender_env_reset():
    import blender_env

    return blender_env.reset_scene()


@pytest.mark.versions
def test_geometry_nodes_instances_are_read(ovrad, fresh_scene, monkeypatch, capsys):
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0.0, 0.0, 3.0))
    scatter = bpy.context.active_object
    tree = bpy.data.node_groups.new("scatter", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    inp, out = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    on_points, cube = tree.nodes.new("GeometryNodeInstanceOnPoints"), tree.nodes.new("GeometryNodeMeshCube")
    cube.inputs["Size"].default_value = (0.5, 0.5, 0.5)
    tree.links.new(inp.outputs[0], on_points.inputs["Points"])
    tree.links.new(cube.outputs[0], on_points.inputs["Instance"])
    tree.links.new(on_points.outputs[0], out.inputs[0])
    scatter.modifiers.new("scatter", "NODES").node_group = tree
    model = ovrad.operators.scene_model.read_model(bpy.context.evaluated_depsgraph_get(), fresh_scene)
    cubes = [it for it in model.items if it.instance]
    assert len(cubes) == 4 and len({id(it.local) for it in cubes}) == 1  # one mesh, read once
    centres = sorted(tuple(np.round(it.data().vertices.mean(axis=0), 6)) for it in cubes)
    assert centres == sorted((x, y, 3.0) for x in (-1.0, 1.0) for y in (-1.0, 1.0))
    # They take part: a floor under them is shadowed where they are.
    fresh_scene.ovrad.patch_count = 150
    fresh_scene.ovrad.min_rays = 200_000
    fl = floor(cuts=20)
    sun()
    select(fl)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}

    def cancel_at_first_line(job):
        assert bpy.ops.ovrad.cancel_solve() == {"FINISHED"}

    with monkeypatch.context() as patch:
        patch.setattr(ovrad.operators.solve_job, "ProgressPrinter", lambda: cancel_at_first_line)
        assert bpy.ops.ovrad.solve() == {"CANCELLED"}
    assert env_object() is None  # a cancelled solve makes no environment atlas
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert len(env_object().data.vertices) > 0
    capsys.readouterr()
    # Solving again reads the stored environment back: the same patches, so the form factors are reused.
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert "reusing the form factors" in capsys.readouterr().out
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    co = np.array([v.co for v in fl.data.vertices])
    values = colors(fl.data, "ovrad_radiance")[:, 0]
    under = np.linalg.norm(np.abs(co[:, :2]) - 1.0, axis=1) < 0.1
    open_floor = np.linalg.norm(co[:, :2], axis=1) < 0.3
    assert under.any() and np.all(values[under] < 0.2 * np.median(values[open_floor]))


def duplicates(scene, shaded: bool):
    """Two boxes sharing one mesh and one box of its own under a sun; shaded: a card (no atlas)
    hides the second duplicate from the sun."""
    scene.ovrad.patch_count = 300
    scene.ovrad.min_rays = 300_000
    shared = box_mesh("Bench", (0.8, 0.4, 0.4))
    a = bpy.data.objects.new("BenchA", shared)
    b = bpy.data.objects.new("BenchB", shared)
    c = bpy.data.objects.new("Crate", box_mesh("Crate", (0.4, 0.4, 0.4)))
    for obj, x in ((a, -3.0), (b, 3.0), (c, 0.0)):
        obj.location = (x, 0.0, 0.0)
        scene.collection.objects.link(obj)
    if shaded:
        bpy.ops.mesh.primitive_plane_add(size=2.0, location=(3.0, 0.0, 1.5))
    sun()
    bpy.context.view_layer.update()
    select(a, b, c)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    return shared, c


def test_linked_duplicates_lit_alike_bake_once(ovrad, fresh_scene, capfd):
    shared, crate = duplicates(fresh_scene, shaded=False)
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    values = colors(shared, "ovrad_radiance")
    co = np.array([v.co for v in shared.vertices])
    top = (co[:, 2] > 0.39) & (np.abs(co[:, 0]) < 0.39) & (np.abs(co[:, 1]) < 0.19)
    assert top.sum() >= 4
    # The sun lights both tops alike: rho E / pi = 0.9 x 3 / pi.
    np.testing.assert_allclose(values[top, 0], 0.9 * 3.0 / np.pi, rtol=0.02)
    assert "ovrad_radiance" in crate.data.attributes
    assert "lit differently" not in capfd.readouterr().out


def test_linked_duplicates_lit_differently_are_skipped_and_the_rest_baked(ovrad, fresh_scene, capfd):
    shared, crate = duplicates(fresh_scene, shaded=True)
    capfd.readouterr()
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    out = capfd.readouterr().out
    assert "'BenchA', 'BenchB' share the mesh 'Bench' but are lit differently" in out
    assert "Make Single User > Object & Data" in out
    assert "ovrad_radiance" not in shared.attributes and "ovrad_radiance" in crate.data.attributes


def test_a_receiver_without_faces_is_skipped_everywhere_and_the_rest_baked(ovrad, fresh_scene, capfd):
    fresh_scene.ovrad.patch_count = 200
    fresh_scene.ovrad.min_rays = 200_000
    box = blender_scenes.closed_box("Box", 2, blender_scenes.principled("lit", (0.5,) * 3, 1.0))
    bpy.ops.mesh.primitive_plane_add(size=0.5)
    card = bpy.context.active_object
    select(box, card)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    card.data = bpy.data.meshes.new("points")
    card.data.vertices.add(3)  # its faces are gone: Solve and the bakes skip it
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert f"'{card.name}' has no faces" in capfd.readouterr().out
    select(box, card)
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    assert "ovrad_radiance" in box.data.attributes
    # Generate too: a selection with a faceless mesh still covers the rest.
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert "has no faces; skipped" in capfd.readouterr().out


def test_batch_without_options_bakes_instances_and_duplicates(ovrad, fresh_scene, run_blender, tmp_path):
    sys.path.insert(0, str(ROOT))
    from benchmarks import real_scenes

    blend = tmp_path / "scene.blend"
    real_scenes.build("instances", blend)
    bench = real_scenes.box_mesh("Bench", (0.6, 0.3, 0.4), real_scenes.diffuse("Warm", real_scenes.WARM))
    real_scenes.place("BenchA", bench, (0.4, 0.4, 0.0))
    real_scenes.place("BenchB", bench, (2.5, 0.4, 0.0))  # a linked duplicate of it
    bpy.ops.wm.save_mainfile(filepath=str(blend))
    out = tmp_path / "out.blend"
    proc = run_blender(["-b", str(blend), "-P", str(BATCH), "--", "--output", str(out)], timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr
    assert out.exists()


def test_lamps_inside_collection_instances_light_the_scene(ovrad, fresh_scene):
    coll = bpy.data.collections.new("Fixtures")
    fresh_scene.collection.children.link(coll)
    lamp = bpy.data.objects.new("Bulb", bpy.data.lights.new("Bulb", "POINT"))
    lamp.data.energy, lamp.location = 100.0, (0.0, 0.0, 1.0)
    coll.objects.link(lamp)
    bpy.context.view_layer.layer_collection.children["Fixtures"].exclude = True
    for k, x in enumerate((2.0, -3.0)):
        empty = bpy.data.objects.new(f"Fixture{k}", None)
        empty.instance_type, empty.instance_collection = "COLLECTION", coll
        empty.location = (x, 0.0, 0.5)
        fresh_scene.collection.objects.link(empty)
    model = ovrad.operators.scene_model.read_model(bpy.context.evaluated_depsgraph_get(), fresh_scene)
    # the excluded collection's own lamp does not render; each instance's does, where it is placed
    assert sorted(lp.position for lp in model.lamps) == [(-3.0, 0.0, 1.5), (2.0, 0.0, 1.5)]
    assert all(lp.kind == "POINT" and lp.power == pytest.approx(100.0) for lp in model.lamps)
