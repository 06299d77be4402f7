"""Colour nodes between a colour source and a shader (Hue/Saturation/Value, Gamma,
Brightness/Contrast, RGB Curves, every Mix blend type): what the material reader makes of them
on a constant, an Image Texture's texels and painted colours, against Cycles' formulas written out
here per colour (intern/cycles/kernel/svm/color_util.h, hsv.h, gamma.h; hue and saturation by
Python's colorsys, which converts as Cycles does), and against Cycles itself: an emission bake of
a plane through a chain of these nodes gives, texel by texel, the colour the reader gives."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

A, B = (0.2, 0.6, 0.9), (0.4, 0.1, 0.8)
FACTOR = 0.7
BLENDS = (
    "MIX ADD MULTIPLY SUBTRACT SCREEN OVERLAY DIVIDE DIFFERENCE EXCLUSION DARKEN LIGHTEN DODGE BURN "
    "SOFT_LIGHT LINEAR_LIGHT HUE SATURATION COLOR VALUE"
).split()


# --- Cycles' formulas, one colour at a time --------------------------------------------------


def lerp(x, y, t):
    return x + t * (y - x)


def mix_one(blend, t, a, b):
    """Cycles' svm_mix_* of one colour pair (tuples), channel by channel."""
    tm = 1.0 - t
    per = {
        "MIX": lambda x, y: lerp(x, y, t),
        "ADD": lambda x, y: lerp(x, x + y, t),
        "MULTIPLY": lambda x, y: lerp(x, x * y, t),
        "SUBTRACT": lambda x, y: lerp(x, x - y, t),
        "SCREEN": lambda x, y: 1.0 - (tm + t * (1.0 - y)) * (1.0 - x),
        "OVERLAY": lambda x, y: x * (tm + 2 * t * y) if x < 0.5 else 1 - (tm + 2 * t * (1 - y)) * (1 - x),
        "DIVIDE": lambda x, y: tm * x + t * x / y if y != 0.0 else x,
        "DIFFERENCE": lambda x, y: lerp(x, abs(x - y), t),
        "EXCLUSION": lambda x, y: max(lerp(x, x + y - 2 * x * y, t), 0.0),
        "DARKEN": lambda x, y: lerp(x, min(x, y), t),
        "LIGHTEN": lambda x, y: lerp(x, max(x, y), t),
        "DODGE": lambda x, y: x if x == 0 else (1.0 if 1 - t * y <= 0 else min(x / (1 - t * y), 1.0)),
        "BURN": lambda x, y: 0.0 if tm + t * y <= 0 else min(max(1 - (1 - x) / (tm + t * y), 0.0), 1.0),
        "SOFT_LIGHT": lambda x, y: tm * x + t * ((1 - x) * y * x + x * (1 - (1 - y) * (1 - x))),
        "LINEAR_LIGHT": lambda x, y: x + t * (2 * y - 1),
    }
    if blend in per:
        return tuple(per[blend](x, y) for x, y in zip(a, b, strict=True))
    ha, hb = colorsys.rgb_to_hsv(*a), colorsys.rgb_to_hsv(*b)
    if blend == "HUE":
        c = colorsys.hsv_to_rgb(hb[0], ha[1], ha[2]) if hb[1] != 0 else a
        return tuple(lerp(x, y, t) for x, y in zip(a, c, strict=True))
    if blend == "COLOR":
        c = colorsys.hsv_to_rgb(hb[0], hb[1], ha[2]) if hb[1] != 0 else a
        return tuple(lerp(x, y, t) for x, y in zip(a, c, strict=True))
    if blend == "SATURATION":
        return colorsys.hsv_to_rgb(ha[0], tm * ha[1] + t * hb[1], ha[2]) if ha[1] != 0 else a
    assert blend == "VALUE"
    return colorsys.hsv_to_rgb(ha[0], ha[1], tm * ha[2] + t * hb[2])


def hsv_one(c, hue, sat, val, fac):
    """Cycles' Hue/Saturation/Value node on one colour."""
    h, s, v = colorsys.rgb_to_hsv(*c)
    out = colorsys.hsv_to_rgb((h + hue + 0.5) % 1.0, min(max(s * sat, 0.0), 1.0), v * val)
    return tuple(max(fac * y + (1 - fac) * x, 0.0) for x, y in zip(c, out, strict=True))


