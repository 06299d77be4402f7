"""The patch display: a geometry-nodes group and a material, built in code, versioned with the extension."""

from __future__ import annotations

import bpy

from ..ovrad_addon import names
from . import compat

# Bump when the node tree or the material changes: files saved with an older version are rebuilt in place.
DISPLAY_VERSION = 1
VERSION_PROP = "ovrad_display_version"
MATERIAL = "ovrad_patch_display"

# Quantities the display can colour patches by (the modifier's "Quantity" input).
QUANTITIES = ("OVERLAP", "RANDOM", "BETA", "RADIOSITY")

# Attributes the node tree writes for the material (they exist only on the modifier's output).
DISPLAY_COLOR = "ovrad_display_color"  # FLOAT_COLOR per patch: the chosen quantity as a colour
DISPLAY_BETA = "ovrad_display_beta"  # FLOAT_VECTOR per patch: weights of box, smooth-disk, smooth-square beta
DISPLAY_ALPHA = "ovrad_display_alpha"  # FLOAT per patch: opacity
DISPLAY_RIM = "ovrad_display_rim"  # FLOAT per patch: where the outline starts (1: no outline)
DISPLAY_LOCAL = "ovrad_local"  # FLOAT_VECTOR per vertex: position in the unit disk / square of its patch

# name -> (socket type, default, min, max, description)
INPUTS = {
    "Quantity": ("NodeSocketInt", 0, 0, 3, "0 overlap count, 1 random colour, 2 beta profile, 3 radiosity"),
    "Smooth Beta": ("NodeSocketBool", True, None, None, "Draw the smooth beta profile (off: box)"),
    "Disk Vertices": ("NodeSocketInt", 32, 3, 256, "Vertices around each disk"),
    "Opacity": ("NodeSocketFloat", 1.0, 0.0, 1.0, "Opacity of each patch"),
    "Overlap Max": ("NodeSocketInt", 12, 1, 1000, "Overlap count shown with the last colour of the ramp"),
    "Outline": ("NodeSocketFloat", 0.06, 0.0, 1.0, "Width of the dark rim around each patch, in radii"),
    "Lift": ("NodeSocketFloat", 0.003, 0.0, 1.0, "Offset along the normal, in radii, over the surface"),
}

# Colour ramp stops for the overlap count (viridis-like: dark blue, teal, green, yellow).
RAMP = (
    (0.0, (0.27, 0.0, 0.33)),
    (0.33, (0.13, 0.34, 0.55)),
    (0.66, (0.12, 0.64, 0.45)),
    (1.0, (0.99, 0.91, 0.14)),
)


def _is_current(idblock) -> bool:
    return idblock is not None and idblock.get(VERSION_PROP) == DISPLAY_VERSION


def _find(collection, name: str, idname: str | None = None):
    """Our data block: by name if it carries our version tag, else any data block that does."""
    block = collection.get(name)
    if block is not None and VERSION_PROP in block and (idname is None or block.bl_idname == idname):
        return block
    for block in collection:
        if VERSION_PROP in block and (idname is None or getattr(block, "bl_idname", idname) == idname):
            return block
    return None


def _ramp(node) -> None:
    els = node.color_ramp.elements
    while len(els) > 1:
        els.remove(els[-1])
    els[0].position, els[0].color = RAMP[0][0], (*RAMP[0][1], 1.0)
    for pos, col in RAMP[1:]:
        els.new(pos).color = (*col, 1.0)


