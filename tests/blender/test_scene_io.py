"""Reading Blender meshes and materials into engine arrays: colours per triangle, warnings, skips."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender


@pytest.fixture
def io(ovrad, fresh_scene):
    return ovrad.operators.scene_io


def material(name, shader, **inputs):
    """A material whose surface is one shader node with the given constant inputs."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    node = tree.nodes.new(shader)
    for key, value in inputs.items():
        node.inputs[key.replace("_", " ")].default_value = value
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    return mat


def colors(io, mat):
    warnings = []
    rho, em = io.material_colors(mat, warnings)
    return rho, em, warnings


def test_principled_base_and_emission_colours_are_read(io):
    mat = material(
        "p",
        "ShaderNodeBsdfPrincipled",
        Base_Color=(0.2, 0.4, 0.6, 1),
        Emission_Color=(1, 0.5, 0.25, 1),
        Emission_Strength=4.0,
    )
    rho, em, warnings = colors(io, mat)
    assert np.allclose(rho, [0.2, 0.4, 0.6]) and np.allclose(em, [4.0, 2.0, 1.0]) and warnings == []


def test_diffuse_and_emission_shaders_are_read(io):
    rho, em, w = colors(io, material("d", "ShaderNodeBsdfDiffuse", Color=(0.1, 0.2, 0.3, 1)))
    assert np.allclose(rho, [0.1, 0.2, 0.3]) and np.allclose(em, 0.0) and w == []
    # An Emission shader reflects nothing in Cycles; its radiance is colour x strength.
    rho, em, w = colors(
        io, material("e", "ShaderNodeEmission", Color=(17 / 17, 12 / 17, 4 / 17, 1), Strength=17.0)
    )
    assert np.allclose(rho, 0.0) and np.allclose(em, [17.0, 12.0, 4.0]) and w == []


def test_no_material_is_the_grey_blender_renders_without_warning(io):
    rho, em, w = colors(io, None)
    assert np.allclose(rho, 0.8) and np.allclose(em, 0.0) and w == []


def test_unreadable_materials_give_grey_and_a_warning_naming_them(io):
    rho, _, w = colors(io, material("Glassy", "ShaderNodeBsdfGlass"))
    assert np.allclose(rho, 0.8) and len(w) == 1 and "'Glassy'" in w[0] and "grey 0.8" in w[0]
    mat = material("Textured", "ShaderNodeBsdfPrincipled")
    tex = mat.node_tree.nodes.new("ShaderNodeTexChecker")
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    rho, _, w = colors(io, mat)
    assert np.allclose(rho, 0.8) and len(w) == 1 and "'Textured'" in w[0] and "Base Color" in w[0]


def test_reflectance_above_one_is_clamped_with_a_warning(io):
    rho, _, w = colors(io, material("Hot", "ShaderNodeBsdfDiffuse", Color=(1.5, 0.5, 0.5, 1)))
    assert np.allclose(rho, [1.0, 0.5, 0.5]) and "'Hot'" in w[0] and "clamped" in w[0]


def test_each_triangle_gets_its_slots_colour_in_world_space(io):
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0, 0, 3))
    plane = bpy.context.active_object
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.subdivide()  # 4 quads
    bpy.ops.object.mode_set(mode="OBJECT")
    red = material("red", "ShaderNodeBsdfDiffuse", Color=(0.9, 0.1, 0.1, 1))
    lamp = material("lamp", "ShaderNodeEmission", Color=(1, 1, 1, 1), Strength=2.0)
    plane.data.materials.append(red)
    plane.data.materials.append(lamp)
    left = np.array([p.center.x < 0 for p in plane.data.polygons])
    plane.data.polygons.foreach_set("material_index", left.astype(np.int32))
    meshes = io.read_scene(bpy.context.evaluated_depsgraph_get(), [plane])
    s = meshes.surfaces
    assert len(s.triangles) == 8 and np.allclose(s.vertices[:, 2], 3.0)
    centre_x = s.corners.mean(axis=1)[:, 0]
    on_left = centre_x < 0
    assert np.allclose(s.reflectance[~on_left], [0.9, 0.1, 0.1]) and np.allclose(s.emission[~on_left], 0.0)
    assert np.allclose(s.reflectance[on_left], 0.0) and np.allclose(s.emission[on_left], 2.0)


def test_meshes_without_faces_are_skipped_and_all_faceless_is_an_error(io, ovrad):
    mesh = bpy.data.meshes.new("points")
    mesh.vertices.add(3)
    points = bpy.data.objects.new("points", mesh)
    bpy.context.scene.collection.objects.link(points)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    meshes = io.read_scene(bpy.context.evaluated_depsgraph_get(), [points, cube])
    assert meshes.surfaces.object_names == (cube.name,)
    assert meshes.warnings == ["'points' has no faces; skipped (give it faces or leave it out)"]
    with pytest.raises(ovrad.ovrad_addon.errors.OvradError, match="no faces"):
        io.read_scene(bpy.context.evaluated_depsgraph_get(), [points])