def gamma_one(c, g):
    return tuple(1.0 if g == 0 else (x**g if x > 0 else x) for x in c)


def bright_contrast_one(c, bright, contrast):
    return tuple(max((1 + contrast) * x + bright - contrast / 2, 0.0) for x in c)


def per_colour(fn, colours, *args):
    """fn of each colour of an array (..., 3)."""
    flat = np.asarray(colours, float).reshape(-1, 3)
    return np.array([fn(tuple(c), *args) for c in flat]).reshape(np.shape(colours))


# --- materials ---------------------------------------------------------------------------------


def emission_material(name):
    """A material whose surface is an Emission shader (strength 1); its tree and that shader."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    shader = tree.nodes.new("ShaderNodeEmission")
    shader.inputs["Strength"].default_value = 1.0
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(shader.outputs[0], out.inputs["Surface"])
    return mat, tree, shader


def feed(tree, source, socket):
    """Plug a colour source into a socket: an RGB triple, an image (Image Texture through the UV
    map, Closest: see the bake test) or a colour attribute's name (Color Attribute node)."""
    if isinstance(source, bpy.types.Image):
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image, node.interpolation = source, "Closest"
        tree.links.new(node.outputs["Color"], socket)
    elif isinstance(source, str):
        node = tree.nodes.new("ShaderNodeVertexColor")
        node.layer_name = source
        tree.links.new(node.outputs["Color"], socket)
    else:
        socket.default_value = (*source, 1.0)


def colour_node(tree, kind, source, **inputs):
    """A colour node (bl_idname kind) fed by source, its inputs (by identifier) set; its output."""
    node = tree.nodes.new(kind)
    by_id = {s.identifier: s for s in node.inputs}
    for key, value in inputs.items():
        by_id[key].default_value = value
    feed(tree, source, by_id["Color"])
    return node


def mix_node(tree, blend, a, b, factor=FACTOR, clamp_result=False):
    node = tree.nodes.new("ShaderNodeMix")
    node.data_type, node.blend_type, node.clamp_result = "RGBA", blend, clamp_result
    by_id = {s.identifier: s for s in node.inputs}
    by_id["Factor_Float"].default_value = factor
    feed(tree, a, by_id["A_Color"])
    feed(tree, b, by_id["B_Color"])
    return node


def result(node):
    return next(s for s in node.outputs if s.identifier in ("Color", "Result_Color"))


def read(ovrad, mat):
    warnings = []
    light = ovrad.operators.materials.read_material(mat, warnings)
    return light, warnings


def float_image(name, pixels):
    """A float image of linear RGB pixels (h, w, 3), row 0 at the bottom."""
    h, w = pixels.shape[:2]
    img = bpy.data.images.new(name, w, h, float_buffer=True)
    rgba = np.concatenate([pixels, np.ones((h, w, 1))], axis=2).astype(np.float32)
    img.pixels.foreach_set(rgba.ravel())
    return img


TEXELS = np.random.default_rng(7).uniform(0.05, 0.95, (3, 4, 3))
RGB = np.array([[0.1, 0.5, 0.9], [0.8, 0.3, 0.3], [0.45, 0.45, 0.45], [0.0, 0.7, 0.2]])


# --- the reader against the formulas --------------------------------------------------------------


@pytest.mark.parametrize("blend", BLENDS)
def test_every_blend_type_on_constants_a_texture_and_paint(ovrad, fresh_scene, blend):
    # constants: the colour of the formula (emission is read unclamped above, clamped at 0)
    mat, tree, shader = emission_material(blend)
    tree.links.new(result(mix_node(tree, blend, A, B)), shader.inputs["Color"])
    light, warnings = read(ovrad, mat)
    assert warnings == []
    np.testing.assert_allclose(light.emission, np.maximum(mix_one(blend, FACTOR, A, B), 0), atol=1e-6)
    # a texture as A, a constant as B: the texels through the formula
    image = float_image("tex", TEXELS)
    mat, tree, shader = emission_material(blend + " tex")
    tree.links.new(result(mix_node(tree, blend, image, B)), shader.inputs["Color"])
    light, warnings = read(ovrad, mat)
    term = light.emitted
    assert warnings == [] and term.paint is None
    expected = per_colour(lambda c: mix_one(blend, FACTOR, c, B), TEXELS)
    np.testing.assert_allclose(term.tint * term.texture.pixels, expected, atol=1e-5)  # float32 texels
    # paint as B, a constant as A: each painted colour through the formula
    mat, tree, shader = emission_material(blend + " paint")
    tree.links.new(result(mix_node(tree, blend, A, "Paint")), shader.inputs["Color"])
    light, warnings = read(ovrad, mat)
    term = light.emitted
    assert warnings == [] and term.texture is None and term.paint.attribute == "Paint"
    expected = per_colour(lambda c: mix_one(blend, FACTOR, A, c), RGB)
    # within float32: the constants are socket values
    np.testing.assert_allclose(term.tint * term.paint.colours(RGB), expected, atol=1e-6)


