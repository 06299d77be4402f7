"""The attribute gateway: every attribute ovrad writes, reads or removes goes through here (atlas
objects' POINT attributes, baked colours and their ownership marks), each write checked."""

from __future__ import annotations

import bpy
import numpy as np

from ..ovrad_addon import FINE_QUADRATURE, Atlas, KeptOverlaps, OvradError, hasher, names

ATLAS_VERSION = 1
ATLAS_SUFFIX = "_ovrad_atlas"

# Attribute type -> (foreach key, components, numpy dtype Blender stores it as).
_LAYOUT = {
    "FLOAT": ("value", 1, np.float32),
    "INT": ("value", 1, np.int32),
    "FLOAT_VECTOR": ("vector", 3, np.float32),
    "FLOAT_COLOR": ("color", 4, np.float32),
    "FLOAT2": ("vector", 2, np.float32),
}


def _values_digest(values) -> str:
    h = hasher(16)
    h.update(values.tobytes())
    return h.hexdigest()


def is_atlas(obj) -> bool:
    """An atlas object is a mesh that carries our source property (its name does not matter)."""
    return obj is not None and obj.type == "MESH" and names.PROP_SOURCE in obj


def atlas_objects(source: str | None = None) -> list:
    """Atlas objects in the file, all of them or those of one source object name."""
    return [o for o in bpy.data.objects if is_atlas(o) and (source is None or o[names.PROP_SOURCE] == source)]


def solved_atlases(scene) -> dict:
    """Source object name -> its atlas object, for atlas objects in the scene holding a solution."""
    return {
        o[names.PROP_SOURCE]: o for o in scene.objects if is_atlas(o) and names.RADIOSITY in o.data.attributes
    }


# Blender's glTF exporter leaves out the objects of a collection of this name (io_scene_gltf2:
# BLENDER_GLTF_SPECIAL_COLLECTION); it need not be in any scene.
NOT_EXPORTED = "glTF_not_exported"


def keep_out_of_renders(obj) -> bool:
    """An atlas object is a tool of the viewport: it takes no part in renders (F12, EEVEE, Cycles
    and its bakes) nor in glTF exports. Its viewport display is left as it is. Returns whether
    anything had to change."""
    changed = not obj.hide_render
    if changed:
        obj.hide_render = True
    coll = bpy.data.collections.get(NOT_EXPORTED)
    if coll is None or coll.library is not None:
        coll = bpy.data.collections.new(NOT_EXPORTED)
        coll.use_fake_user = True  # in no scene: kept in the file by its fake user
    if coll.objects.get(obj.name) is not obj:
        coll.objects.link(obj)
        changed = True
    return changed


def keep_atlases_out_of_renders() -> int:
    """keep_out_of_renders on every atlas object of the file (atlases of files made before they
    were kept out render); returns how many had to change."""
    return sum(keep_out_of_renders(obj) for obj in atlas_objects())


def ensure_collection(scene) -> bpy.types.Collection:
    """The collection holding atlas objects, linked under the scene's root if it is not in the scene."""
    coll = bpy.data.collections.get(names.COLLECTION)
    if coll is None or coll.library is not None:
        coll = bpy.data.collections.new(names.COLLECTION)
    if coll != scene.collection and coll not in scene.collection.children_recursive:
        scene.collection.children.link(coll)
    return coll


OWNED_PROP = "ovrad_baked_attributes"  # on a mesh: {attribute name: signature of what ovrad wrote}

# Domain -> number of elements of a mesh in it.
_DOMAIN_SIZE = {
    "POINT": lambda mesh: len(mesh.vertices),
    "EDGE": lambda mesh: len(mesh.edges),
    "FACE": lambda mesh: len(mesh.polygons),
    "CORNER": lambda mesh: len(mesh.loops),
}


class AttributeLayoutError(ValueError):
    """An attribute write whose type, domain or value shape does not fit the mesh (a bug, not a
    user error)."""


def _layout(mesh, name: str, values, kind: str, domain: str) -> np.ndarray:
    """values as the (n, components) array Blender stores for `kind` in `domain`; raises
    AttributeLayoutError when the type or domain is unknown or the length does not match."""
    if kind not in _LAYOUT:
        raise AttributeLayoutError(
            f"attribute {name}: unsupported type {kind!r} (known: {', '.join(_LAYOUT)})"
        )
    if domain not in _DOMAIN_SIZE:
        raise AttributeLayoutError(f"attribute {name}: unknown domain {domain!r}")
    _, comps, dtype = _LAYOUT[kind]
    n = _DOMAIN_SIZE[domain](mesh)
    a = np.asarray(values, dtype=dtype)
    if a.size == 0 and n == 0:  # an atlas may be empty
        return a.reshape(0, comps)
    a = a.reshape(len(a), -1) if a.ndim else a.reshape(1, 1)
    if len(a) != n:
        raise AttributeLayoutError(f"attribute {name}: {len(a)} values for {n} elements of domain {domain}")
    if kind == "FLOAT_COLOR" and a.shape[1] == 3:
        a = np.concatenate([a, np.ones((len(a), 1), dtype)], axis=1)
    if a.shape[1] != comps:
        raise AttributeLayoutError(f"attribute {name}: expected {comps} components, got {a.shape[1]}")
    return np.ascontiguousarray(a)


