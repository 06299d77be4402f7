"""Bake Vertex Colors through the installed extension: domains, quantities, replacing only its own
attribute, never a user's, topology-changing modifiers, and baking before solving."""

from __future__ import annotations

import blender_scenes
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

RHO, LE = 0.6, 1.0  # furnace: L = LE / (1 - RHO) = 2.5; light arriving, E / pi, is the same 2.5


def closed_box(name="Box", cuts=3):
    """A 2 m cube seen from inside, uniform emission LE and reflectance RHO, selected and active."""
    obj = blender_scenes.closed_box(name, cuts, blender_scenes.principled("furnace", (RHO,) * 3, LE))
    bpy.context.view_layer.update()
    for o in bpy.context.view_layer.objects:
        o.select_set(o == obj)
    bpy.context.view_layer.objects.active = obj
    return obj


colors = blender_scenes.color_values


@pytest.fixture
def box(ovrad, fresh_scene):
    fresh_scene.ovrad.patch_count = 300
    fresh_scene.ovrad.solve_tolerance = 1e-4
    obj = closed_box()
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    return obj


@pytest.fixture
def solved(box):
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    return box


@pytest.mark.versions
def test_point_and_corner_domains_hold_the_furnace_answer(solved):
    mesh = solved.data
    assert bpy.ops.ovrad.bake_vertex(domain="CORNER", attribute="corner") == {"FINISHED"}
    attr = mesh.attributes["corner"]
    assert (attr.data_type, attr.domain, len(attr.data)) == ("FLOAT_COLOR", "CORNER", len(mesh.loops))
    np.testing.assert_allclose(colors(mesh, "corner")[:, :3], LE / (1 - RHO), rtol=0.02)
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}  # the panel's defaults: ovrad_radiance, POINT
    attr = mesh.attributes["ovrad_radiance"]
    assert (attr.domain, len(attr.data)) == ("POINT", len(mesh.vertices))
    values = colors(mesh, "ovrad_radiance")
    np.testing.assert_allclose(values[:, :3], LE / (1 - RHO), rtol=0.02)
    assert np.all(values[:, 3] == 1.0)
    # Shown: the active and the render colour.
    assert mesh.color_attributes.active_color_name == "ovrad_radiance"
    assert mesh.color_attributes[mesh.color_attributes.render_color_index].name == "ovrad_radiance"


@pytest.mark.versions
@pytest.mark.parametrize("gather_rays", [0, 64])
def test_the_furnace_answer_with_the_final_gather_or_from_the_patches(ovrad, solved, gather_rays):
    # 0: the indirect light reconstructed from the patches (the paper); else gathered once per
    # vertex and face with this many rays (the scene's default is also a gather).
    bpy.context.scene.ovrad.gather_rays = gather_rays
    assert ovrad.operators.solution.load_solution(bpy.context).light.gather_rays == gather_rays
    mesh = solved.data
    for domain in ("POINT", "CORNER"):
        assert bpy.ops.ovrad.bake_vertex(domain=domain, attribute=domain) == {"FINISHED"}
        np.testing.assert_allclose(colors(mesh, domain)[:, :3], LE / (1 - RHO), rtol=0.02)
    bpy.ops.ovrad.bake_vertex(attribute="H", quantity="IRRADIANCE")
    np.testing.assert_allclose(colors(mesh, "H")[:, :3], LE / (1 - RHO), rtol=0.02)


def test_irradiance_is_the_light_arriving_without_albedo_or_emission(solved):
    mesh = solved.data
    bpy.ops.ovrad.bake_vertex(attribute="L", quantity="RADIANCE")
    bpy.ops.ovrad.bake_vertex(attribute="H", quantity="IRRADIANCE")
    L, H = colors(mesh, "L")[:, :3], colors(mesh, "H")[:, :3]
    # Closed box: what arrives is the room's radiance L = LE / (1 - RHO); what leaves is LE + RHO H.
    np.testing.assert_allclose(H, LE / (1 - RHO), rtol=0.02)
    np.testing.assert_allclose(L, LE + RHO * H, rtol=1e-4)


