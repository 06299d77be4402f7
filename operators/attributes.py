"""Atlas objects in the Blender file: every attribute write and read of ovrad happens here."""

from __future__ import annotations

import bpy
import numpy as np

from ..ovrad_addon import names
from ..ovrad_addon.atlas import Atlas

ATLAS_VERSION = 1
ATLAS_SUFFIX = "_ovrad_atlas"

# Attribute type -> (foreach key, components, numpy dtype Blender stores it as).
_LAYOUT = {
    "FLOAT": ("value", 1, np.float32),
    "INT": ("value", 1, np.int32),
    "FLOAT_VECTOR": ("vector", 3, np.float32),
    "FLOAT_COLOR": ("color", 4, np.float32),
}


def is_atlas(obj) -> bool:
    """An atlas object is a mesh that carries our source property (its name does not matter)."""
    return obj is not None and obj.type == "MESH" and names.PROP_SOURCE in obj


def atlas_objects(source: str | None = None) -> list:
    """Atlas objects in the file, all of them or those of one source object name."""
    return [o for o in bpy.data.objects if is_atlas(o) and (source is None or o[names.PROP_SOURCE] == source)]


def ensure_collection(scene) -> bpy.types.Collection:
    """The collection holding atlas objects, linked under the scene's root if it is not in the scene."""
    coll = bpy.data.collections.get(names.COLLECTION)
    if coll is None or coll.library is not None:
        coll = bpy.data.collections.new(names.COLLECTION)
    if coll != scene.collection and coll not in scene.collection.children_recursive:
        scene.collection.children.link(coll)
    return coll


def write_point_attribute(mesh, name: str, values: np.ndarray, kind: str) -> None:
    """Create or replace one POINT attribute; values (n,) or (n, k) with n the vertex count."""
    key, comps, dtype = _LAYOUT[kind]
    old = mesh.attributes.get(name)
    if old is not None:
        mesh.attributes.remove(old)
    attr = mesh.attributes.new(name, kind, "POINT")
    a = np.asarray(values, dtype=dtype)
    a = a.reshape(len(mesh.vertices), -1) if a.size else a.reshape(0, comps)  # an atlas may be empty
    if kind == "FLOAT_COLOR" and a.shape[1] == 3:
        a = np.concatenate([a, np.ones((len(a), 1), dtype)], axis=1)
    if a.shape[1] != comps:
        raise ValueError(f"attribute {name}: expected {comps} components, got {a.shape[1]}")
    attr.data.foreach_set(key, np.ascontiguousarray(a).ravel())


def read_point_attribute(mesh, name: str) -> np.ndarray:
    """One POINT attribute as (n,) or (n, k); raises KeyError if missing."""
    attr = mesh.attributes[name]
    key, comps, dtype = _LAYOUT[attr.data_type]
    out = np.empty(len(mesh.vertices) * comps, dtype)
    attr.data.foreach_get(key, out)
    return out if comps == 1 else out.reshape(-1, comps)


def _atlas_mesh(name: str, atlas: Atlas) -> bpy.types.Mesh:
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(atlas))
    mesh.vertices.foreach_set("co", np.ascontiguousarray(atlas.centers, np.float32).ravel())
    for attr_name, (values, kind) in atlas.point_attributes().items():
        write_point_attribute(mesh, attr_name, values, kind)
    mesh.update()
    return mesh


def write_atlas(scene, source: str, atlas: Atlas) -> bpy.types.Object:
    """Create, or replace the mesh of, the one atlas object of `source`; returns it.

    Only objects carrying our source property are touched; a user object that merely has a
    similar name is left alone (the new object then gets Blender's .001-style name).
    """
    mesh = _atlas_mesh(source + ATLAS_SUFFIX, atlas)
    existing = atlas_objects(source)
    if existing:
        obj = existing[0]
        old = obj.data
        obj.data = mesh
        if old.users == 0:
            bpy.data.meshes.remove(old)
        # One atlas per source: duplicates (a copied atlas object) would be stale after this.
        for extra in existing[1:]:
            remove_atlas(extra)
    else:
        obj = bpy.data.objects.new(source + ATLAS_SUFFIX, mesh)
    if obj.name not in scene.objects:
        ensure_collection(scene).objects.link(obj)
    # Centres are in world space: the object must not move them.
    obj.matrix_world = ((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))
    obj[names.PROP_SOURCE] = source
    obj[names.PROP_BETA] = atlas.beta
    obj[names.PROP_VERSION] = ATLAS_VERSION
    return obj


def remove_atlas(obj) -> None:
    """Delete an atlas object and its mesh (if nothing else uses it)."""
    mesh = obj.data
    bpy.data.objects.remove(obj)
    if mesh is not None and mesh.users == 0:
        bpy.data.meshes.remove(mesh)


def read_atlas(obj) -> Atlas:
    """An atlas object back into engine arrays (float32 in the file: unit vectors are renormalised)."""
    if not is_atlas(obj):
        raise ValueError(f"{obj.name} is not an ovrad atlas object")
    mesh = obj.data
    n = len(mesh.vertices)
    co = np.empty(3 * n, np.float32)
    mesh.vertices.foreach_get("co", co)
    # Points are written in world space with an identity matrix; the matrix is ignored on purpose, as
    # a moved atlas object no longer matches its surfaces anyway.
    centers = co.reshape(-1, 3).astype(np.float64)
    attrs = {
        a.name: read_point_attribute(mesh, a.name) for a in mesh.attributes if a.name.startswith("ovrad_")
    }
    for key in (names.NORMAL, names.TANGENT):
        v = attrs[key].astype(np.float64)
        attrs[key] = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-30)
    return Atlas.from_point_attributes(centers, attrs, beta=str(obj.get(names.PROP_BETA, "smooth")))


def patch_count(obj) -> int:
    """Number of patches of an atlas object (0 for anything else)."""
    return len(obj.data.vertices) if is_atlas(obj) else 0