def test_two_textures_mix_texel_by_texel_and_paint_with_itself(ovrad, fresh_scene):
    other = np.random.default_rng(8).uniform(0.05, 0.95, TEXELS.shape)
    mat, tree, shader = emission_material("two")
    tree.links.new(
        result(mix_node(tree, "OVERLAY", float_image("a", TEXELS), float_image("b", other))),
        shader.inputs["Color"],
    )
    light, warnings = read(ovrad, mat)
    assert warnings == []
    expected = np.array(
        [
            mix_one("OVERLAY", FACTOR, tuple(x), tuple(y))
            for x, y in zip(TEXELS.reshape(-1, 3), other.reshape(-1, 3), strict=True)
        ]
    ).reshape(TEXELS.shape)
    np.testing.assert_allclose(light.emitted.tint * light.emitted.texture.pixels, expected, atol=1e-5)
    # one attribute on both sides, Screen then clamped: per colour
    mat, tree, shader = emission_material("paint twice")
    tree.links.new(
        result(mix_node(tree, "SCREEN", "Paint", "Paint", clamp_result=True)), shader.inputs["Color"]
    )
    light, _ = read(ovrad, mat)
    expected = np.clip(per_colour(lambda c: mix_one("SCREEN", FACTOR, c, c), RGB), 0, 1)
    # within float32: the constants are socket values
    np.testing.assert_allclose(light.emitted.tint * light.emitted.paint.colours(RGB), expected, atol=1e-6)


def test_a_clamped_result_and_the_legacy_mix_node(ovrad, fresh_scene):
    mat, tree, shader = emission_material("clamped add")
    tree.links.new(result(mix_node(tree, "ADD", A, B, factor=1.0, clamp_result=True)), shader.inputs["Color"])
    light, _ = read(ovrad, mat)
    np.testing.assert_allclose(light.emission, np.minimum(np.add(A, B), 1.0), atol=1e-6)  # 1.7 -> 1
    # the legacy MixRGB node: Color1, Color2, a factor always clamped, Clamp on the result
    mat, tree, shader = emission_material("legacy")
    node = tree.nodes.new("ShaderNodeMixRGB")
    node.blend_type, node.use_clamp = "DODGE", True
    node.inputs["Fac"].default_value = 1.5  # read as 1
    feed(tree, "Paint", node.inputs["Color1"])
    feed(tree, B, node.inputs["Color2"])
    tree.links.new(node.outputs["Color"], shader.inputs["Color"])
    light, warnings = read(ovrad, mat)
    assert warnings == []
    expected = np.clip(per_colour(lambda c: mix_one("DODGE", 1.0, c, B), RGB), 0, 1)
    # within float32: the constants are socket values
    np.testing.assert_allclose(light.emitted.tint * light.emitted.paint.colours(RGB), expected, atol=1e-6)


NODES = [
    ("ShaderNodeHueSaturation", dict(Hue=0.62, Saturation=1.4, Value=0.8, Fac=0.9), hsv_one),
    ("ShaderNodeGamma", dict(Gamma=2.2), gamma_one),
    ("ShaderNodeBrightContrast", dict(Bright=0.1, Contrast=0.3), bright_contrast_one),
]