def remove_attribute(mesh, name: str) -> bool:
    """Remove the attribute `name` if the mesh has it; returns whether it did."""
    old = mesh.attributes.get(name)
    if old is None:
        return False
    mesh.attributes.remove(old)
    return True


def write_attribute(mesh, name: str, values, kind: str, domain: str = "POINT", color: bool = False):
    """Create or replace one attribute, checked first (nothing changes if the check fails);
    values (n,) or (n, k), n the size of the domain. color: made as a colour attribute."""
    a = _layout(mesh, name, values, kind, domain)
    remove_attribute(mesh, name)
    attr = (mesh.color_attributes if color else mesh.attributes).new(name, kind, domain)
    attr.data.foreach_set(_LAYOUT[kind][0], a.ravel())
    return attr


def write_point_attribute(mesh, name: str, values: np.ndarray, kind: str) -> None:
    """Create or replace one POINT attribute; values (n,) or (n, k) with n the vertex count."""
    write_attribute(mesh, name, values, kind, "POINT")


def signature(attr) -> str:
    """Type, domain and a hash of the values of a colour attribute."""
    if attr.data_type != "FLOAT_COLOR":
        return attr.data_type
    values = np.empty(4 * len(attr.data), np.float32)
    attr.data.foreach_get("color", values)
    return f"FLOAT_COLOR:{attr.domain}:{_values_digest(values)}"


def owned(mesh) -> list[str]:
    """Names of the attributes of `mesh` that are exactly what an ovrad bake wrote."""
    marks = mesh.get(OWNED_PROP)
    if not hasattr(marks, "keys"):
        return []
    return [n for n in marks.keys() if n in mesh.attributes and signature(mesh.attributes[n]) == marks[n]]


def check_target(mesh, name: str) -> None:
    """Raise OvradError if `name` on `mesh` is an attribute ovrad did not make (never overwrite it)."""
    existing = mesh.attributes.get(name)
    if existing is not None and name not in owned(mesh):
        raise OvradError(
            f"mesh '{mesh.name}' already has an attribute '{name}' that ovrad did not make: "
            "choose another attribute name (it is never overwritten)"
        )


def write_color(mesh, name: str, values: np.ndarray, domain: str) -> None:
    """Create (or replace ovrad's own) FLOAT_COLOR attribute from RGB values (n, 3), alpha 1; mark
    it as ovrad's and make it the active and render colour."""
    write_attribute(mesh, name, values, "FLOAT_COLOR", domain, color=True)
    marks = {n: mesh[OWNED_PROP][n] for n in owned(mesh) if n != name}
    marks[name] = signature(mesh.attributes[name])
    mesh[OWNED_PROP] = marks
    colors = mesh.color_attributes
    colors.active_color_name = name
    colors.render_color_index = [a.name for a in colors].index(name)
    mesh.update()


def read_attribute(mesh, name: str) -> np.ndarray:
    """One attribute of any domain as (n,) or (n, k); raises KeyError if missing."""
    attr = mesh.attributes[name]
    key, comps, dtype = _LAYOUT[attr.data_type]
    out = np.empty(len(attr.data) * comps, dtype)
    attr.data.foreach_get(key, out)
    return out if comps == 1 else out.reshape(-1, comps)


def read_point_attribute(mesh, name: str) -> np.ndarray:
    """One POINT attribute as (n,) or (n, k), n the mesh's points; raises KeyError if missing."""
    return read_attribute(mesh, name)


def _atlas_mesh(name: str, atlas: Atlas, kept: KeptOverlaps | None = None) -> bpy.types.Mesh:
    """A new mesh holding the atlas: a point per patch, and with `kept`, the C of its patches (an edge
    between each two that overlap, their diagonal being the patches' effective areas)."""
    if kept is not None and not np.array_equal(kept.diagonal, np.asarray(atlas.effective_area, np.float32)):
        raise AttributeLayoutError("the kept overlaps' diagonal is not the atlas's effective areas")
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(atlas))
    mesh.vertices.foreach_set("co", np.ascontiguousarray(atlas.centers, np.float32).ravel())
    for attr_name, (values, kind) in atlas.point_attributes().items():
        write_point_attribute(mesh, attr_name, values, kind)
    if kept is not None:
        mesh.edges.add(len(kept.edges))
        mesh.edges.foreach_set("vertices", np.ascontiguousarray(kept.edges, np.int32).ravel())
        write_attribute(mesh, names.OVERLAP_C, kept.values, "FLOAT2", "EDGE")
        mesh[names.PROP_OVERLAP_KEY] = kept.key
        mesh[names.PROP_OVERLAP_QUADRATURE] = int(kept.quadrature)
        if kept.contacts is not None:
            write_point_attribute(mesh, names.CONTACTS, kept.contacts, "INT")
    mesh.update()
    return mesh