def ensure_material() -> bpy.types.Material:
    """The display material (created once; rebuilt when its version is old)."""
    mat = _find(bpy.data.materials, MATERIAL)
    if _is_current(mat):
        return mat
    if mat is None:
        mat = bpy.data.materials.new(MATERIAL)
    tree = compat.use_nodes(mat)
    tree.nodes.clear()
    nodes, link = tree.nodes, tree.links.new

    def attr(name):
        n = nodes.new("ShaderNodeAttribute")
        n.attribute_type, n.attribute_name = "GEOMETRY", name
        return n

    def math(op, a, b=None, clamp=False):
        n = nodes.new("ShaderNodeMath")
        n.operation, n.use_clamp = op, clamp
        for sock, v in zip(n.inputs, (a, b), strict=False):
            if v is None:
                continue
            link(v, sock) if isinstance(v, bpy.types.NodeSocket) else setattr(sock, "default_value", v)
        return n.outputs[0]

    col, w, loc, alpha = attr(DISPLAY_COLOR), attr(DISPLAY_BETA), attr(DISPLAY_LOCAL), attr(DISPLAY_ALPHA)
    # beta of each kind from the unit-patch coordinates, interpolated exactly (they are affine on a face).
    sep = nodes.new("ShaderNodeSeparateXYZ")
    link(loc.outputs["Vector"], sep.inputs[0])
    x, y = sep.outputs["X"], sep.outputs["Y"]
    d2 = math("ADD", math("MULTIPLY", x, x), math("MULTIPLY", y, y))
    disk = math("POWER", math("SUBTRACT", 1.0, d2, clamp=True), 2.0)
    square = math(
        "MULTIPLY",
        math("SUBTRACT", 1.0, math("MULTIPLY", x, x), True),
        math("SUBTRACT", 1.0, math("MULTIPLY", y, y), True),
    )
    prof = nodes.new("ShaderNodeCombineXYZ")
    prof.inputs[0].default_value = 1.0
    link(disk, prof.inputs[1])
    link(square, prof.inputs[2])
    beta = nodes.new("ShaderNodeVectorMath")
    beta.operation = "DOT_PRODUCT"
    link(w.outputs["Vector"], beta.inputs[0])
    link(prof.outputs[0], beta.inputs[1])
    show = nodes.new("ShaderNodeVectorMath")
    show.operation = "DOT_PRODUCT"
    link(w.outputs["Vector"], show.inputs[0])
    show.inputs[1].default_value = (1.0, 1.0, 1.0)
    # Beta mode: the patch's own colour times beta, so box patches stay flat and smooth ones fade to the rim.
    factor = math("ADD", math("SUBTRACT", 1.0, show.outputs["Value"]), beta.outputs["Value"])
    # A dark outline shows where each patch ends, even between neighbours of the same colour.
    shape = attr(names.SHAPE)
    box_norm = math("MAXIMUM", math("ABSOLUTE", x), math("ABSOLUTE", y))
    rim_dist = math(
        "ADD",
        math("SQRT", d2),
        math("MULTIPLY", shape.outputs["Fac"], math("SUBTRACT", box_norm, math("SQRT", d2))),
    )
    on_rim = math("GREATER_THAN", rim_dist, attr(DISPLAY_RIM).outputs["Fac"])
    factor = math("MULTIPLY", factor, math("SUBTRACT", 1.0, math("MULTIPLY", on_rim, 0.7)))
    shaded = nodes.new("ShaderNodeVectorMath")
    shaded.operation = "SCALE"
    link(col.outputs["Color"], shaded.inputs[0])
    link(factor, shaded.inputs["Scale"])
    # Emission, not a BSDF: the patch colour is data to read, not something to light.
    emit = nodes.new("ShaderNodeEmission")
    link(shaded.outputs[0], emit.inputs["Color"])
    shader = nodes.new("ShaderNodeMixShader")
    link(alpha.outputs["Fac"], shader.inputs["Fac"])
    link(nodes.new("ShaderNodeBsdfTransparent").outputs[0], shader.inputs[1])
    link(emit.outputs[0], shader.inputs[2])
    out = nodes.new("ShaderNodeOutputMaterial")
    link(shader.outputs[0], out.inputs["Surface"])
    mat.diffuse_color = (0.4, 0.6, 0.9, 1.0)
    mat[VERSION_PROP] = DISPLAY_VERSION
    return mat


class _Builder:
    """Adds nodes to a node group, linking sockets given as inputs and setting plain values."""

    def __init__(self, ng):
        self.nodes, self.link = ng.nodes, ng.links.new

    def node(self, idname, inputs=(), **props):
        n = self.nodes.new(idname)
        for k, v in props.items():
            setattr(n, k, v)
        for key, v in inputs:
            # By identifier first: some nodes (Compare) have several inputs of the same name.
            sock = (
                n.inputs[key]
                if isinstance(key, int)
                else next(s for s in n.inputs if key in (s.identifier, s.name))
            )
            self.link(v, sock) if isinstance(v, bpy.types.NodeSocket) else setattr(sock, "default_value", v)
        return n

    def named(self, name, dtype):
        node = self.node("GeometryNodeInputNamedAttribute", [("Name", name)], data_type=dtype)
        return node.outputs["Attribute"]

    def math(self, op, a, b=None, idname="ShaderNodeMath"):
        return self.node(idname, [(0, a)] + ([(1, b)] if b is not None else []), operation=op).outputs[0]

    def compare(self, a, b):
        """1 where the integers a and b are equal, else 0."""
        node = self.node("FunctionNodeCompare", data_type="INT", operation="EQUAL")
        for value, sock in zip((a, b), compat.compare_operands(node), strict=True):
            if isinstance(value, bpy.types.NodeSocket):
                self.link(value, sock)
            else:
                sock.default_value = value
        return node.outputs[0]

    def store(self, geo, name, dtype, value, domain="POINT"):
        n = self.node(
            "GeometryNodeStoreNamedAttribute",
            [("Geometry", geo), ("Name", name)],
            data_type=dtype,
            domain=domain,
        )
        self.link(value, n.inputs["Value"])
        return n.outputs[0]