@pytest.mark.parametrize(("kind", "inputs", "formula"), NODES, ids=[n[0][10:] for n in NODES])
def test_colour_nodes_on_a_constant_a_texture_and_paint(ovrad, fresh_scene, kind, inputs, formula):
    args = list(inputs.values())
    # a constant: the emission of the formula
    mat, tree, shader = emission_material(kind)
    tree.links.new(result(colour_node(tree, kind, A, **inputs)), shader.inputs["Color"])
    light, warnings = read(ovrad, mat)
    assert warnings == []
    np.testing.assert_allclose(light.emission, formula(A, *args), atol=1e-6)
    mat, tree, shader = emission_material(kind + " tex")
    tree.links.new(
        result(colour_node(tree, kind, float_image("t", TEXELS), **inputs)), shader.inputs["Color"]
    )
    term = read(ovrad, mat)[0].emitted
    np.testing.assert_allclose(term.tint * term.texture.pixels, per_colour(formula, TEXELS, *args), atol=1e-5)
    # paint times a constant (a Multiply at 1) into the node: the formula of each product
    mat, tree, shader = emission_material(kind + " paint")
    node = colour_node(tree, kind, (0, 0, 0), **inputs)
    tree.links.new(result(mix_node(tree, "MULTIPLY", "Paint", B, factor=1.0)), node.inputs["Color"])
    tree.links.new(result(node), shader.inputs["Color"])
    term = read(ovrad, mat)[0].emitted
    expected = per_colour(formula, RGB * np.array(B), *args)
    # within float32: the constants are socket values
    np.testing.assert_allclose(term.tint * term.paint.colours(RGB), expected, atol=1e-6)


def curves_material(name, source, fac=0.8):
    """An RGB Curves node: the combined curve through (0, 0), (0.4, 0.6), (1, 1), red lifted to
    (0, 0.1)-(1, 0.9), green through (0.5, 0.3); its mapping updated as the editor updates it."""
    mat, tree, shader = emission_material(name)
    node = colour_node(tree, "ShaderNodeRGBCurve", source, Fac=fac)
    mapping = node.mapping
    mapping.curves[3].points.new(0.4, 0.6)
    mapping.curves[0].points[0].location = (0.0, 0.1)
    mapping.curves[0].points[1].location = (1.0, 0.9)
    mapping.curves[1].points.new(0.5, 0.3)
    mapping.update()
    tree.links.new(result(node), shader.inputs["Color"])
    return mat, mapping


def curves_exact(mapping, colours, fac):
    """The node's formula with each curve evaluated by Blender at each value (no table):
    (1 - fac) c + fac curve_k(combined(c_k))."""
    curves = mapping.curves
    flat = np.asarray(colours, float).reshape(-1, 3)
    out = [
        [mapping.evaluate(curves[k], mapping.evaluate(curves[3], float(c[k]))) for k in range(3)]
        for c in flat
    ]
    return ((1 - fac) * flat + fac * np.array(out)).reshape(np.shape(colours))


def test_rgb_curves_on_a_constant_a_texture_and_paint(ovrad, fresh_scene):
    # Cycles tabulates the curves at 257 points and interpolates linearly: within 1e-4 of the
    # curves evaluated at each value (the table's step is 1/256, these curves' bend is gentle;
    # measured 8e-6)
    mat, mapping = curves_material("curves", A)
    light, warnings = read(ovrad, mat)
    assert warnings == []
    np.testing.assert_allclose(light.emission, curves_exact(mapping, A, 0.8), atol=1e-4)
    mat, mapping = curves_material("curves tex", float_image("t", TEXELS))
    term = read(ovrad, mat)[0].emitted
    np.testing.assert_allclose(term.texture.pixels, curves_exact(mapping, TEXELS, 0.8), atol=1e-4)
    mat, mapping = curves_material("curves paint", "Paint")
    term = read(ovrad, mat)[0].emitted
    np.testing.assert_allclose(term.paint.colours(RGB), curves_exact(mapping, RGB, 0.8), atol=1e-4)
    # the curves are not the identity: the node changes these colours by more than 0.05
    assert np.abs(term.paint.colours(RGB) - RGB).max() > 0.05


