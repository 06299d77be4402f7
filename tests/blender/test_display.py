"""The patch display modifier: evaluated geometry (disks and squares where the atlas says) and its colours."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender


@pytest.fixture
def cube_atlas(ovrad, fresh_scene):
    """The atlas object of a 2 m cube (disks inside the faces, squares along the edges)."""
    fresh_scene.ovrad.patch_count = 150
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    cube = bpy.context.active_object
    cube.name = "Cube"
    bpy.ops.ovrad.generate_atlas()
    (atlas,) = [o for o in bpy.data.objects if o.get("ovrad_source") == "Cube"]
    return atlas


def point_array(attrs, name, n):
    attr = attrs[name]
    key, comps, dtype = {
        "FLOAT": ("value", 1, np.float32),
        "INT": ("value", 1, np.int32),
        "FLOAT_VECTOR": ("vector", 3, np.float32),
        "FLOAT_COLOR": ("color", 4, np.float32),
    }[attr.data_type]
    out = np.empty(n * comps, dtype)
    attr.data.foreach_get(key, out)
    return out.reshape(n, -1) if comps > 1 else out


class Evaluated:
    """The display modifier's output as arrays (vertices, faces and their attributes)."""

    def __init__(self, obj, names=()):
        depsgraph = bpy.context.evaluated_depsgraph_get()
        ev = obj.evaluated_get(depsgraph)
        mesh = ev.to_mesh()
        try:
            nv, nf = len(mesh.vertices), len(mesh.polygons)
            self.co = point_array(mesh.attributes, "position", nv)
            self.sizes = np.empty(nf, np.int32)
            mesh.polygons.foreach_get("loop_total", self.sizes)
            self.starts = np.empty(nf, np.int32)
            mesh.polygons.foreach_get("loop_start", self.starts)
            self.corner_vert = np.empty(len(mesh.loops), np.int32)
            mesh.loops.foreach_get("vertex_index", self.corner_vert)
            self.attrs = {n: point_array(mesh.attributes, n, nv) for n in names}
            self.n_vertices, self.n_faces = nv, nf
        finally:
            ev.to_mesh_clear()

    def face_vertices(self, f):
        return self.corner_vert[self.starts[f] : self.starts[f] + self.sizes[f]]


def atlas_array(obj, name):
    return point_array(obj.data.attributes, name, len(obj.data.vertices))


@pytest.mark.versions
def test_display_draws_one_face_per_patch_with_the_right_vertex_counts(cube_atlas, ovrad):
    shape = atlas_array(cube_atlas, "ovrad_shape")
    disks, squares = int(np.sum(shape == 0)), int(np.sum(shape == 1))
    assert disks > 0 and squares > 0  # AUTO shapes on a cube: both kinds
    ev = Evaluated(cube_atlas)
    assert ev.n_faces == disks + squares
    assert ev.n_vertices == 32 * disks + 4 * squares
    assert sorted(np.unique(ev.sizes, return_counts=True)[1].tolist()) == sorted([disks, squares])
    # The "Disk Vertices" input is live.
    mod = cube_atlas.modifiers["ovrad display"]
    assert mod.node_group.name == "ovrad_patch_display"
    assert ovrad.operators.display.set_input(cube_atlas, "Disk Vertices", 8)
    assert Evaluated(cube_atlas).n_vertices == 8 * disks + 4 * squares


@pytest.mark.versions
def test_each_face_is_its_patch_oriented_and_sized(cube_atlas):
    centers = np.empty(3 * len(cube_atlas.data.vertices), np.float32)
    cube_atlas.data.vertices.foreach_get("co", centers)
    centers = centers.reshape(-1, 3)
    names = ("ovrad_normal", "ovrad_tangent", "ovrad_radius", "ovrad_shape", "ovrad_local")
    ev = Evaluated(cube_atlas, names)
    matched = set()
    for f in range(ev.n_faces):
        vs = ev.face_vertices(f)
        n, t = ev.attrs["ovrad_normal"][vs[0]], ev.attrs["ovrad_tangent"][vs[0]]
        r, shape = float(ev.attrs["ovrad_radius"][vs[0]]), int(ev.attrs["ovrad_shape"][vs[0]])
        c = ev.co[vs].mean(axis=0)
        rel = ev.co[vs] - c
        # Centre: the patch's own point, lifted a hair (under 1 % of the radius) along its normal.
        k = int(np.argmin(np.linalg.norm(centers - c, axis=1)))
        matched.add(k)
        lift = c - centers[k]
        assert np.linalg.norm(np.cross(lift, n)) < 1e-5 and 0 < lift @ n < 0.01 * r
        assert np.allclose(rel @ n, 0.0, atol=1e-5)  # flat, in the plane the normal defines
        if shape == 0:
            assert np.allclose(np.linalg.norm(rel, axis=1), r, rtol=1e-4)
            assert np.allclose(np.linalg.norm(ev.attrs["ovrad_local"][vs][:, :2], axis=1), 1.0, atol=1e-5)
        else:
            b = np.cross(n, t)
            assert np.allclose(np.abs(rel @ t), r, rtol=1e-4) and np.allclose(np.abs(rel @ b), r, rtol=1e-4)
            assert np.allclose(np.abs(ev.attrs["ovrad_local"][vs][:, :2]), 1.0, atol=1e-5)
    assert len(matched) == ev.n_faces  # every patch drawn exactly once