def _build_interface(ng) -> None:
    """Geometry in, the modifier's INPUTS, geometry out."""
    ng.interface.clear()
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    for name, (stype, default, lo, hi, desc) in INPUTS.items():
        s = ng.interface.new_socket(name, in_out="INPUT", socket_type=stype)
        s.default_value, s.description = default, desc
        if lo is not None:
            s.min_value, s.max_value = lo, hi
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")


def _lifted_points(b: _Builder, gin, normal, radius, rnd):
    """The patch points lifted off their surface by a per-patch amount, so coplanar neighbours do
    not z-fight."""
    lift = b.math("MULTIPLY", b.math("MULTIPLY", radius, gin.outputs["Lift"]), b.math("ADD", rnd, 1.0))
    offset = b.node("ShaderNodeVectorMath", [(0, normal), ("Scale", lift)], operation="SCALE").outputs[0]
    return b.node(
        "GeometryNodeSetPosition", [("Geometry", gin.outputs["Geometry"]), ("Offset", offset)]
    ).outputs[0]


def _patch_colour(b: _Builder, gin, rnd):
    """The chosen quantity as one colour per patch."""
    overlap = b.math("DIVIDE", b.named(names.OVERLAP, "INT"), gin.outputs["Overlap Max"])
    ramp = b.node("ShaderNodeValToRGB", [(0, overlap)])
    _ramp(ramp)
    hsv = b.node("FunctionNodeCombineColor", [(0, rnd), (1, 0.65), (2, 0.95)], mode="HSV")
    switch = b.node("GeometryNodeIndexSwitch", [("Index", gin.outputs["Quantity"])], data_type="RGBA")
    switch.index_switch_items.new()
    switch.index_switch_items.new()
    b.link(ramp.outputs["Color"], switch.inputs[1])
    b.link(hsv.outputs[0], switch.inputs[2])
    b.link(hsv.outputs[0], switch.inputs[3])  # beta: the material multiplies it by the profile
    b.link(b.named(names.RADIOSITY, "FLOAT_COLOR"), switch.inputs[4])
    return switch.outputs[0]


def _beta_weights(b: _Builder, gin, shape):
    """Which beta the material draws: weights of (box, smooth disk, smooth square), all 0 unless
    Quantity is 2."""
    show = b.compare(gin.outputs["Quantity"], 2)
    smooth = b.math("MULTIPLY", show, gin.outputs["Smooth Beta"])
    sq = b.math("MULTIPLY", smooth, shape)
    weights = b.node(
        "ShaderNodeCombineXYZ",
        [(0, b.math("SUBTRACT", show, smooth)), (1, b.math("SUBTRACT", smooth, sq)), (2, sq)],
    )
    return weights.outputs[0]


def _patch_instances(b: _Builder, gin, points, normal, tangent, radius, shape):
    """A unit disk (radius 1), unit square (side 2) or unit ball (a clutter patch, clutter.py) on
    each point, turned and scaled to its patch; a vertex's DISPLAY_LOCAL is its coordinate in the
    patch."""
    circle = b.node(
        "GeometryNodeMeshCircle",
        [("Vertices", gin.outputs["Disk Vertices"]), ("Radius", 1.0)],
        fill_type="NGON",
    )
    grid = b.node(
        "GeometryNodeMeshGrid", [("Size X", 2.0), ("Size Y", 2.0), ("Vertices X", 2), ("Vertices Y", 2)]
    )
    ball = b.node("GeometryNodeMeshIcoSphere", [("Radius", 1.0), ("Subdivisions", 2)])
    position = b.node("GeometryNodeInputPosition").outputs[0]
    rotation = b.node(
        "FunctionNodeAxesToRotation", [(0, normal), (1, tangent)], primary_axis="Z", secondary_axis="X"
    ).outputs[0]
    join = b.node("GeometryNodeJoinGeometry")
    for kind, mesh in ((names.SHAPE_DISK, circle), (names.SHAPE_SQUARE, grid), (names.SHAPE_BALL, ball)):
        unit = b.store(mesh.outputs["Mesh"], DISPLAY_LOCAL, "FLOAT_VECTOR", position)
        inst = b.node(
            "GeometryNodeInstanceOnPoints",
            [
                ("Points", points),
                ("Selection", b.compare(shape, kind)),
                ("Instance", unit),
                ("Rotation", rotation),
                ("Scale", radius),
            ],
        )
        b.link(inst.outputs[0], join.inputs[0])
    return join.outputs[0]