def test_what_stays_unread_falls_back_naming_the_node(ovrad, fresh_scene):
    # a Hue/Saturation/Value node whose Hue is linked
    mat, tree, shader = emission_material("linked hue")
    node = colour_node(tree, "ShaderNodeHueSaturation", A)
    tree.links.new(tree.nodes.new("ShaderNodeValue").outputs[0], node.inputs["Hue"])
    tree.links.new(result(node), shader.inputs["Color"])
    light, warnings = read(ovrad, mat)
    assert light.emitted is None and any("Hue/Saturation/Value" in w for w in warnings)
    # Gamma of a texture times paint (not a texture times paint any more)
    mat = bpy.data.materials.new("gamma of a product")
    mat.use_nodes = True
    tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    node = colour_node(tree, "ShaderNodeGamma", (0, 0, 0), Gamma=2.0)
    tree.links.new(
        result(mix_node(tree, "MULTIPLY", float_image("t", TEXELS), "Paint", factor=1.0)),
        node.inputs["Color"],
    )
    tree.links.new(result(node), bsdf.inputs["Base Color"])
    light, warnings = read(ovrad, mat)
    assert light.texture is None and light.paint is None
    assert any("Gamma" in w for w in warnings)
    np.testing.assert_allclose(light.reflectance, mat.diffuse_color[:3], atol=1e-6)


# --- against Cycles ------------------------------------------------------------------------------


def bake_emission(obj, mat, size):
    """Cycles' emission bake of obj (its material mat) into a size x size float image: linear RGB
    (size, size, 3), row 0 at the bottom; one sample at each texel's centre."""
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples = "CPU", 1
    target = bpy.data.images.new("baked", size, size, float_buffer=True)
    node = mat.node_tree.nodes.new("ShaderNodeTexImage")
    node.image = target
    mat.node_tree.nodes.active = node
    for other in bpy.context.view_layer.objects:
        other.select_set(other == obj)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.object.bake(type="EMIT", margin=0) == {"FINISHED"}
    px = np.empty(4 * size * size, np.float32)
    target.pixels.foreach_get(px)
    mat.node_tree.nodes.remove(node)
    return px.reshape(size, size, 4)[..., :3].astype(float)


def chain(tree, source, shader):
    """source -> Hue/Saturation/Value -> Gamma -> RGB Curves -> Mix Overlay with a constant ->
    Brightness/Contrast -> the shader's Color."""
    hsv = colour_node(tree, "ShaderNodeHueSaturation", source, Hue=0.6, Saturation=1.3, Value=0.9, Fac=1.0)
    gam = colour_node(tree, "ShaderNodeGamma", (0, 0, 0), Gamma=1.8)
    tree.links.new(result(hsv), gam.inputs["Color"])
    curves = colour_node(tree, "ShaderNodeRGBCurve", (0, 0, 0), Fac=1.0)
    curves.mapping.curves[3].points.new(0.3, 0.5)
    curves.mapping.update()
    tree.links.new(result(gam), curves.inputs["Color"])
    mix = mix_node(tree, "OVERLAY", (0, 0, 0), (0.3, 0.6, 0.5), factor=0.8)
    tree.links.new(result(curves), next(s for s in mix.inputs if s.identifier == "A_Color"))
    bc = colour_node(tree, "ShaderNodeBrightContrast", (0, 0, 0), Bright=0.05, Contrast=0.2)
    tree.links.new(result(mix), bc.inputs["Color"])
    tree.links.new(result(bc), shader.inputs["Color"])


def test_a_cycles_emission_bake_through_a_node_chain_gives_the_read_colours(ovrad, fresh_scene):
    # A unit plane whose UVs span the image: each baked texel's centre is a texel centre of an
    # image of that size. The source texture is sampled Closest: a bake's sample may sit off
    # the texel centre, and the test compares the nodes, not filtering.
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    plane = bpy.context.active_object
    texels = np.random.default_rng(3).uniform(0.02, 0.98, (8, 8, 3))
    mat, tree, shader = emission_material("chain tex")
    chain(tree, float_image("src", texels), shader)
    plane.data.materials.append(mat)
    light, warnings = read(ovrad, mat)
    assert warnings == []
    baked = bake_emission(plane, mat, 8)
    read_colour = light.emitted.tint * light.emitted.texture.pixels
    assert np.abs(read_colour - texels).max() > 0.1  # the chain changes the colours
    # float32 in Cycles against float64 here, the same curve table: within 2e-5 (measured 8e-7)
    np.testing.assert_allclose(baked, read_colour, atol=2e-5)