def read_kept(obj, start: int) -> KeptOverlaps | None:
    """The overlaps kept on an atlas object's edges (None: it keeps none), for a solve whose atlas
    has the object's patches from position `start` on. Whether they still fit is the engine's
    to decide (overlap.kept.usable)."""
    mesh = obj.data
    key = mesh.get(names.PROP_OVERLAP_KEY)
    attr = mesh.attributes.get(names.OVERLAP_C)
    if not isinstance(key, str) or attr is None or attr.domain != "EDGE" or attr.data_type != "FLOAT2":
        return None
    if names.AREA not in mesh.attributes:
        return None
    edges = np.empty(2 * len(mesh.edges), np.int32)
    mesh.edges.foreach_get("vertices", edges)
    diagonal = read_point_attribute(mesh, names.AREA)
    quadrature = mesh.get(names.PROP_OVERLAP_QUADRATURE, FINE_QUADRATURE)  # kept before it was stored: 12
    if not isinstance(quadrature, int) or not 2 <= quadrature <= 64:
        return None
    values = read_attribute(mesh, names.OVERLAP_C)
    flags = mesh.attributes.get(names.CONTACTS)
    contacts = None  # kept before the contacts were: a solve finds them again
    if flags is not None and flags.domain == "POINT" and flags.data_type == "INT":
        contacts = read_point_attribute(mesh, names.CONTACTS)
    count = len(mesh.vertices)
    return KeptOverlaps(start, count, key, edges.reshape(-1, 2), values, diagonal, quadrature, contacts)


def write_atlas(scene, source: str, atlas: Atlas, kept: KeptOverlaps | None = None) -> bpy.types.Object:
    """Create, or replace the mesh of, the one atlas object of `source`; returns it. kept: the C
    of its patches, kept on the mesh (overlap/kept.py).

    Only objects carrying our source property are touched; a user object that merely has a
    similar name is left alone (the new object then gets Blender's .001-style name).
    """
    mesh = _atlas_mesh(source + ATLAS_SUFFIX, atlas, kept)
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
    keep_out_of_renders(obj)
    return obj


def remove_atlas(obj) -> None:
    """Delete an atlas object and its mesh (if nothing else uses it)."""
    mesh = obj.data
    bpy.data.objects.remove(obj)
    if mesh is not None and mesh.users == 0:
        bpy.data.meshes.remove(mesh)


def read_atlas(obj) -> Atlas:
    """An atlas object back into engine arrays (the file's float32 values, widened)."""
    if not is_atlas(obj):
        raise ValueError(f"{obj.name} is not an ovrad atlas object")
    mesh = obj.data
    n = len(mesh.vertices)
    co = np.empty(3 * n, np.float32)
    mesh.vertices.foreach_get("co", co)
    attrs = {
        a.name: read_point_attribute(mesh, a.name)
        for a in mesh.attributes
        if a.name.startswith("ovrad_") and a.domain == "POINT"
    }
    # Points are written in world space with an identity matrix; the matrix is ignored on purpose, as
    # a moved atlas object no longer matches its surfaces anyway.
    return Atlas.from_point_attributes(co, attrs, beta=str(obj.get(names.PROP_BETA, "smooth")))


def is_environment(obj) -> bool:
    """The environment atlas: patches on every rendered mesh without an atlas of its own."""
    return is_atlas(obj) and names.PROP_ENVIRONMENT in obj


def environment_object(scene):
    """The scene's environment atlas object, or None."""
    return next((o for o in scene.objects if is_environment(o)), None)


def write_environment(scene, atlas: Atlas, key: str, kept: KeptOverlaps | None = None) -> bpy.types.Object:
    """Create, or replace the mesh of, the scene's one environment atlas object (hidden, in the
    ovrad collection), marked with the fingerprint `key` of the surfaces it was built from; kept:
    the C of its patches."""
    mesh = _atlas_mesh(names.ENVIRONMENT, atlas, kept)
    obj = environment_object(scene)
    if obj is None:
        obj = bpy.data.objects.new(names.ENVIRONMENT, mesh)
        ensure_collection(scene).objects.link(obj)
    else:
        old = obj.data
        obj.data = mesh
        if old.users == 0:
            bpy.data.meshes.remove(old)
    # its patches lie on many objects: which one each, so its stored triangles find their sheets
    write_point_attribute(mesh, names.OBJECT, atlas.source_object.astype(np.int32), "INT")
    obj.matrix_world = ((1, 0, 0, 0), (0, 1, 0, 0), (0, 0, 1, 0), (0, 0, 0, 1))
    obj[names.PROP_SOURCE] = ""  # an atlas of no one object
    obj[names.PROP_ENVIRONMENT] = key
    obj[names.PROP_BETA] = atlas.beta
    obj[names.PROP_VERSION] = ATLAS_VERSION
    obj.hide_viewport = True
    keep_out_of_renders(obj)
    return obj


def patch_count(obj) -> int:
    """Number of patches of an atlas object (0 for anything else)."""
    return len(obj.data.vertices) if is_atlas(obj) else 0
