"""A Principled BSDF's diffuse share as Cycles' diffuse bake reports it (operators/principled.py):
the reader's bake weight and reflectance against Cycles' own DIFFUSE colour pass, at parameters
between the table's rows and columns, and a lit floor baked by ovrad against the closed form
times that weight."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

# (roughness, IOR, Specular IOR Level, Metallic, Transmission Weight): off the table's grid
CASES = [
    (0.35, 1.5, 0.5, 0.0, 0.0),
    (0.75, 1.7, 0.5, 0.0, 0.0),
    (0.5, 1.45, 0.8, 0.0, 0.0),
    (0.15, 2.2, 0.5, 0.0, 0.0),
    (0.5, 1.5, 0.5, 0.4, 0.0),
    (0.6, 1.5, 0.5, 0.0, 0.3),
    (0.6, 1.5, 0.0, 0.0, 0.0),
]


def principled(name, roughness, ior, level, metallic, transmission, colour=(0.8, 0.6, 0.4)):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["IOR"].default_value = ior
    bsdf.inputs["Specular IOR Level"].default_value = level
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Transmission Weight"].default_value = transmission
    return mat


def colour_pass(materials, tmp_path) -> np.ndarray:
    """Cycles' DIFFUSE colour pass (k, 3) of one plane per material: the diffuse lobe's weight x
    its colour, viewed along the normal (no light involved, no noise)."""
    for k, mat in enumerate(materials):
        mesh = bpy.data.meshes.new(f"plane{k}")
        mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
        mesh.materials.append(mat)
        obj = bpy.data.objects.new(mesh.name, mesh)
        obj.location = (2.0 * k, 0.0, 0.0)
        bpy.context.scene.collection.objects.link(obj)
        mesh.color_attributes.new("weight", "FLOAT_COLOR", "POINT")
    path = tmp_path / "layers.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples = "CPU", 1
    planes = [scene.objects[f"plane{k}"] for k in range(len(materials))]
    for obj in scene.objects:
        obj.select_set(obj in planes)
        obj.data.color_attributes.active_color = obj.data.color_attributes["weight"]
    bpy.context.view_layer.objects.active = planes[0]
    assert bpy.ops.object.bake(type="DIFFUSE", pass_filter={"COLOR"}, target="VERTEX_COLORS") == {"FINISHED"}
    out = []
    for obj in planes:
        data = obj.data.color_attributes["weight"].data
        v = np.empty(4 * len(data), np.float32)
        data.foreach_get("color", v)
        out.append(v.reshape(-1, 4)[:, :3].mean(axis=0))
    return np.array(out, np.float64)


def test_the_diffuse_share_is_cycles_colour_pass(ovrad, fresh_scene, tmp_path):
    # The table is Cycles' colour pass on a grid (benchmarks/principled_layer.py); between its
    # nodes it is interpolated: within 2e-3 of Cycles (the interpolation's error), where leaving
    # the layers out is 0.03-0.6 off (metallic 0.4: 40 %).
    materials = [principled(f"case{k}", *case) for k, case in enumerate(CASES)]
    read = []
    for mat in materials:
        warnings: list[str] = []
        light = ovrad.operators.materials.read_material(mat, warnings)
        assert warnings == []
        read.append(light.reflectance * light.bake_weight)
    read = np.array(read)
    baked = colour_pass(materials, tmp_path)
    plain = np.array([0.8, 0.6, 0.4])
    assert np.all(np.abs(baked[:-1] - plain).max(axis=1) > 0.01)  # the layers matter...
    np.testing.assert_allclose(baked[-1], plain, atol=1e-5)  # ...but a Specular IOR Level 0 has none
    np.testing.assert_allclose(read, baked, atol=2e-3)


def test_a_diffuse_bsdf_and_the_defaults_of_the_reader(ovrad, fresh_scene):
    # A Diffuse BSDF has no upper layer; a Principled BSDF's roughness driven by a texture is
    # read as Blender's default 0.5, its metallic driven by nodes as 0.
    mat = bpy.data.materials.new("diffuse")
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.remove(next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"))
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    tree.links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
    warnings: list[str] = []
    light = ovrad.operators.materials.read_material(mat, warnings)
    assert light.bake_weight == 1.0
    np.testing.assert_allclose(light.reflectance, 0.5)
    driven = principled("driven", 0.9, 1.5, 0.5, 0.0, 0.0)
    bsdf = next(n for n in driven.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    noise = driven.node_tree.nodes.new("ShaderNodeTexNoise")
    driven.node_tree.links.new(noise.outputs["Fac"], bsdf.inputs["Roughness"])
    driven.node_tree.links.new(noise.outputs["Fac"], bsdf.inputs["Metallic"])
    light = ovrad.operators.materials.read_material(driven, warnings)
    principled_module = ovrad.operators.principled
    assert light.bake_weight == pytest.approx(principled_module.layer_weight(0.5, 0.04))
    np.testing.assert_allclose(light.reflectance, [0.8, 0.6, 0.4])


def test_a_gltf_material_without_its_textures_is_read_as_cycles_renders_it(ovrad, fresh_scene, tmp_path):
    # A glTF import (the BoomBox asset) whose images are missing: Cycles renders each missing image
    # magenta, so the metallic-roughness map's Separate Color gives Metallic (blue) 1 and Roughness
    # (green) 0: a mirror-like metal, no diffuse light. The reader follows the Separate Color to the
    # same values; a map that is there (varying) is not read (Metallic 0, Roughness 0.5).
    mat = principled("gltf", 0.5, 1.5, 0.5, 0.0, 0.0)
    tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    for name in ("base", "orm"):
        img = bpy.data.images.new(name, 4, 4)
        img.source = "FILE"
        img.filepath = str(tmp_path / f"{name}.png")  # no such file
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image = img
        if name == "base":
            tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
        else:
            split = tree.nodes.new("ShaderNodeSeparateColor")
            tree.links.new(tex.outputs["Color"], split.inputs["Color"])
            tree.links.new(split.outputs["Green"], bsdf.inputs["Roughness"])
            tree.links.new(split.outputs["Blue"], bsdf.inputs["Metallic"])
    half = principled("half", 0.5, 1.5, 0.5, 0.0, 0.0, colour=(0.8, 0.6, 0.4))
    split = half.node_tree.nodes.new("ShaderNodeSeparateColor")
    split.inputs["Color"].default_value = (0.0, 0.3, 0.5, 1.0)
    hb = next(n for n in half.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    half.node_tree.links.new(split.outputs["Green"], hb.inputs["Roughness"])
    half.node_tree.links.new(split.outputs["Blue"], hb.inputs["Metallic"])
    read = []
    for m in (mat, half):
        warnings: list[str] = []
        light = ovrad.operators.materials.read_material(m, warnings)
        read.append(light.reflectance * light.bake_weight)
    np.testing.assert_allclose(read[0], 0.0)
    np.testing.assert_allclose(read[1], np.array([0.8, 0.6, 0.4]) * 0.5 * 0.96025, rtol=2e-3)
    np.testing.assert_allclose(colour_pass([mat, half], tmp_path), np.array(read), atol=2e-3)