def test_a_cycles_emission_bake_of_paint_constant_per_face_is_exact(ovrad, fresh_scene):
    # A 4 x 4 grid painted one colour per face (face corners): the reader's per-corner node
    # colours are Cycles' colours wherever a face has one colour; the 16 x 16 texels' centres
    # lie inside faces.
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=4, y_subdivisions=4, size=1.0)
    grid = bpy.context.active_object
    me = grid.data
    assert len(me.polygons) == 16
    face_rgb = np.random.default_rng(4).uniform(0.02, 0.98, (16, 3))
    attr = me.color_attributes.new("Paint", "FLOAT_COLOR", "CORNER")
    rgba = np.zeros((len(me.loops), 4))
    for poly in me.polygons:
        rgba[list(poly.loop_indices)] = (*face_rgb[poly.index], 1.0)
    attr.data.foreach_set("color", rgba.ravel())
    mat, tree, shader = emission_material("chain paint")
    chain(tree, "Paint", shader)
    grid.data.materials.append(mat)
    light, warnings = read(ovrad, mat)
    assert warnings == []
    baked = bake_emission(grid, mat, 16)
    # each texel's face: the grid's faces by their centres
    centre = np.array([p.center[:2] for p in me.polygons]) + 0.5  # UV = position + 0.5
    uv = (np.stack(np.meshgrid(np.arange(16), np.arange(16)), axis=-1) + 0.5) / 16  # [row][col] = (u, v)
    face = np.argmin(np.linalg.norm(uv[..., None, :] - centre, axis=-1), axis=-1)
    read_colour = light.emitted.tint * light.emitted.paint.colours(face_rgb)
    assert np.abs(read_colour - face_rgb).max() > 0.1
    np.testing.assert_allclose(baked, read_colour[face], atol=2e-5)
    # the scene read: each triangle emits its face's colour through the chain (the attribute
    # holds float32)
    meshes = ovrad.operators.scene_io.read_scene(bpy.context.evaluated_depsgraph_get(), [grid])
    me.calc_loop_triangles()
    tri_face = np.array([t.polygon_index for t in me.loop_triangles])
    np.testing.assert_allclose(meshes.surfaces.emission, np.maximum(read_colour[tri_face], 0.0), atol=1e-6)


def test_an_8_bit_srgb_texture_is_interpolated_before_it_is_decoded(ovrad, fresh_scene):
    # Cycles keeps an 8-bit sRGB image as stored and decodes after the bilinear interpolation: the
    # colour between a bright and a dark texel is the sRGB curve of their mean, darker than the mean
    # of their linear colours. A plane whose Base Color and Emission Color are one 4 x 4 byte image
    # (Linear interpolation): the emission baked at 16 x 16 texel centres, between the image's, is
    # the albedo the scene read gives there.
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    plane = bpy.context.active_object
    stored = np.random.default_rng(6).integers(0, 256, (4, 4, 3)) / 255.0
    img = bpy.data.images.new("bytes", 4, 4)
    img.colorspace_settings.name = "sRGB"
    img.pixels.foreach_set(np.concatenate([stored, np.ones((4, 4, 1))], axis=2).astype(np.float32).ravel())
    img.pack()
    mat, tree, shader = emission_material("srgb bytes")
    tree.nodes.remove(shader)
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Emission Strength"].default_value = 1.0
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image, tex.interpolation = img, "Linear"
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Emission Color"])
    tree.links.new(
        bsdf.outputs[0], next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial").inputs[0]
    )
    plane.data.materials.append(mat)
    baked = bake_emission(plane, mat, 16)
    s = ovrad.operators.scene_io.read_scene(bpy.context.evaluated_depsgraph_get(), [plane]).surfaces
    assert s.albedo.srgb == (True,)
    uv = (np.stack(np.meshgrid(np.arange(16), np.arange(16)), axis=-1) + 0.5) / 16  # [row][col] = (u, v)
    points = np.concatenate([uv.reshape(-1, 2) - 0.5, np.zeros((256, 1))], axis=1)  # UV = position + 0.5
    down = np.tile([0.0, 0.0, -1.0], (256, 1))
    tri = ovrad.ovrad_addon.make_rays(s.vertices, s.triangles).closest_hit(points - down, down, 2.0)[1]
    read = s.reflectance_at(tri, points).reshape(16, 16, 3)
    # float32 in Cycles, where a bake sample sits in its texel: within 2e-3 (measured 9e-4)
    np.testing.assert_allclose(read, baked, atol=2e-3)
    # the other order (decode, then interpolate) misses by far more
    linear = ovrad.operators.images.srgb_to_linear(stored.astype(np.float32)).astype(float)
    x, y = uv[..., 0] * 4 - 0.5, uv[..., 1] * 4 - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    c0, c1, r0, r1 = x0 % 4, (x0 + 1) % 4, y0 % 4, (y0 + 1) % 4
    other = (linear[r0, c0] * (1 - fx) + linear[r0, c1] * fx) * (1 - fy) + (
        linear[r1, c0] * (1 - fx) + linear[r1, c1] * fx
    ) * fy
    assert np.abs(other - baked).max() > 0.02


