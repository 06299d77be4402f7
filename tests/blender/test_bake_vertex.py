"""Bake Vertex Colors through the installed extension: domains, quantities, replacing only its own
attribute, never a user's, meshes under topology-changing modifiers, and baking before solving."""

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


def lit_box(modifiers=(), lamp_at=(0.45, 0.3, 0.5)):
    """A 2 m box seen from inside (reflectance RHO, 2 x 2 quads a face) lit by a point lamp (off its
    centre by default), with these (type, settings) modifiers, selected; patches 300."""
    bpy.context.scene.ovrad.patch_count = 300
    bpy.context.scene.ovrad.solve_tolerance = 1e-4
    obj = closed_box(cuts=1)
    obj.data.materials.clear()
    obj.data.materials.append(blender_scenes.principled("grey", (RHO,) * 3))
    for kind, settings in modifiers:
        mod = obj.modifiers.new(kind.title(), kind)
        for key, value in settings.items():
            setattr(mod, key, value)
    light = bpy.data.lights.new("Lamp", "POINT")
    light.energy = 200.0
    lamp = bpy.data.objects.new("Lamp", light)
    lamp.location = lamp_at
    bpy.context.scene.collection.objects.link(lamp)
    blender_scenes.select(obj)
    return obj


SIMPLE_SPLIT = (
    ("SUBSURF", {"subdivision_type": "SIMPLE", "levels": 1, "render_levels": 1}),
    ("TRIANGULATE", {}),
)


@pytest.mark.versions
def test_origins_are_the_loops_the_modifiers_copied(ovrad, fresh_scene):
    """Simple subdivision keeps each original corner where it was; an array copies each loop once
    per element, moved by its offset; the temporary attributes that carry the map are gone after."""
    reader = ovrad.operators.mesh_reader
    obj = lit_box(SIMPLE_SPLIT)
    before = sorted(a.name for a in obj.data.attributes)
    own = reader.vertex_positions(obj.data, obj.matrix_world)[reader.loop_vertices(obj.data)]
    data, origin = reader.read_with_origins([obj], bpy.context.evaluated_depsgraph_get())[obj.name]
    assert sorted(a.name for a in obj.data.attributes) == before
    mapped = origin >= 0
    assert set(origin[mapped]) == set(range(len(obj.data.loops)))
    # where it was, to float32 rounding (OpenSubdiv evaluates the corners too)
    np.testing.assert_allclose(data.vertices[data.loop_vertices[mapped]], own[origin[mapped]], atol=1e-6)
    # loops the subdivision made (on the new edge and face points) copy none
    assert mapped.sum() < len(origin) and len(data.vertices) == 26 + 48 + 24
    obj.modifiers.clear()
    array = obj.modifiers.new("Array", "ARRAY")
    array.count, array.use_relative_offset, array.use_constant_offset = 3, False, True
    array.constant_offset_displace = (5.0, 0.0, 0.0)
    data, origin = reader.read_with_origins([obj], bpy.context.evaluated_depsgraph_get())[obj.name]
    assert np.all(origin >= 0) and np.all(np.bincount(origin) == 3)
    shift = data.vertices[data.loop_vertices] - own[origin]
    np.testing.assert_allclose(shift[:, 1:], 0.0, atol=1e-6)
    assert set(np.round(shift[:, 0], 4)) == {0.0, 5.0, 10.0}


