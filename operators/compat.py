"""What differs between the Blender versions ovrad supports (4.2 LTS to 5.3), in one place.

Every other module calls these instead of testing `bpy.app.version` or probing attributes
itself. Found by running the cross-version tests (`make test-versions`) on bpy 4.2, 4.5 and 5.3:

- Materials and worlds: before 5.0 a node tree is used only when `use_nodes` is on; from 5.0 a
  material or world always renders through its tree (and new ones are made with one).
- Lamps: `exposure`, an area lamp's `normalize` and `use_temperature` came after 4.2 (4.5 has them); a 4.2
  lamp has none of them and renders as exposure 0, normalized, no blackbody colour. In 5.3
  every lamp has a node tree (white Emission of strength 1, `use_nodes` deprecated and on);
  before, a lamp has a tree only when the user turned nodes on.
- Geometry-nodes modifiers: input values are ID properties keyed by socket identifier
  (`modifier[identifier]`) up to 5.0, and `modifier.properties.inputs.<identifier>.value` in
  5.3 (the modifier no longer holds ID properties).
- Geometry nodes: the Compare node has one input per data type (`A_INT`, `B_INT`, ...) up to
  5.0 and two inputs `A`, `B` that take the chosen data type from 5.1.
"""

from __future__ import annotations

import bpy

# Blender 5.0 made node trees always used by materials and worlds (`use_nodes` is deprecated).
NODE_TREES_ALWAYS_USED = bpy.app.version >= (5, 0, 0)

_LIGHT_PROPERTIES = set(bpy.types.Light.bl_rna.properties.keys())
_AREA_PROPERTIES = set(bpy.types.AreaLight.bl_rna.properties.keys())
HAS_LIGHT_EXPOSURE = "exposure" in _LIGHT_PROPERTIES
HAS_LIGHT_TEMPERATURE = "use_temperature" in _LIGHT_PROPERTIES
HAS_AREA_NORMALIZE = "normalize" in _AREA_PROPERTIES
# Newer Blenders keep a nodes modifier's input values in `modifier.properties.inputs`.
MODIFIER_INPUTS_AS_PROPERTIES = "properties" in bpy.types.NodesModifier.bl_rna.properties.keys()


def renders_with_nodes(block) -> bool:
    """True when a material or world renders through its node tree (else its plain colour)."""
    if block.node_tree is None:
        return False
    return NODE_TREES_ALWAYS_USED or bool(block.use_nodes)


def use_nodes(material):
    """Make a material render through its node tree (making one before 5.0); returns the tree."""
    if not renders_with_nodes(material):
        material.use_nodes = True  # before 5.0 only: from 5.0 every material has a used tree
    return material.node_tree


def light_exposure(light) -> float:
    """The lamp's exposure (its power is times 2^exposure); 0 where Blender has none (4.2)."""
    return float(light.exposure) if HAS_LIGHT_EXPOSURE else 0.0


def light_normalized(light) -> bool:
    """Whether the lamp's power is independent of its size: always so where Blender has no
    'Normalize' setting (4.2)."""
    return bool(getattr(light, "normalize", True)) if HAS_AREA_NORMALIZE else True


def light_temperature_color(light) -> tuple[float, float, float] | None:
    """The blackbody colour the lamp's colour is multiplied by, None when Temperature is off or
    Blender has no such setting (4.2)."""
    if not HAS_LIGHT_TEMPERATURE or not light.use_temperature:
        return None
    return tuple(float(c) for c in light.temperature_color[:3])


def light_uses_nodes(light) -> bool:
    """True when the lamp renders through a node tree that changes its light (which ovrad does
    not read): a tree in use other than the default white Emission of strength 1."""
    tree = light.node_tree
    if tree is None or _is_default_light_tree(tree):
        return False
    return bool(light.use_nodes)


def _is_default_light_tree(tree) -> bool:
    kinds = sorted(n.bl_idname for n in tree.nodes)
    if kinds != ["ShaderNodeEmission", "ShaderNodeOutputLight"] or len(tree.links) != 1:
        return False
    emission = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeEmission")
    color, strength = emission.inputs["Color"], emission.inputs["Strength"]
    return (
        not color.is_linked
        and not strength.is_linked
        and tuple(color.default_value) == (1.0, 1.0, 1.0, 1.0)
        and strength.default_value == 1.0
    )


def compare_operands(node) -> tuple:
    """The two operand sockets (A, B) of a Compare node for its current data type.

    Up to 5.0 the node has one pair per type (`A_INT`, `B_INT`, `A_VEC3`, ...), all but the
    chosen type's hidden; from 5.1 it has one pair `A`, `B` that takes the chosen type.
    """
    suffix = {"FLOAT": "", "INT": "_INT", "VECTOR": "_VEC3", "RGBA": "_COL", "STRING": "_STR"}[node.data_type]
    inputs = {s.identifier: s for s in node.inputs}
    if f"A{suffix}" in inputs and inputs[f"A{suffix}"].enabled:
        return inputs[f"A{suffix}"], inputs[f"B{suffix}"]
    return inputs["A"], inputs["B"]


def modifier_input(modifier, identifier: str, default=None):
    """A geometry-nodes modifier's value for its group input `identifier` (default when unset)."""
    if MODIFIER_INPUTS_AS_PROPERTIES:
        item = getattr(modifier.properties.inputs, identifier, None)
        return default if item is None else item.value
    return modifier.get(identifier, default)


def set_modifier_input(modifier, identifier: str, value) -> None:
    """Set a geometry-nodes modifier's value for its group input `identifier`."""
    if MODIFIER_INPUTS_AS_PROPERTIES:
        getattr(modifier.properties.inputs, identifier).value = value
    else:
        modifier[identifier] = value