def test_an_emission_image_reaches_the_light_as_cycles_emits_it(ovrad, fresh_scene):
    # A plane whose Emission Color is a 4 x 4 float image (Linear, strength 3): the colour the scene
    # read keeps for the light's pieces (Surfaces.emitted) is Cycles' own emission bake at 16 x 16
    # texel centres, between the image's; each triangle's emission is its mean, and its light comes
    # from pieces that each emit their own (light.emitters.emission_pieces).
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    plane = bpy.context.active_object
    pixels = np.random.default_rng(8).uniform(0.05, 0.95, (4, 4, 3))
    mat, tree, shader = emission_material("image light")
    shader.inputs["Strength"].default_value = 3.0
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image, tex.interpolation = float_image("light image", pixels), "Linear"
    tree.links.new(tex.outputs["Color"], shader.inputs["Color"])
    plane.data.materials.append(mat)
    baked = bake_emission(plane, mat, 16)
    s = ovrad.operators.scene_io.read_scene(bpy.context.evaluated_depsgraph_get(), [plane]).surfaces
    assert s.emitted is not None and s.albedo is None
    uv = (np.stack(np.meshgrid(np.arange(16), np.arange(16)), axis=-1) + 0.5) / 16
    points = np.concatenate([uv.reshape(-1, 2) - 0.5, np.zeros((256, 1))], axis=1)
    down = np.tile([0.0, 0.0, -1.0], (256, 1))
    tri = ovrad.ovrad_addon.make_rays(s.vertices, s.triangles).closest_hit(points - down, down, 2.0)[1]
    emitted = ovrad.ovrad_addon.scene.albedo.albedo_at(
        s.emitted, s.emission, s.corners, tri, points, clip=False
    )
    np.testing.assert_allclose(emitted.reshape(16, 16, 3), baked, atol=2e-3 * 3.0)
    corners, radiance = ovrad.ovrad_addon.light.emitters.emitting_triangles(
        s, np.ones(len(s.triangles), bool)
    )
    assert len(corners) == 2 * 36  # the diagonal spans 4 sqrt(2) = 5.7 texels: 6 pieces along each edge
    assert len(np.unique(radiance.round(9), axis=0)) == len(corners)


def test_an_image_without_pixels_is_magenta_as_cycles_renders_it(ovrad, fresh_scene, tmp_path):
    # A glTF whose textures are missing (the BoomBox asset) renders magenta in Cycles, in its base
    # colour and its emission alike (Cycles' own emission bake below). The reader gives the base
    # colour magenta and leaves the emission out, both with a warning naming the image: a whole
    # mesh emitting would make every point near it sum its triangles exactly (light.tree).
    img = bpy.data.images.new("gone", 4, 4)
    img.source = "FILE"
    img.filepath = str(tmp_path / "gone.png")  # no such file
    mat = bpy.data.materials.new("missing texture")
    mat.use_nodes = True
    tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    bsdf.inputs["Specular IOR Level"].default_value = 0.0
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Emission Color"])
    bsdf.inputs["Emission Strength"].default_value = 2.0
    light, warnings = read(ovrad, mat)
    np.testing.assert_allclose(light.reflectance, [1.0, 0.0, 1.0])
    np.testing.assert_allclose(light.emission, 0.0)
    assert len(warnings) == 2 and all("'gone'" in w and "magenta" in w for w in warnings)
    assert any("ignored" in w for w in warnings)
    bpy.ops.mesh.primitive_plane_add(size=1.0)
    plane = bpy.context.active_object
    plane.data.materials.append(mat)
    baked = bake_emission(plane, mat, 4)  # Cycles: emission colour x strength
    np.testing.assert_allclose(baked, np.broadcast_to([2.0, 0.0, 2.0], baked.shape), atol=1e-6)