@pytest.mark.versions
def test_a_subdivided_box_bakes_each_corner_as_the_applied_mesh_does_there(ovrad, fresh_scene):
    """A mesh under topology-changing modifiers is baked at the evaluated corners that copy its own
    (Cycles' rule): against the same box with the modifiers applied (the same triangles, so the same
    atlas and solve), each corner's value is the value of one of the applied mesh's corners at that
    spot on that face, and each vertex's value that of the applied mesh's vertex there."""
    obj = lit_box(SIMPLE_SPLIT)
    # the same box with its modifiers applied (baked below)
    applied = bpy.data.meshes.new_from_object(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()))
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"} and bpy.ops.ovrad.solve() == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex(domain="CORNER", attribute="c") == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex(domain="POINT", attribute="p") == {"FINISHED"}
    mesh = obj.data
    corner, point = colors(mesh, "c")[:, :3], colors(mesh, "p")[:, :3]
    assert len(corner) == len(mesh.loops) == 96 and len(point) == len(mesh.vertices) == 26
    assert np.all(point > 0.0) and np.ptp(point[:, 0]) > 0.2 * point[:, 0].max()  # lit unevenly
    positions = np.array([v.co for v in mesh.vertices])
    face_normal = np.array([mesh.polygons[i].normal for i in range(len(mesh.polygons))])
    loop_face = np.repeat(np.arange(len(mesh.polygons)), [p.loop_total for p in mesh.polygons])
    loop_vertex = np.array([lp.vertex_index for lp in mesh.loops])

    obj.modifiers.clear()
    obj.data = applied
    blender_scenes.select(obj)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"} and bpy.ops.ovrad.solve() == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex(domain="CORNER", attribute="c") == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex(domain="POINT", attribute="p") == {"FINISHED"}
    a_corner, a_point = colors(applied, "c")[:, :3], colors(applied, "p")[:, :3]
    a_positions = np.array([v.co for v in applied.vertices])
    a_normal = np.array([p.normal for p in applied.polygons])
    a_loop_face = np.repeat(np.arange(len(applied.polygons)), [p.loop_total for p in applied.polygons])
    a_loop_vertex = np.array([lp.vertex_index for lp in applied.loops])
    for v in range(len(positions)):
        (same,) = np.flatnonzero(np.all(np.abs(a_positions - positions[v]) < 1e-6, axis=1))
        # each vertex: both bakes gather there along the same normals; the corners they average
        # are nudged 1e-3 patch radii into different triangles
        np.testing.assert_allclose(point[v], a_point[same], rtol=1e-3)
        for lp in np.flatnonzero(loop_vertex == v):
            there = (a_loop_vertex == same) & np.all(
                np.abs(a_normal[a_loop_face] - face_normal[loop_face[lp]]) < 1e-5, axis=1
            )
            assert there.any()
            assert np.any(np.all(np.abs(a_corner[there] - corner[lp]) <= 1e-6 * corner[lp], axis=1))


def bevelled(obj):
    bevel = obj.modifiers.new("Bevel", "BEVEL")  # the box's edges (limited by angle), not its flat ones
    bevel.width, bevel.segments = 0.1, 2


def cut(obj):
    """A Boolean (float solver: it keeps the inside-out box's faces facing in) taking a 0.8 m cube
    off one corner of the box."""
    import bmesh

    cube = bpy.data.meshes.new("Cutter")
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=0.8)
    bm.to_mesh(cube)
    bm.free()
    cutter = bpy.data.objects.new("Cutter", cube)
    cutter.location = (1.0, 1.0, 1.0)
    cutter.hide_render = True
    bpy.context.scene.collection.objects.link(cutter)
    boolean = obj.modifiers.new("Cut", "BOOLEAN")
    boolean.object, boolean.operation = cutter, "DIFFERENCE"
    solvers = {item.identifier for item in boolean.bl_rna.properties["solver"].enum_items}
    boolean.solver = "FLOAT" if "FLOAT" in solvers else "FAST"


@pytest.mark.parametrize("modifiers", [(), SIMPLE_SPLIT], ids=["kept", "split"])
def test_a_loose_vertex_bakes_black_as_in_cycles(ovrad, fresh_scene, modifiers):
    """A vertex no face uses lies on no surface: it gets 0 (Cycles' own vertex bake leaves it black),
    with or without modifiers that change the topology; every other vertex is lit."""
    obj = lit_box(modifiers)
    mesh = obj.data
    mesh.vertices.add(2)
    mesh.vertices[-2].co = (0.1, 0.2, 0.3)  # inside the box, where light arrives
    mesh.vertices[-1].co = (0.99, 0.0, 0.0)  # next to a lit wall
    mesh.update()
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"} and bpy.ops.ovrad.solve() == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    point = colors(mesh, "ovrad_radiance")[:, :3]
    assert np.all(point[-2:] == 0.0)
    assert np.all(point[:-2] > 0.0)


