"""Preview of a vertex bake: the receivers' materials show the baked attribute as emission, reversibly.

Showing: every Material Output of a receiver's materials gets its Surface input from our
Attribute -> Emission nodes; the links it had are recorded (JSON in the material's PREVIEW_PROP)
and put back on the second press, and our nodes are removed. Receivers without a material get a
shared preview material in an added slot (or in their empty slots), removed again afterwards.
Nothing of the user's is deleted.
"""

from __future__ import annotations

import json

import bpy

from ..ovrad_addon import OvradError
from . import attributes, compat, preview_images

PREVIEW_PROP = "ovrad_preview"  # material: JSON record of what the preview changed; our nodes: 1
SLOTS_PROP = "ovrad_preview_slots"  # object: indices of empty slots the preview filled
ADDED_PROP = "ovrad_preview_added"  # mesh: the preview appended its material to mesh.materials
MATERIAL_PROP = "ovrad_preview_material"  # the shared preview material
PREVIEW_MATERIAL = "ovrad preview"


def is_active() -> bool:
    """Whether a preview is set up in this file (materials or, for lightmaps, objects carry our record)."""
    return preview_images.is_active() or any(
        PREVIEW_PROP in m or MATERIAL_PROP in m for m in bpy.data.materials
    )


def _nodes(tree, attribute: str):
    """Our Attribute -> Emission nodes, returning the Emission output socket."""
    attr = tree.nodes.new("ShaderNodeAttribute")
    attr.attribute_type, attr.attribute_name = "GEOMETRY", attribute
    attr.name = attr.label = "ovrad preview attribute"
    emit = tree.nodes.new("ShaderNodeEmission")
    emit.name = emit.label = "ovrad preview emission"
    emit.inputs["Strength"].default_value = 1.0
    tree.links.new(attr.outputs["Color"], emit.inputs["Color"])
    outputs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial" and PREVIEW_PROP not in n]
    x = min((n.location.x for n in outputs), default=0.0)
    y = max((n.location.y for n in outputs), default=0.0)
    attr.location, emit.location = (x - 400, y + 300), (x - 200, y + 300)
    for n in (attr, emit):
        n[PREVIEW_PROP] = 1
    return emit.outputs["Emission"]


def _outputs(tree):
    return [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]


def show(material, attribute: str) -> None:
    """Route `material`'s surface through the baked attribute; record what is replaced."""
    used_nodes = compat.renders_with_nodes(material)
    tree = compat.use_nodes(material)
    record = {"attribute": attribute, "use_nodes": used_nodes, "links": [], "added_output": None}
    outputs = _outputs(tree)
    emission = _nodes(tree, attribute)
    if not outputs:
        out = tree.nodes.new("ShaderNodeOutputMaterial")
        out[PREVIEW_PROP] = 1
        record["added_output"] = out.name
        outputs = [out]
    for out in outputs:
        sock = out.inputs["Surface"]
        if sock.is_linked:
            link = sock.links[0]
            record["links"].append([out.name, link.from_node.name, link.from_socket.identifier])
        else:
            record["links"].append([out.name, None, None])
        tree.links.new(emission, sock)
    material[PREVIEW_PROP] = json.dumps(record)


def hide(material) -> list[str]:
    """Undo show(): remove our nodes, put the recorded links back; returns what could not be restored."""
    record = json.loads(material[PREVIEW_PROP])
    problems = []
    tree = material.node_tree
    if tree is not None:
        for node in [n for n in tree.nodes if PREVIEW_PROP in n]:
            tree.nodes.remove(node)
        for out_name, from_name, socket_id in record["links"]:
            out = tree.nodes.get(out_name)
            if from_name is None or out is None:
                continue
            src = tree.nodes.get(from_name)
            sock = next((s for s in src.outputs if s.identifier == socket_id), None) if src else None
            if sock is None:
                problems.append(
                    f"material '{material.name}': node '{from_name}' is gone, its output stays empty"
                )
                continue
            tree.links.new(sock, out.inputs["Surface"])
    if not record["use_nodes"]:
        material.use_nodes = False  # only ever recorded before 5.0 (compat.renders_with_nodes)
    del material[PREVIEW_PROP]
    return problems


def _preview_material(attribute: str):
    mat = bpy.data.materials.new(PREVIEW_MATERIAL)
    tree = compat.use_nodes(mat)
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(_nodes(tree, attribute), out.inputs["Surface"])
    mat[MATERIAL_PROP] = 1
    return mat


