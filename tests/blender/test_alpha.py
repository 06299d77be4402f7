"""A material's alpha as Cycles uses it (operators/materials.py, scene_io.py): a constant Alpha, an
Image Texture's Alpha output through a UV map, a Mix Shader over a Transparent BSDF; what reaches
the engine's Coverage, and what is read as opaque with a warning."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

# an 8-bit RGBA image of 2 x 2 texels, alpha 0, 1 / 255, 128 / 255, 1 (row 0 at the bottom)
ALPHA = np.array([[0, 1], [128, 255]]) / 255.0


@pytest.fixture
def io(ovrad, fresh_scene):
    return ovrad.operators.scene_io


def _image():
    img = bpy.data.images.new("mask.png", 2, 2, alpha=True)
    px = np.zeros((2, 2, 4), np.float32)
    px[..., :3] = 0.5
    px[..., 3] = ALPHA
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


def _principled(name):
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (0.6, 0.6, 0.6, 1.0)
    return mat, bsdf


def _plane(mat):
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.active_object
    plane.data.materials.append(mat)
    return plane


def _read(io, plane):
    return io.read_scene(bpy.context.evaluated_depsgraph_get(), [plane])


@pytest.mark.versions
def test_a_constant_alpha_reaches_every_triangle(io):
    mat, bsdf = _principled("Veil")
    bsdf.inputs["Alpha"].default_value = 0.35
    meshes = _read(io, _plane(mat))
    cov = meshes.surfaces.coverage
    assert meshes.warnings == [] and cov is not None
    np.testing.assert_allclose(cov.opacity, 0.35, atol=1e-7)  # a float32 socket
    assert cov.image_of is None


def test_an_opaque_material_gives_no_coverage(io):
    mat, _ = _principled("Solid")
    assert _read(io, _plane(mat)).surfaces.coverage is None


@pytest.mark.versions
def test_an_image_alpha_is_read_through_the_uv_map(io):
    mat, bsdf = _principled("Leaf")
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = _image()
    mat.node_tree.links.new(tex.outputs["Alpha"], bsdf.inputs["Alpha"])
    plane = _plane(mat)
    s = _read(io, plane).surfaces
    cov = s.coverage
    assert cov is not None and len(cov.images) == 1 and np.all(cov.image_of == 0)
    np.testing.assert_allclose(cov.images[0], ALPHA, atol=1e-6)  # alpha is not colour-managed
    # the plane's UVs span the image once: its centre is where the four texels meet
    centre = s.opacity_at(np.array([0]), np.zeros((1, 3)))
    np.testing.assert_allclose(centre, ALPHA.mean(), atol=1e-6)
    # an image whose Alpha mode is None gives alpha 1: opaque
    tex.image.alpha_mode = "NONE"
    assert _read(io, plane).surfaces.coverage is None


@pytest.mark.parametrize("transparent_first", [True, False])
def test_a_mix_shader_over_a_transparent_bsdf_is_read_as_alpha(io, transparent_first):
    mat, bsdf = _principled("Card")
    tree = mat.node_tree
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    mix = tree.nodes.new("ShaderNodeMixShader")
    clear = tree.nodes.new("ShaderNodeBsdfTransparent")
    mix.inputs[0].default_value = 0.3
    tree.links.new(clear.outputs[0], mix.inputs[1 if transparent_first else 2])
    tree.links.new(bsdf.outputs[0], mix.inputs[2 if transparent_first else 1])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    meshes = _read(io, _plane(mat))
    # Mix Shader: (1 - fac) x first + fac x second; the Principled BSDF's share is the alpha
    want = 0.3 if transparent_first else 0.7
    assert meshes.warnings == []
    np.testing.assert_allclose(meshes.surfaces.coverage.opacity, want, atol=1e-6)
    np.testing.assert_allclose(meshes.surfaces.reflectance, 0.6, atol=1e-6)  # the BSDF under it


def test_an_alpha_the_reader_cannot_follow_is_opaque_with_a_warning(io):
    mat, bsdf = _principled("Odd")
    math = mat.node_tree.nodes.new("ShaderNodeMath")
    mat.node_tree.links.new(math.outputs[0], bsdf.inputs["Alpha"])
    meshes = _read(io, _plane(mat))
    assert meshes.surfaces.coverage is None
    assert any("Alpha driven by a Math node" in w and "'Odd'" in w for w in meshes.warnings)