@pytest.mark.versions
@pytest.mark.parametrize("modify", [bevelled, cut], ids=["bevel", "boolean"])
def test_a_vertex_without_a_copy_bakes_at_the_evaluated_vertex_nearest_it(ovrad, fresh_scene, modify):
    """A bevel replaces the box's corners and edge vertices, a boolean cuts one corner away: those
    vertices take the value the applied mesh has at its vertex nearest them; the others, the value
    it has at their copies (both bakes gather at the same corners; a corner nudged 1e-3 patch
    radii into another triangle moves its value by far less than 1e-3)."""
    obj = lit_box()
    modify(obj)
    blender_scenes.select(obj)
    applied = bpy.data.meshes.new_from_object(obj.evaluated_get(bpy.context.evaluated_depsgraph_get()))
    before = sorted(a.name for a in obj.data.attributes)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"} and bpy.ops.ovrad.solve() == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    assert sorted(a.name for a in obj.data.attributes) == sorted([*before, "ovrad_radiance"])
    point = colors(obj.data, "ovrad_radiance")[:, :3]
    positions = np.array([v.co for v in obj.data.vertices])
    obj.modifiers.clear()
    obj.data = applied
    blender_scenes.select(obj)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"} and bpy.ops.ovrad.solve() == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    a_point = colors(applied, "ovrad_radiance")[:, :3]
    a_positions = np.array([v.co for v in applied.vertices])
    copies = 0
    for v in range(len(positions)):
        dist = np.linalg.norm(a_positions - positions[v], axis=1)
        copies += dist.min() < 1e-6
        nearest = np.flatnonzero(dist <= dist.min() + 1e-6)  # ties: the box is symmetric
        assert any(np.allclose(point[v], a_point[k], rtol=1e-3) for k in nearest)
    assert np.all(point > 0.0) and 0 < copies < len(positions)


def test_modifiers_that_drop_the_mesh_attributes_are_refused_with_what_to_do(ovrad, fresh_scene):
    # a voxel remesh faces the box out: lit from above
    obj = lit_box((("REMESH", {"mode": "VOXEL", "voxel_size": 0.25}),), lamp_at=(0.0, 0.0, 3.0))
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"} and bpy.ops.ovrad.solve() == {"FINISHED"}
    attributes = sorted(a.name for a in obj.data.attributes)
    with pytest.raises(RuntimeError, match="apply the modifiers first"):
        bpy.ops.ovrad.bake_vertex()
    assert sorted(a.name for a in obj.data.attributes) == attributes


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
    tri_verts = np.array([[0, 1, 2], [3, 0, 4]])
    bake.corners = bake.loops = np.arange(6)
    bake.vertices = bake.loop_vertices = tri_verts.ravel()
    bake.positions = pos
    bake.angles = ovrad.operators.bake_vertex.corner_angles(pos[tri_verts]).ravel()
    bake.n_vertices, bake.n_loops = 5, 6
    bake.loose = np.zeros(0, np.int64)  # every vertex has a face
    bake.no_area = np.array([False, True])
    corner = np.array([1.0, 1.0, 1.0, 0.2, 0.0, 0.4])[:, None] * np.ones(3)  # (corner, channel)
    got = bake.domain_values(corner, "POINT")[:, 0]
    np.testing.assert_allclose(got, [1.0, 1.0, 1.0, 0.2, 0.4])
    # without the rule (all three corners weighed by angle): vertex 0 read (pi/2 + 0) / (pi/2 + pi)
    bake.no_area = np.array([False, False])
    assert bake.domain_values(corner, "POINT")[0, 0] < 0.4


def test_a_flat_shaded_sphere_gathers_once_per_vertex_for_the_point_domain(ovrad, fresh_scene, monkeypatch):
    """A vertex of a flat-shaded sphere (faces 22.5 degrees apart) gathers once for all the faces
    around it when the vertex domain averages them (bake.gather.shared_normals), once per face for the
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
    gather = ovrad.ovrad_addon.bake.gather
    counted = []
    original = gather.gather_indirect

    def counting(problem, gather, points, *args, **kwargs):
        counted.append(int(np.sum(np.linalg.norm(points, axis=1) < 0.6)))  # the sphere's (radius 0.5)
        return original(problem, gather, points, *args, **kwargs)

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
