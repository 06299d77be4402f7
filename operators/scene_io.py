"""Reading the Blender scene into engine arrays: evaluated meshes in world space, material colours."""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..ovrad_addon import names
from ..ovrad_addon.errors import OvradError
from ..ovrad_addon.surfaces import Surfaces

# What a surface gets when its material cannot be read (and what Blender renders without a material).
DEFAULT_REFLECTANCE = (0.8, 0.8, 0.8)


@dataclass
class SceneMeshes:
    """Surfaces with the Blender objects they came from.

    objects[i] is the object of surfaces.object_names[i]; the first n_receivers are receivers
    (they get patches), the rest only occlude.
    """

    surfaces: Surfaces
    objects: list
    n_receivers: int
    warnings: list[str] = field(default_factory=list)


def _constant(socket, what: str, material, warnings: list[str]):
    """A socket's value if nothing is plugged into it, else None (and a warning)."""
    if socket.is_linked:
        warnings.append(f"material '{material.name}': {what} is driven by nodes; using grey 0.8 instead")
        return None
    return socket.default_value


def _surface_shader(material):
    tree = material.node_tree
    if tree is None:
        return None
    out = tree.get_output_node("CYCLES") or tree.get_output_node("ALL")
    if out is None or not out.inputs["Surface"].is_linked:
        return None
    node = out.inputs["Surface"].links[0].from_node
    while node.bl_idname == "NodeReroute" and node.inputs[0].is_linked:
        node = node.inputs[0].links[0].from_node
    return node


