"""Generate Atlas driven as a user would: atlas objects, their attributes, replacement, undo and bad input."""

from __future__ import annotations

import re

import blender_scenes
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

# (name, Blender attribute type) of every POINT attribute an atlas object must carry.
ATLAS_ATTRIBUTES = {
    "ovrad_normal": "FLOAT_VECTOR",
    "ovrad_radius": "FLOAT",
    "ovrad_shape": "INT",
    "ovrad_tangent": "FLOAT_VECTOR",
    "ovrad_area": "FLOAT",
    "ovrad_overlap": "INT",
    "ovrad_sheet": "INT",
    "ovrad_thickness": "FLOAT",
    "ovrad_min_cos": "FLOAT",
    "ovrad_support_area": "FLOAT",
    "ovrad_random": "FLOAT",
}


@pytest.fixture
def scene(ovrad, fresh_scene):
    """An empty file with the installed extension enabled; default settings but a small patch count."""
    fresh_scene.ovrad.patch_count = 150
    return fresh_scene


def add_cube(name="Cube", size=2.0, location=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):
    bpy.ops.mesh.primitive_cube_add(size=size, location=location)
    obj = bpy.context.active_object
    obj.scale = scale  # on the object: the operator's own scale argument would be baked into the mesh
    obj.name = obj.data.name = name
    return obj


select = blender_scenes.select


def atlases(source=None):
    return [
        o for o in bpy.data.objects if "ovrad_source" in o and (source is None or o["ovrad_source"] == source)
    ]


def attribute(mesh, name):
    attr = mesh.attributes[name]
    key, comps, dtype = {
        "FLOAT": ("value", 1, np.float32),
        "INT": ("value", 1, np.int32),
        "FLOAT_VECTOR": ("vector", 3, np.float32),
        "FLOAT_COLOR": ("color", 4, np.float32),
        "FLOAT2": ("vector", 2, np.float32),
    }[attr.data_type]
    out = np.empty(len(attr.data) * comps, dtype)
    attr.data.foreach_get(key, out)
    return out.reshape(len(attr.data), -1) if comps > 1 else out


def edges(mesh):
    e = np.empty(2 * len(mesh.edges), np.int32)
    mesh.edges.foreach_get("vertices", e)
    return e.reshape(-1, 2)


def positions(mesh):
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    return co.reshape(-1, 3)


def snapshot():
    """Everything a failed operator must leave as it was."""
    data = bpy.data
    return (
        sorted(o.name for o in data.objects),
        sorted(m.name for m in data.meshes),
        sorted(c.name for c in data.collections),
        sorted(m.name for m in data.materials),
        sorted(g.name for g in data.node_groups),
        sorted(o.name for o in bpy.context.selected_objects),
        getattr(bpy.context.view_layer.objects.active, "name", None),
    )


@pytest.mark.versions
def test_generate_on_cube_makes_one_atlas_object_with_every_attribute(scene):
    cube = add_cube()
    select(cube)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    (atlas,) = atlases()
    assert atlas["ovrad_source"] == "Cube" and atlas["ovrad_beta"] == "smooth"
    # in the scene through the ovrad collection; also in the one Blender's glTF exporter leaves out
    assert sorted(c.name for c in atlas.users_collection) == ["glTF_not_exported", "ovrad"]
    assert atlas.hide_render and bpy.data.collections["ovrad"].name in {
        c.name for c in bpy.context.scene.collection.children
    }
    assert "ovrad" in [c.name for c in scene.collection.children]
    mesh = atlas.data
    assert len(mesh.vertices) > 50 and len(mesh.edges) > 0 and len(mesh.polygons) == 0
    for name, kind in ATLAS_ATTRIBUTES.items():
        attr = mesh.attributes[name]
        assert (attr.data_type, attr.domain) == (kind, "POINT"), name
    # C kept on the edges: one between each two overlapping patches i < j, (C[i, j], C[j, i]) on it
    attr = mesh.attributes["ovrad_c"]
    assert (attr.data_type, attr.domain) == ("FLOAT2", "EDGE")
    pairs, c = edges(mesh), attribute(mesh, "ovrad_c")
    assert np.all(pairs[:, 0] < pairs[:, 1]) and np.all(c.max(axis=1) > 0)
    n = len(mesh.vertices)
    np.testing.assert_array_equal(np.bincount(pairs.ravel(), minlength=n), attribute(mesh, "ovrad_overlap"))
    # a row of C sums to the patch's support area: the diagonal is the effective area
    rows = (
        attribute(mesh, "ovrad_area")
        + np.bincount(pairs[:, 0], c[:, 0], n)
        + np.bincount(pairs[:, 1], c[:, 1], n)
    )
    np.testing.assert_allclose(rows, attribute(mesh, "ovrad_support_area"), rtol=1e-5)
    assert isinstance(mesh.get("ovrad_overlap_key"), str)
    # Every centre lies on the cube's surface (|coordinate| = 1 on some axis), normals are unit and outward.
    p = positions(mesh)
    assert np.allclose(np.abs(p).max(axis=1), 1.0, atol=1e-5)
    n = attribute(mesh, "ovrad_normal")
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert np.all(np.einsum("ij,ij->i", n, p) > 0.9)
    assert set(np.unique(attribute(mesh, "ovrad_shape"))) <= {0, 1}
    # Selection and active object are what the user had.
    assert bpy.context.selected_objects == [cube] and bpy.context.view_layer.objects.active == cube