@pytest.mark.versions
def test_quantity_setting_recolours_every_atlas(cube_atlas):
    scene = bpy.context.scene
    overlap = atlas_array(cube_atlas, "ovrad_overlap")
    names = ("ovrad_display_color", "ovrad_display_beta", "ovrad_overlap", "ovrad_shape")

    def per_patch():
        ev = Evaluated(cube_atlas, names)
        first = ev.corner_vert[ev.starts]  # one vertex per face: per-patch values
        return {k: v[first] for k, v in ev.attrs.items()}

    scene.ovrad.display_quantity = "OVERLAP"
    p = per_patch()
    # The same count always gives the same colour, different counts different colours.
    col = {
        int(c): tuple(np.round(rgb, 5))
        for c, rgb in zip(p["ovrad_overlap"], p["ovrad_display_color"], strict=True)
    }
    assert len(set(col.values())) == len(col) == len(np.unique(overlap))
    assert np.all(p["ovrad_display_beta"] == 0.0)

    scene.ovrad.display_quantity = "RANDOM"
    p = per_patch()
    assert len(np.unique(np.round(p["ovrad_display_color"], 4), axis=0)) > 0.9 * len(overlap)
    random_colors = p["ovrad_display_color"]

    # Beta: each patch's random colour, which the material multiplies by the disk or square profile.
    scene.ovrad.display_quantity = "BETA"
    p = per_patch()
    expect = np.where(p["ovrad_shape"][:, None] == 0, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])
    assert np.array_equal(p["ovrad_display_beta"], expect)
    assert np.array_equal(p["ovrad_display_color"], random_colors)

    scene.ovrad.display_quantity = "RADIOSITY"
    p = per_patch()
    assert np.all(p["ovrad_display_color"][:, :3] == 0.0)  # not solved yet: black


@pytest.mark.versions
def test_radiosity_attribute_is_shown_when_present(cube_atlas, ovrad):
    n = len(cube_atlas.data.vertices)
    rgb = np.random.default_rng(1).random((n, 3))
    ovrad.operators.attributes.write_point_attribute(cube_atlas.data, "ovrad_radiosity", rgb, "FLOAT_COLOR")
    bpy.context.scene.ovrad.display_quantity = "RADIOSITY"
    ev = Evaluated(cube_atlas, ("ovrad_display_color", "ovrad_random"))
    first = ev.corner_vert[ev.starts]
    # Faces come out grouped by shape, so match them to patches through their stable random value.
    order = np.argsort(atlas_array(cube_atlas, "ovrad_random"))
    got = ev.attrs["ovrad_display_color"][first][np.argsort(ev.attrs["ovrad_random"][first])]
    assert np.allclose(got[:, :3], rgb[order], atol=1e-6)


def test_box_beta_atlas_is_drawn_with_the_box_profile(ovrad, fresh_scene):
    scene = fresh_scene
    scene.ovrad.patch_count, scene.ovrad.beta, scene.ovrad.display_quantity = 100, "box", "BETA"
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    bpy.ops.ovrad.generate_atlas()
    (atlas,) = [o for o in bpy.data.objects if "ovrad_source" in o]
    assert atlas["ovrad_beta"] == "box"
    ev = Evaluated(atlas, ("ovrad_display_beta",))
    assert np.all(ev.attrs["ovrad_display_beta"] == [1.0, 0.0, 0.0])


@pytest.mark.versions
def test_an_old_display_tree_is_rebuilt_in_place(cube_atlas, ovrad):
    display = ovrad.operators.display
    shape = atlas_array(cube_atlas, "ovrad_shape")
    display.set_input(cube_atlas, "Disk Vertices", 8)  # a user's choice, to survive the upgrade
    ng = cube_atlas.modifiers["ovrad display"].node_group
    ng[display.VERSION_PROP] = display.DISPLAY_VERSION - 1
    ng.nodes.clear()  # as if an older extension had saved a different tree
    again = display.ensure_node_group()
    assert again == ng and again[display.VERSION_PROP] == display.DISPLAY_VERSION
    assert len(bpy.data.node_groups) == 1
    ev = Evaluated(cube_atlas)
    assert ev.n_faces == len(shape)
    assert ev.n_vertices == 8 * np.sum(shape == 0) + 4 * np.sum(shape == 1)