def material_colors(material, warnings: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(reflectance (3,), emitted radiance (3,)) of a material, as Cycles would see its diffuse part.

    Read: Principled BSDF (Base Color; Emission Color x Strength), Diffuse BSDF (Color), Emission
    (Color x Strength, no reflection). Anything else gives grey 0.8 and a warning naming the material.
    """
    grey, black = np.array(DEFAULT_REFLECTANCE), np.zeros(3)
    if material is None:
        return grey, black
    legacy = bpy.app.version < (5, 0, 0) and not material.use_nodes
    if material.node_tree is None or legacy:
        # A material without nodes renders as a diffuse surface of its viewport colour.
        return np.array(material.diffuse_color[:3], float), black
    node = _surface_shader(material)
    kind = node.bl_idname if node is not None else None
    rho, em = grey, black
    if kind == "ShaderNodeBsdfPrincipled":
        base = _constant(node.inputs["Base Color"], "Base Color", material, warnings)
        rho = grey if base is None else np.array(base[:3], float)
        col = _constant(node.inputs["Emission Color"], "Emission Color", material, warnings)
        strength = _constant(node.inputs["Emission Strength"], "Emission Strength", material, warnings)
        if col is not None and strength is not None:
            em = np.array(col[:3], float) * float(strength)
    elif kind == "ShaderNodeBsdfDiffuse":
        base = _constant(node.inputs["Color"], "Color", material, warnings)
        rho = grey if base is None else np.array(base[:3], float)
    elif kind == "ShaderNodeEmission":
        rho = np.zeros(3)
        col = _constant(node.inputs["Color"], "Emission Color", material, warnings)
        strength = _constant(node.inputs["Strength"], "Emission Strength", material, warnings)
        if col is not None and strength is not None:
            em = np.array(col[:3], float) * float(strength)
    else:
        what = "no surface shader" if node is None else f"a {node.bl_label} shader"
        warnings.append(
            f"material '{material.name}' has {what}; using grey 0.8 (read: Principled, Diffuse, Emission)"
        )
    if rho.min() < 0.0 or rho.max() > 1.0:
        warnings.append(
            f"material '{material.name}': reflectance {tuple(np.round(rho, 3))} clamped to [0, 1]"
        )
        rho = np.clip(rho, 0.0, 1.0)
    return rho, np.maximum(em, 0.0)


def _read_mesh(obj, depsgraph, warnings: list[str]):
    """(vertices (V, 3) world, triangles (T, 3), reflectance (T, 3), emission (T, 3)) of one object."""
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    try:
        nv, nt = len(mesh.vertices), len(mesh.loop_triangles)
        co = np.empty(3 * nv, np.float32)
        mesh.vertices.foreach_get("co", co)
        tri = np.empty(3 * nt, np.int32)
        mesh.loop_triangles.foreach_get("vertices", tri)
        mat_index = np.empty(nt, np.int32)
        mesh.loop_triangles.foreach_get("material_index", mat_index)
        slots = [s.material for s in ev.material_slots] or list(mesh.materials)
    finally:
        ev.to_mesh_clear()
    m = np.array(ev.matrix_world, dtype=np.float64)
    verts = co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    tri = tri.reshape(-1, 3).astype(np.int64)
    if np.linalg.det(m[:3, :3]) < 0.0:
        # A mirroring matrix turns faces inside out; flipping the winding keeps normals as Blender shows them.
        tri = tri[:, [0, 2, 1]]
    colors = [material_colors(mat, warnings) for mat in slots] or [material_colors(None, warnings)]
    slot = np.clip(mat_index, 0, len(colors) - 1)
    rho = np.array([c[0] for c in colors])[slot]
    em = np.array([c[1] for c in colors])[slot]
    return verts, tri, rho, em


def default_occluders(context, receivers) -> list:
    """Every other mesh that renders in the view layer: it gets no patches, but hides and bounds space."""
    chosen = {o.name for o in receivers}
    return [
        o
        for o in context.view_layer.objects
        if o.type == "MESH" and o.name not in chosen and names.PROP_SOURCE not in o and not o.hide_render
    ]


def read_scene(depsgraph, receivers, occluders=()) -> SceneMeshes:
    """Read receiver meshes (they get patches) and occluder meshes into one Surfaces.

    Non-mesh objects, atlas objects and meshes without faces are skipped with a warning; raises
    OvradError when no receiver is left.
    """
    warnings: list[str] = []
    kept = []
    for obj in receivers:
        if obj.type != "MESH":
            warnings.append(f"'{obj.name}' is not a mesh ({obj.type.lower()}); skipped")
        elif names.PROP_SOURCE in obj:
            warnings.append(f"'{obj.name}' is an ovrad atlas; skipped")
        else:
            kept.append(obj)
    if not kept:
        raise OvradError(
            "no mesh to cover with patches: select at least one mesh object"
            if not receivers
            else "none of the selected objects is a mesh: select at least one mesh object"
        )
    objects, parts = [], []
    n_receivers = 0
    for role, group in (("receiver", kept), ("occluder", [o for o in occluders if o.type == "MESH"])):
        for obj in group:
            part = _read_mesh(obj, depsgraph, warnings)
            if len(part[1]) == 0:
                if role == "receiver":
                    warnings.append(f"'{obj.name}' has no faces; skipped")
                continue
            objects.append(obj)
            parts.append(part)
            n_receivers += role == "receiver"
    if n_receivers == 0:
        raise OvradError("the selected meshes have no faces: select at least one mesh with faces")
    base = np.cumsum([0] + [len(p[0]) for p in parts])[:-1]
    surfaces = Surfaces.from_arrays(
        vertices=np.concatenate([p[0] for p in parts]),
        triangles=np.concatenate([p[1] + b for p, b in zip(parts, base, strict=True)]),
        object_index=np.concatenate([np.full(len(p[1]), i) for i, p in enumerate(parts)]),
        reflectance=np.concatenate([p[2] for p in parts]),
        emission=np.concatenate([p[3] for p in parts]),
        object_names=[o.name for o in objects],
        receiver=np.arange(len(objects)) < n_receivers,
    )
    # The same material on many objects would repeat its warning.
    return SceneMeshes(surfaces, objects, n_receivers, list(dict.fromkeys(warnings)))