@pytest.mark.versions
def test_atlas_attributes_survive_save_and_reload(scene, tmp_path):
    select(add_cube())
    bpy.ops.ovrad.generate_atlas()
    (atlas,) = atlases()
    before = {name: attribute(atlas.data, name) for name in [*ATLAS_ATTRIBUTES, "ovrad_c"]}
    before_co, before_edges = positions(atlas.data), edges(atlas.data)
    key = atlas.data["ovrad_overlap_key"]
    path = str(tmp_path / "atlas.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    assert atlases() == []
    bpy.ops.wm.open_mainfile(filepath=path)
    (atlas,) = atlases("Cube")
    assert atlas["ovrad_beta"] == "smooth"
    assert np.array_equal(positions(atlas.data), before_co)
    assert np.array_equal(edges(atlas.data), before_edges) and atlas.data["ovrad_overlap_key"] == key
    for name, values in before.items():
        assert np.array_equal(attribute(atlas.data, name), values), name


def test_generating_again_replaces_only_that_sources_atlas(scene):
    cube = add_cube()
    # A user's object that merely has the atlas's name: it must never be touched.
    impostor = add_cube("Cube_ovrad_atlas", size=0.5, location=(5, 0, 0))
    other = add_cube("Other", location=(0, 5, 0))
    select(cube, other)
    bpy.ops.ovrad.generate_atlas()
    first = {o["ovrad_source"]: len(o.data.vertices) for o in atlases()}
    assert set(first) == {"Cube", "Other"}
    old_mesh = atlases("Cube")[0].data.name
    scene.ovrad.patch_count = 600
    select(cube)
    bpy.ops.ovrad.generate_atlas()
    assert len(atlases("Cube")) == 1 and len(atlases("Other")) == 1
    assert len(atlases("Cube")[0].data.vertices) > 2 * first["Cube"]
    assert len(atlases("Other")[0].data.vertices) == first["Other"]
    assert old_mesh not in bpy.data.meshes or bpy.data.meshes[old_mesh] == atlases("Cube")[0].data
    assert "ovrad_source" not in impostor and len(impostor.data.vertices) == 8
    assert impostor.users_collection[0].name != "ovrad"


@pytest.mark.versions
def test_undo_restores_the_previous_atlas(scene):
    # bpy.ops called from Python in background mode pushes no undo step (checked: the undo stack stays
    # as it was), so the test pushes the steps the UI pushes around an UNDO operator itself.
    select(add_cube())
    bpy.ops.ed.undo_push(message="before")
    bpy.ops.ovrad.generate_atlas()
    bpy.ops.ed.undo_push(message="Generate Atlas")
    small = len(atlases("Cube")[0].data.vertices)
    scene.ovrad.patch_count = 600
    bpy.ops.ovrad.generate_atlas()
    bpy.ops.ed.undo_push(message="Generate Atlas")
    assert len(atlases("Cube")[0].data.vertices) > 2 * small
    bpy.ops.ed.undo()
    assert [len(o.data.vertices) for o in atlases("Cube")] == [small]
    bpy.ops.ed.undo()
    assert atlases() == [] and "ovrad" not in bpy.data.collections


def test_empty_selection_is_refused_with_a_clear_message(scene, ovrad):
    add_cube()
    select()
    before = snapshot()
    with pytest.raises(RuntimeError, match="Select at least one mesh object"):
        bpy.ops.ovrad.generate_atlas()
    assert snapshot() == before
    # The reader behind it says the same when asked directly.
    with pytest.raises(ovrad.ovrad_addon.errors.OvradError, match="select at least one mesh"):
        ovrad.operators.scene_io.read_scene(bpy.context.evaluated_depsgraph_get(), [])


def test_non_mesh_objects_are_skipped_with_a_warning(scene, capfd):
    cube = add_cube()
    bpy.ops.object.camera_add()
    cam = bpy.context.active_object
    bpy.ops.object.light_add(type="POINT")
    lamp = bpy.context.active_object
    select(cam, cube, lamp)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert [o["ovrad_source"] for o in atlases()] == ["Cube"]
    err = capfd.readouterr()
    text = err.out + err.err
    assert f"'{cam.name}' is not a mesh (camera); skipped" in text
    assert f"'{lamp.name}' is not a mesh (light); skipped" in text
    assert bpy.context.view_layer.objects.active == cam


def test_too_many_patches_is_an_error_with_the_count_and_nothing_is_made(scene):
    select(add_cube())
    scene.ovrad.patch_count = 2000
    scene.ovrad.max_patches = 300
    before = snapshot()
    with pytest.raises(RuntimeError) as err:
        bpy.ops.ovrad.generate_atlas()
    # Blender drops the commas of a report when it turns it into the exception, so accept both.
    msg = str(err.value)
    count = re.search(r"would make (?:about )?([\d,]+)\+? patches", msg)
    assert count and int(count.group(1).replace(",", "")) > 300
    assert "limit of 300" in msg and "raise the patch limit" in msg
    assert snapshot() == before


def test_mirrored_object_keeps_outward_normals(scene):
    # Scale -1 turns the winding inside out; the reader flips it back, so patches stay on the outside.
    cube = add_cube(scale=(-1.0, 1.0, 1.0), location=(3.0, 0.0, 0.0))
    select(cube)
    bpy.ops.ovrad.generate_atlas()
    mesh = atlases("Cube")[0].data
    p = positions(mesh) - np.array([3.0, 0.0, 0.0], np.float32)
    assert np.all(np.einsum("ij,ij->i", attribute(mesh, "ovrad_normal"), p) > 0.9)


@pytest.mark.versions
def test_modifiers_and_transforms_are_applied(scene):
    cube = add_cube(location=(0.0, 0.0, 10.0))
    mod = cube.modifiers.new("array", "ARRAY")
    mod.count, mod.relative_offset_displace = 2, (2.0, 0.0, 0.0)  # a second cube at x in [3, 5]
    select(cube)
    bpy.ops.ovrad.generate_atlas()
    p = positions(atlases("Cube")[0].data)
    assert np.allclose(p[:, 2].min(), 9.0, atol=1e-5) and np.allclose(p[:, 2].max(), 11.0, atol=1e-5)
    assert p[:, 0].min() == pytest.approx(-1.0, abs=1e-5) and p[:, 0].max() == pytest.approx(5.0, abs=1e-5)
    assert np.any((p[:, 0] > 1.5) & (p[:, 0] < 2.5)) is np.False_  # nothing in the gap between the copies


def test_per_object_density_override_sets_patch_size(scene):
    a = add_cube("A")
    b = add_cube("B", location=(10.0, 0.0, 0.0))
    b.ovrad.density = 2.0
    scene.ovrad.size_mode = "SIZE"
    scene.ovrad.patch_size = 0.25
    scene.ovrad.shapes = "SQUARES"
    select(a, b)
    bpy.ops.ovrad.generate_atlas()
    # Squares tile a 2 x 2 face exactly: 8 x 8 per face at size 0.25, 16 x 16 at density 2.
    assert len(atlases("A")[0].data.vertices) == 6 * 8 * 8
    assert len(atlases("B")[0].data.vertices) == 6 * 16 * 16


def test_other_visible_meshes_are_read_as_occluders_without_patches(scene, ovrad):
    card = add_cube("Card")
    wall = add_cube("Wall", location=(0, 0, 5))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    io = ovrad.operators.scene_io
    meshes = io.read_scene(depsgraph, [card], io.default_occluders(bpy.context, [card]))
    assert meshes.surfaces.object_names == ("Card", "Wall")
    assert meshes.surfaces.receiver.tolist() == [True, False] and meshes.n_receivers == 1
    assert meshes.objects == [card, wall]


def test_a_mesh_with_only_degenerate_faces_gets_an_empty_atlas_and_a_warning(scene, capfd):
    cube = add_cube()
    mesh = bpy.data.meshes.new("sliver")
    mesh.from_pydata([(0, 0, 3), (1, 0, 3), (2, 0, 3)], [], [(0, 1, 2)])  # collinear: zero area
    sliver = bpy.data.objects.new("sliver", mesh)
    scene.collection.objects.link(sliver)
    select(cube, sliver)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert len(atlases("Cube")[0].data.vertices) > 0
    assert [len(o.data.vertices) for o in atlases("sliver")] == [0]
    assert "'sliver' got no patches" in "".join(capfd.readouterr())
