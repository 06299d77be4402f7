"""Preview of an image bake: each baked receiver shows its lightmap as emission, reversibly.

Every material slot of a receiver is switched to an object-linked material showing its lightmap
(UV Map -> Image Texture -> Emission, times 2^exposure for a 16-bit PNG); the mesh's materials,
which other objects may share, are not touched. What each slot held (its link, and the object's
own material in it) is recorded (JSON in the object's SLOTS_PROP) and put back on the second
press; a receiver without slots gets one on its mesh, removed again. The receivers are the meshes
an image bake wrote (names.PROP_LIGHTMAP_IMAGE and PROP_LIGHTMAP_UV_MAP on the object).
"""

from __future__ import annotations

import json

import bpy

from ..ovrad_addon import OvradError, names
from . import compat

SLOTS_PROP = "ovrad_preview_lightmap"  # object: JSON [[link, object's own material or None], ...]
ADDED_PROP = "ovrad_preview_lightmap_slot"  # mesh: the preview gave it its only (empty) slot
MATERIAL_PROP = "ovrad_preview_lightmap_material"  # the preview's materials


def is_active() -> bool:
    return any(SLOTS_PROP in o for o in bpy.data.objects)


def baked(scene) -> list:
    """The scene's meshes whose last image bake's image and UV map are still there."""
    out = []
    for o in scene.objects:
        image = bpy.data.images.get(o.get(names.PROP_LIGHTMAP_IMAGE, ""))
        if o.type == "MESH" and image is not None and o.get(names.PROP_LIGHTMAP_UV_MAP) in o.data.uv_layers:
            out.append(o)
    return out


def _material(image, uv_map: str):
    """An emission material showing `image` through `uv_map`."""
    mat = bpy.data.materials.new(f"ovrad preview {image.name}")
    tree = compat.use_nodes(mat)
    tree.nodes.clear()
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.uv_map = uv_map
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image, tex.interpolation, tex.extension = image, "Linear", "EXTEND"
    emit = tree.nodes.new("ShaderNodeEmission")
    emit.inputs["Strength"].default_value = 2.0 ** float(image.get(names.PROP_EXPOSURE, 0) or 0)
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], emit.inputs["Color"])
    tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    for k, n in enumerate((uv, tex, emit, out)):
        n.location = (-600 + 200 * k, 0)
    mat[MATERIAL_PROP] = 1
    return mat


def setup(scene) -> int:
    """Show each baked receiver's lightmap; returns how many."""
    targets = baked(scene)
    if not targets:
        raise OvradError("no mesh in the scene has a baked lightmap: bake to images first")
    made = {}
    for obj in targets:
        image = bpy.data.images[obj[names.PROP_LIGHTMAP_IMAGE]]
        uv_map = obj[names.PROP_LIGHTMAP_UV_MAP]
        mat = made.get((image.name, uv_map))
        if mat is None:
            mat = made[image.name, uv_map] = _material(image, uv_map)
        if len(obj.material_slots) == 0:
            obj.data.materials.append(None)
            obj.data[ADDED_PROP] = 1
        record = []
        for slot in obj.material_slots:
            link = slot.link
            slot.link = "OBJECT"  # the object's own material in the slot (None unless it had one)
            record.append([link, slot.material.name if slot.material else None])
            slot.material = mat
        obj[SLOTS_PROP] = json.dumps(record)
    return len(targets)


def teardown() -> list[str]:
    """Put every slot the preview switched back; returns what could not be restored."""
    problems = []
    for obj in bpy.data.objects:
        if SLOTS_PROP not in obj:
            continue
        record = json.loads(obj[SLOTS_PROP])
        for slot, (link, name) in zip(obj.material_slots, record, strict=False):
            mat = bpy.data.materials.get(name) if name else None
            if name and mat is None:
                problems.append(f"'{obj.name}': its material '{name}' is gone")
            slot.link = "OBJECT"
            slot.material = mat
            slot.link = link
        del obj[SLOTS_PROP]
    for mesh in bpy.data.meshes:
        if ADDED_PROP in mesh:
            if len(mesh.materials) == 1 and mesh.materials[0] is None:
                mesh.materials.clear()
            del mesh[ADDED_PROP]
    for mat in [m for m in bpy.data.materials if MATERIAL_PROP in m]:
        bpy.data.materials.remove(mat)
    return problems