@pytest.mark.versions
def test_baking_twice_replaces_its_own_attribute(solved):
    mesh = solved.data
    bpy.ops.ovrad.bake_vertex()
    names_before = sorted(a.name for a in mesh.attributes)
    first = colors(mesh, "ovrad_radiance").copy()
    strength = mesh.materials[0].node_tree.nodes["Principled BSDF"].inputs["Emission Strength"]
    strength.default_value = 2 * LE
    bpy.ops.ovrad.solve()
    assert bpy.ops.ovrad.bake_vertex(domain="CORNER") == {"FINISHED"}
    assert sorted(a.name for a in mesh.attributes) == names_before  # replaced, not duplicated
    assert [a.name for a in mesh.color_attributes].count("ovrad_radiance") == 1
    attr = mesh.attributes["ovrad_radiance"]
    assert attr.domain == "CORNER"
    np.testing.assert_allclose(colors(mesh, "ovrad_radiance")[:, :3], 2 * first[0, 0], rtol=0.02)


@pytest.mark.versions
def test_a_users_attribute_of_that_name_is_never_overwritten(solved):
    mesh = solved.data
    mine = mesh.color_attributes.new("ovrad_radiance", "BYTE_COLOR", "CORNER")
    mine.data.foreach_set("color", np.full(4 * len(mesh.loops), 0.25, np.float32))
    before = colors(mesh, "ovrad_radiance").copy()
    with pytest.raises(
        RuntimeError, match="already has an attribute 'ovrad_radiance' that ovrad did not make"
    ):
        bpy.ops.ovrad.bake_vertex()
    attr = mesh.attributes["ovrad_radiance"]
    assert (attr.data_type, attr.domain) == ("BYTE_COLOR", "CORNER")
    assert np.array_equal(colors(mesh, "ovrad_radiance"), before)
    # Another name works, and the user's attribute is still untouched.
    assert bpy.ops.ovrad.bake_vertex(attribute="baked") == {"FINISHED"}
    assert np.array_equal(colors(mesh, "ovrad_radiance"), before)


def test_an_attribute_the_user_made_or_changed_under_a_baked_name_is_kept(solved):
    mesh = solved.data
    bpy.ops.ovrad.bake_vertex(attribute="lit")
    mesh.attributes.remove(mesh.attributes["lit"])
    mesh.attributes.new("lit", "FLOAT_COLOR", "POINT")  # the user's own, under the old name
    before = colors(mesh, "lit").copy()
    with pytest.raises(RuntimeError, match="that ovrad did not make"):
        bpy.ops.ovrad.bake_vertex(attribute="lit")
    assert np.array_equal(colors(mesh, "lit"), before)
    # A bake the user painted over is theirs now too.
    bpy.ops.ovrad.bake_vertex(attribute="painted")
    mesh.attributes["painted"].data[0].color = (1.0, 0.0, 0.0, 1.0)
    with pytest.raises(RuntimeError, match="that ovrad did not make"):
        bpy.ops.ovrad.bake_vertex(attribute="painted")
    assert tuple(mesh.attributes["painted"].data[0].color) == (1.0, 0.0, 0.0, 1.0)


def test_topology_changing_modifiers_are_refused_with_what_to_do(box):
    box.modifiers.new("Subdivision", "SUBSURF")
    bpy.ops.ovrad.generate_atlas()  # the atlas of the subdivided surface
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    attributes = sorted(a.name for a in box.data.attributes)
    with pytest.raises(RuntimeError, match="apply the modifiers first"):
        bpy.ops.ovrad.bake_vertex()
    assert sorted(a.name for a in box.data.attributes) == attributes


def test_baking_before_solving_says_to_solve(box):
    with pytest.raises(RuntimeError, match="press Solve first"):
        bpy.ops.ovrad.bake_vertex()
    assert "ovrad_radiance" not in box.data.attributes


def test_an_empty_attribute_name_is_refused(solved):
    with pytest.raises(RuntimeError, match="attribute name"):
        bpy.ops.ovrad.bake_vertex(attribute="  ")


