"""Scene pieces the Blender tests build in code (Principled materials, closed boxes) and small helpers
they share (selecting objects, reading a colour attribute)."""

from __future__ import annotations


def principled(name, base=(0.8, 0.8, 0.8), emission=0.0):
    """A Principled BSDF material of that base colour and white emission of that strength, a plain
    Lambert surface as the closed forms assume: no specular layer (Specular IOR Level 0), which
    would keep a share of the light a bake reports (operators/principled.py)."""
    import bpy

    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True  # Blender < 5.0
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*base, 1.0)
    bsdf.inputs["Emission Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bsdf.inputs["Emission Strength"].default_value = emission
    bsdf.inputs["Specular IOR Level"].default_value = 0.0
    return mat


def closed_box(name="Box", cuts=3, mat=None):
    """A 2 m cube seen from inside (normals inward), its faces split into (cuts + 1)^2 quads,
    linked to the scene."""
    import bmesh
    import bpy

    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=2.0)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)
    bmesh.ops.reverse_faces(bm, faces=bm.faces[:])
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    if mat is not None:
        mesh.materials.append(mat)
    return obj


def select(*objs):
    """Select exactly these objects, the first one active."""
    import bpy

    bpy.context.view_layer.update()  # an object linked from Python is only selectable once the layer syncs
    for o in bpy.context.view_layer.objects:
        o.select_set(o in objs)
    bpy.context.view_layer.objects.active = objs[0] if objs else None


def color_values(mesh, name):
    """A colour attribute's values (n, 4) float32."""
    import numpy as np

    attr = mesh.attributes[name]
    out = np.empty(4 * len(attr.data), np.float32)
    attr.data.foreach_get("color", out)
    return out.reshape(-1, 4)
