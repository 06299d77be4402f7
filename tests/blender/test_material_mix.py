"""Base Color through Mix and Invert nodes: what the material reader makes of them, against the
node's formula worked out by hand (Blender's Mix: Mix (1 - f) A + f B, Multiply A ((1 - f) + f B),
Add A + f B; Invert c + f (1 - 2 c))."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[2]

RED, GREY = (0.8, 0.2, 0.1), (0.5, 0.5, 0.5)


def _material(blend: str, factor: float, a, b):
    """A Principled material whose Base Color is a Mix (colour) node of a and b (an RGB triple or a
    colour attribute's name), made as the real-scenes set makes it; and that node."""
    sys.path.insert(0, str(ROOT))
    from benchmarks import real_scenes

    mat = real_scenes.mixed_material(f"mix {blend}", blend, factor, a, b)
    return mat, next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeMix")


@pytest.mark.parametrize(
    ("blend", "factor", "expected"),
    [
        ("MIX", 0.25, 0.75 * np.array(RED) + 0.25 * np.array(GREY)),
        ("MULTIPLY", 0.5, np.array(RED) * (0.5 + 0.5 * np.array(GREY))),
        ("ADD", 0.5, np.array(RED) + 0.5 * np.array(GREY)),
    ],
)
def test_a_mix_of_constants_is_the_constant_of_its_formula(ovrad, fresh_scene, blend, factor, expected):
    mat, _ = _material(blend, factor, RED, GREY)
    warnings = []
    light = ovrad.operators.materials.read_material(mat, warnings)
    assert warnings == [] or blend == "ADD"  # ADD goes over 1 in red: clamped, with a warning
    np.testing.assert_allclose(light.reflectance, np.clip(expected, 0.0, 1.0), atol=1e-6)
    assert light.texture is None and light.paint is None


def test_paint_mixed_with_a_constant_is_affine_in_the_paint(ovrad, fresh_scene):
    mat, _ = _material("MIX", 0.6, RED, "Paint")
    light = ovrad.operators.materials.read_material(mat, [])
    paint = light.paint
    assert paint is not None and paint.attribute == "Paint" and light.texture is None
    rgb = np.array([[0.1, 0.5, 0.9], [1.0, 0.0, 0.3]])
    np.testing.assert_allclose(paint.colours(rgb), 0.4 * np.array(RED) + 0.6 * rgb, atol=1e-12)


def test_inverted_paint_and_a_linked_factor(ovrad, fresh_scene):
    mat, mix = _material("MULTIPLY", 1.0, GREY, "Paint")
    tree = mat.node_tree
    inv = tree.nodes.new("ShaderNodeInvert")
    inv.inputs["Fac"].default_value = 0.8
    b_socket = next(s for s in mix.inputs if s.identifier == "B_Color")
    tree.links.new(b_socket.links[0].from_socket, inv.inputs["Color"])  # the paint, through Invert
    tree.links.new(inv.outputs["Color"], b_socket)
    light = ovrad.operators.materials.read_material(mat, [])
    rgb = np.array([[0.1, 0.5, 0.9]])
    # Multiply at 1: GREY x inverted paint, GREY x (c + 0.8 (1 - 2c))
    expected = np.array(GREY) * (rgb + 0.8 * (1.0 - 2.0 * rgb))
    np.testing.assert_allclose(light.tint * light.paint.colours(rgb), expected, atol=1e-12)
    # a factor driven by another node is not followed: the viewport colour, with a warning naming it
    value = tree.nodes.new("ShaderNodeValue")
    tree.links.new(value.outputs[0], next(s for s in mix.inputs if s.identifier == "Factor_Float"))
    warnings = []
    light = ovrad.operators.materials.read_material(mat, warnings)
    assert light.paint is None and any("Mix" in w for w in warnings)
    np.testing.assert_allclose(light.reflectance, mat.diffuse_color[:3], atol=1e-6)
