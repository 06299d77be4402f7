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
    light = io.materials.read_material(mat, warnings)
    return light.reflectance, light.emission, warnings


@pytest.mark.versions
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


@pytest.mark.versions
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


@pytest.mark.versions
def test_unreadable_materials_give_their_viewport_colour_and_a_warning_naming_them(io):
    glassy = material("Glassy", "ShaderNodeBsdfGlass")
    glassy.diffuse_color = (0.3, 0.6, 0.9, 1.0)
    rho, _, w = colors(io, glassy)
    assert np.allclose(rho, [0.3, 0.6, 0.9]) and len(w) == 1 and "'Glassy'" in w[0] and "viewport" in w[0]
    # a procedural texture cannot be read: the viewport colour, one warning naming the socket
    mat = material("Procedural", "ShaderNodeBsdfPrincipled")
    mat.diffuse_color = (0.2, 0.4, 0.1, 1.0)
    tex = mat.node_tree.nodes.new("ShaderNodeTexChecker")
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    light = io.materials.read_material(mat, w := [])
    assert light.texture is None and np.allclose(light.reflectance, [0.2, 0.4, 0.1])
    assert len(w) == 1 and "'Procedural'" in w[0] and "Base Color" in w[0]


# 8-bit sRGB values as Blender stores them (byte / 255), and their linear values by the sRGB
# transfer function: 128/255 (0.5 rounded up) decodes to 0.2158 (0.5 itself to 0.2140)
BYTES = np.array([[[128, 64, 255], [0, 200, 32]], [[10, 128, 90], [255, 255, 0]]]) / 255.0


def srgb_decoded(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def image(name="tex"):
    """A 2 x 2 8-bit sRGB image of BYTES (row 0 at the bottom)."""
    img = bpy.data.images.new(name, 2, 2, alpha=False)
    img.colorspace_settings.name = "sRGB"  # before the pixels: it regenerates a generated image
    px = np.concatenate([BYTES, np.ones((2, 2, 1))], axis=-1).astype(np.float32)
    img.pixels.foreach_set(px.ravel())
    return img


def textured(name, shader="ShaderNodeBsdfPrincipled", uv_map=None):
    """A material whose colour is an Image Texture, through the active UV map (no Vector link)
    or through a UV Map node naming uv_map."""
    mat = material(name, shader)
    tree = mat.node_tree
    node = next(n for n in tree.nodes if n.bl_idname == shader)
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image(f"{name}.png")
    tree.links.new(tex.outputs["Color"], node.inputs["Base Color" if "Principled" in shader else "Color"])
    if uv_map is not None:
        uv = tree.nodes.new("ShaderNodeUVMap")
        uv.uv_map = uv_map
        tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    return mat


@pytest.mark.versions
def test_an_image_texture_is_read_as_linear_pixels(io):
    for shader in ("ShaderNodeBsdfPrincipled", "ShaderNodeBsdfDiffuse"):
        light = io.materials.read_material(textured(shader[-9:], shader), w := [])
        assert w == [] and light.texture is not None and light.texture.uv_map == ""
        px = light.texture.pixels
        assert px.shape == (2, 2, 3)
        np.testing.assert_allclose(px, srgb_decoded(BYTES), atol=1e-6)
        assert px[0, 0, 0] == pytest.approx(0.2158, abs=1e-4)
        # the constant is the image's mean (what per-triangle code uses)
        np.testing.assert_allclose(
            light.reflectance, srgb_decoded(BYTES).reshape(-1, 3).mean(axis=0), atol=1e-6
        )


def uv_plane(*layers):
    """A 1 x 1 plane (2 triangles) with UV layers of the given names: layer i holds the UVs
    (x + 0.5) / (i + 1), (y + 0.5) / (i + 1) of each loop's vertex."""
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    plane = bpy.context.active_object
    me = plane.data
    while me.uv_layers:
        me.uv_layers.remove(me.uv_layers[0])
    co = np.array([v.co[:2] for v in me.vertices])
    loops = np.array([lp.vertex_index for lp in me.loops])
    for i, name in enumerate(layers):
        lay = me.uv_layers.new(name=name)
        lay.data.foreach_set("uv", ((co[loops] + 0.5) / (i + 1)).astype(np.float32).ravel())
    return plane


def plane_uv(surfaces, layer):
    """The UVs (T, 3, 2) uv_plane's layer would give each triangle corner of surfaces."""
    return (surfaces.corners[..., :2] + 0.5) / (layer + 1)


@pytest.mark.versions
def test_textures_reach_the_surfaces_through_the_active_or_a_named_uv_map(io):
    plane = uv_plane("First", "Second")
    plane.data.uv_layers["First"].active_render = True
    plane.data.materials.append(textured("ByActive"))
    meshes = io.read_scene(bpy.context.evaluated_depsgraph_get(), [plane])
    s = meshes.surfaces
    assert meshes.warnings == [] and s.albedo is not None and len(s.albedo.images) == 1
    assert np.all(s.albedo.image_of == 0)
    np.testing.assert_allclose(s.albedo.uv, plane_uv(s, 0), atol=1e-6)
    # an 8-bit sRGB image goes to the engine as stored, decoded after interpolation (as Cycles does)
    np.testing.assert_allclose(s.albedo.images[0], BYTES, atol=1e-6)
    assert s.albedo.srgb == (True,)
    plane.data.materials[0] = textured("BySecond", uv_map="Second")
    s = io.read_scene(bpy.context.evaluated_depsgraph_get(), [plane]).surfaces
    np.testing.assert_allclose(s.albedo.uv, plane_uv(s, 1), atol=1e-6)
    # the albedo at a point is the texture's there: the plane's centre is UV (0.25, 0.25) on the
    # second map, the centre of texel (0, 0)
    centre = s.reflectance_at(np.array([0]), np.zeros((1, 3)))
    np.testing.assert_allclose(centre[0], srgb_decoded(BYTES)[0, 0], atol=1e-6)


def test_a_missing_uv_map_gives_the_images_mean_and_a_warning(io):
    plane = uv_plane("First")
    plane.data.materials.append(textured("Lost", uv_map="Gone"))
    meshes = io.read_scene(bpy.context.evaluated_depsgraph_get(), [plane])
    assert meshes.surfaces.albedo is None
    np.testing.assert_allclose(
        meshes.surfaces.reflectance,
        np.tile(srgb_decoded(BYTES).reshape(-1, 3).mean(axis=0), (2, 1)),
        atol=1e-6,
    )
    assert len(meshes.warnings) == 1 and "'Gone'" in meshes.warnings[0] and "'Lost'" in meshes.warnings[0]


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