def _build_tree(ng, material) -> None:
    """The display: lifted points carry their colour, beta weights, opacity and rim, then become
    disk and square instances, realised, with the display material."""
    ng.nodes.clear()
    _build_interface(ng)
    b = _Builder(ng)
    gin, gout = b.nodes.new("NodeGroupInput"), b.nodes.new("NodeGroupOutput")
    normal, tangent = b.named(names.NORMAL, "FLOAT_VECTOR"), b.named(names.TANGENT, "FLOAT_VECTOR")
    radius, shape = b.named(names.RADIUS, "FLOAT"), b.named(names.SHAPE, "INT")
    rnd = b.named(names.RANDOM, "FLOAT")
    points = _lifted_points(b, gin, normal, radius, rnd)
    colour = _patch_colour(b, gin, rnd)
    weights = _beta_weights(b, gin, shape)
    points = b.store(points, DISPLAY_COLOR, "FLOAT_COLOR", colour)
    points = b.store(points, DISPLAY_BETA, "FLOAT_VECTOR", weights)
    points = b.store(points, DISPLAY_ALPHA, "FLOAT", gin.outputs["Opacity"])
    points = b.store(points, DISPLAY_RIM, "FLOAT", b.math("SUBTRACT", 1.0, gin.outputs["Outline"]))
    patches = _patch_instances(b, gin, points, normal, tangent, radius, shape)
    real = b.node("GeometryNodeRealizeInstances", [("Geometry", patches)])
    setmat = b.node("GeometryNodeSetMaterial", [("Geometry", real.outputs[0]), ("Material", material)])
    b.link(setmat.outputs[0], gout.inputs["Geometry"])
    for i, n in enumerate(b.nodes):
        n.location = (200 * (i % 8), -180 * (i // 8))


def ensure_node_group() -> bpy.types.GeometryNodeTree:
    """The display node group (created once; rebuilt in place when old, so modifiers keep it)."""
    material = ensure_material()
    ng = _find(bpy.data.node_groups, names.DISPLAY_NODE_GROUP, "GeometryNodeTree")
    if _is_current(ng):
        return ng
    if ng is None:
        ng = bpy.data.node_groups.new(names.DISPLAY_NODE_GROUP, "GeometryNodeTree")
    # Rebuilding renames the sockets, and modifiers would fall back to zeros: carry their values over by name.
    users = [
        (o, m) for o in bpy.data.objects for m in o.modifiers if m.type == "NODES" and m.node_group == ng
    ]
    saved = [{name: compat.modifier_input(m, ident) for name, ident in _inputs(ng).items()} for _, m in users]
    _build_tree(ng, material)
    ng[VERSION_PROP] = DISPLAY_VERSION
    for (obj, mod), values in zip(users, saved, strict=True):
        for name, ident in _inputs(ng).items():
            value = values.get(name)
            compat.set_modifier_input(mod, ident, INPUTS[name][1] if value is None else value)
        obj.update_tag()
    return ng


def _inputs(ng) -> dict[str, str]:
    """Input socket name -> identifier (a modifier stores its input values under the identifier)."""
    return {
        item.name: item.identifier
        for item in ng.interface.items_tree
        if item.item_type == "SOCKET" and item.in_out == "INPUT" and item.name in INPUTS
    }


def input_identifier(ng, name: str) -> str:
    """A modifier input is set by its socket identifier, not by its display name."""
    return _inputs(ng)[name]


def ensure_modifier(obj, beta: str) -> bpy.types.NodesModifier:
    """Add (or refresh) the display modifier on an atlas object."""
    ng = ensure_node_group()
    mod = obj.modifiers.get(names.DISPLAY_MODIFIER)
    if mod is None or mod.type != "NODES":
        mod = obj.modifiers.new(names.DISPLAY_MODIFIER, "NODES")
    mod.node_group = ng
    compat.set_modifier_input(mod, input_identifier(ng, "Smooth Beta"), beta == "smooth")
    return mod


def set_input(obj, name: str, value) -> bool:
    """Set one display input on an atlas object; False if it has no display modifier."""
    mod = obj.modifiers.get(names.DISPLAY_MODIFIER)
    if mod is None or mod.node_group is None:
        return False
    compat.set_modifier_input(mod, input_identifier(mod.node_group, name), value)
    # Changing an ID property does not tag the object: re-evaluate so the viewport updates.
    obj.update_tag()
    return True


def set_quantity(obj, quantity: str) -> bool:
    """Colour an atlas object's patches by one of QUANTITIES."""
    return set_input(obj, "Quantity", QUANTITIES.index(quantity))