def setup(scene, attribute: str) -> tuple[int, list[str]]:
    """Show `attribute` on every mesh of the scene that an ovrad bake wrote it to; (count, warnings)."""
    targets = [
        o
        for o in scene.objects
        if o.type == "MESH" and attribute in attributes.owned(o.data) and attribute in o.data.attributes
    ]
    if not targets:
        raise OvradError(f"no mesh in the scene has a baked '{attribute}': bake vertex colours first")
    warnings = []
    shared = None
    materials = []
    for obj in targets:
        slots = obj.material_slots
        if len(slots) == 0 or any(s.material is None for s in slots):
            shared = shared or _preview_material(attribute)
            if len(slots) == 0:
                obj.data.materials.append(shared)
                obj.data[ADDED_PROP] = 1
            else:
                empty = [i for i, s in enumerate(slots) if s.material is None]
                for i in empty:
                    slots[i].material = shared
                obj[SLOTS_PROP] = empty
        for slot in obj.material_slots:
            mat = slot.material
            if mat is None or mat == shared or mat in materials:
                continue
            if mat.library is not None:
                warnings.append(f"material '{mat.name}' is linked from a library: not previewed")
                continue
            materials.append(mat)
    chosen = set(targets)
    for mat in materials:
        show(mat, attribute)
        others = [
            o.name
            for o in scene.objects
            if o not in chosen and any(s.material == mat for s in o.material_slots)
        ]
        if others:
            warnings.append(
                f"material '{mat.name}' is also used by {', '.join(others[:3])}, which have no bake: "
                "black in the preview"
            )
    return len(targets), warnings


def teardown() -> list[str]:
    """Restore every material, slot and mesh the preview changed; returns what could not be restored."""
    problems = []
    for mat in list(bpy.data.materials):
        if PREVIEW_PROP in mat:
            problems += hide(mat)
    shared = [m for m in bpy.data.materials if MATERIAL_PROP in m]
    for obj in bpy.data.objects:
        if SLOTS_PROP in obj:
            for i in obj[SLOTS_PROP]:
                if i < len(obj.material_slots) and obj.material_slots[i].material in shared:
                    obj.material_slots[i].material = None
            del obj[SLOTS_PROP]
    for mesh in bpy.data.meshes:
        if ADDED_PROP in mesh:
            if all(m in shared for m in mesh.materials):
                mesh.materials.clear()  # unlike pop(), this also removes the objects' slots
            else:
                for i in reversed(range(len(mesh.materials))):
                    if mesh.materials[i] in shared:
                        mesh.materials.pop(index=i)
            del mesh[ADDED_PROP]
    for mat in shared:
        bpy.data.materials.remove(mat)
    return problems


class OVRAD_OT_preview(bpy.types.Operator):
    bl_idname = "ovrad.preview"
    bl_label = "Preview Bake"
    bl_description = (
        "Toggle: show the baked colour attribute (or the baked lightmaps) as emission on the "
        "receivers; press again to restore the materials exactly"
    )
    bl_options = {"REGISTER", "UNDO"}

    attribute: bpy.props.StringProperty(
        name="Attribute", description="Baked attribute to show (default: the panel's)", maxlen=63
    )
    source: bpy.props.EnumProperty(
        name="Show",
        items=(
            ("AUTO", "Auto", "What the panel's Bake To says"),
            ("VERTEX", "Vertex Colors", "The baked colour attribute"),
            ("IMAGE", "Lightmaps", "Each receiver's lightmap from its last image bake, through its UV map"),
        ),
        default="AUTO",
    )

    def execute(self, context):
        attributes.keep_atlases_out_of_renders()  # atlases of older files rendered: mend them
        if is_active():
            for p in teardown() + preview_images.teardown():
                self.report({"WARNING"}, p)
            self.report({"INFO"}, "ovrad: preview off, materials restored")
            return {"FINISHED"}
        source = context.scene.ovrad.bake_target if self.source == "AUTO" else self.source
        if source == "IMAGE":
            try:
                count = preview_images.setup(context.scene)
            except OvradError as e:
                self.report({"ERROR"}, str(e))
                return {"CANCELLED"}
            self.report(
                {"INFO"}, f"ovrad: previewing the lightmaps of {count} mesh(es); press again to restore"
            )
            return {"FINISHED"}
        name = (
            self.attribute
            if self.properties.is_property_set("attribute")
            else context.scene.ovrad.bake_attribute
        )
        try:
            count, warnings = setup(context.scene, name.strip())
        except OvradError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for w in warnings:
            self.report({"WARNING"}, w)
        self.report({"INFO"}, f"ovrad: previewing '{name}' on {count} mesh(es); press again to restore")
        return {"FINISHED"}


classes = (OVRAD_OT_preview,)