@pytest.mark.versions
def test_undo_takes_back_a_solve_and_a_bake(box):
    # Background bpy.ops push no undo steps: push the ones the UI pushes around UNDO operators.
    bpy.ops.ed.undo_push(message="before")
    bpy.ops.ovrad.solve()
    bpy.ops.ed.undo_push(message="Solve")
    bpy.ops.ovrad.bake_vertex()
    bpy.ops.ed.undo_push(message="Bake Vertex Colors")
    box = bpy.data.objects["Box"]
    assert "ovrad_radiance" in box.data.attributes
    bpy.ops.ed.undo()
    box = bpy.data.objects["Box"]  # undo reloads the data: look objects up again
    atlas = next(o for o in bpy.data.objects if o.get("ovrad_source") == "Box")
    assert "ovrad_radiance" not in box.data.attributes and "ovrad_radiosity" in atlas.data.attributes
    bpy.ops.ed.undo()
    atlas = next(o for o in bpy.data.objects if o.get("ovrad_source") == "Box")
    assert "ovrad_radiosity" not in atlas.data.attributes


def test_corners_of_a_triangle_without_area_do_not_darken_the_vertex_they_share(ovrad):
    """Three points on a line make angles 0, 0 and pi: weighted by angle, the middle corner of such
    a sliver outweighed the real faces around its vertex. It weighs nothing there now; a vertex of
    slivers only still gets their plain mean."""
    bake = ovrad.operators.bake_vertex.ReceiverBake.__new__(ovrad.operators.bake_vertex.ReceiverBake)
    # vertex 0 is a corner of a right triangle (0, 1, 2) and the middle of the line (3, 0, 4);
    # vertices 3 and 4 belong to the line only
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, -1, 0], [1, 1, 0]], float)
    bake.tri_verts = np.array([[0, 1, 2], [3, 0, 4]])
    bake.tri_loops = np.arange(6).reshape(2, 3)
    bake.points = pos[bake.tri_verts]
    bake.n_vertices, bake.n_loops = 5, 6
    bake.no_area = np.array([False, True])
    corner = np.array([[1.0, 1.0, 1.0], [0.2, 0.0, 0.4]])[:, :, None] * np.ones(3)
    got = bake.domain_values(corner, "POINT")[:, 0]
    np.testing.assert_allclose(got, [1.0, 1.0, 1.0, 0.2, 0.4])
    # without the rule (all three corners weighed by angle): vertex 0 read (pi/2 + 0) / (pi/2 + pi)
    bake.no_area = np.array([False, False])
    assert bake.domain_values(corner, "POINT")[0, 0] < 0.4


def test_a_flat_shaded_sphere_gathers_once_per_vertex_for_the_point_domain(ovrad, fresh_scene, monkeypatch):
    """A vertex of a flat-shaded sphere (faces 22.5 degrees apart) gathers once for all the faces
    around it when the vertex domain averages them (gather.shared_normals), once per face for the
    face corner domain; both hold the furnace answer inside a closed furnace box."""
    fresh_scene.ovrad.patch_count = 400
    fresh_scene.ovrad.solve_tolerance = 1e-4
    mat = blender_scenes.principled("furnace", (RHO,) * 3, LE)
    box = blender_scenes.closed_box("Box", 3, mat)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8, radius=0.5)
    sphere = bpy.context.active_object
    sphere.data.materials.append(mat)
    blender_scenes.select(sphere, box)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    blender_scenes.select(sphere)
    gather = ovrad.ovrad_addon.gather
    counted = []
    original = gather.gather_indirect

    def counting(problem, radiosity, emission, points, *args, **kwargs):
        counted.append(int(np.sum(np.linalg.norm(points, axis=1) < 0.6)))  # the sphere's (radius 0.5)
        return original(problem, radiosity, emission, points, *args, **kwargs)

    monkeypatch.setattr(gather, "gather_indirect", counting)
    mesh = sphere.data
    gathered = {}
    for domain in ("POINT", "CORNER"):
        counted.clear()
        assert bpy.ops.ovrad.bake_vertex(domain=domain, attribute=domain) == {"FINISHED"}
        np.testing.assert_allclose(colors(mesh, domain)[:, :3], LE / (1 - RHO), rtol=0.02)
        gathered[domain] = sum(counted)
    # once per vertex for POINT; for CORNER once per face and vertex (a quad's two triangles may
    # count twice: their normals, from float32 positions, differ in the last digits)
    per_face = sum(len(p.vertices) for p in mesh.polygons)
    assert len(mesh.vertices) == 114 and per_face == 480
    assert gathered["POINT"] == len(mesh.vertices)
    assert gathered["CORNER"] >= per_face
