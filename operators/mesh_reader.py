"""The one reader of evaluated meshes: world vertices, loop triangles and their loops, polygons,
materials and UVs, as plain arrays (the scene reader and both bakes read meshes through it)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..ovrad_addon import OvradError
from . import attributes


@dataclass(frozen=True)
class MeshData:
    """One mesh in world space, per loop triangle (Blender's order).

    vertices (V, 3) float64 world positions; triangles (T, 3) int64 vertex indices, winding
    flipped under a mirroring matrix so normals face as Blender shows them; loops (T, 3) int64
    the loop of each triangle corner (same corner order as triangles); polygons (T,) and
    material_index (T,) int64; loop_vertices (L,) int64 the vertex of each loop; uv (T, 3, 2)
    float64 of the chosen UV map or None; materials: the material of each slot (object slots
    first, else the mesh's), possibly empty; loop_uvs: every UV map's (L, 2) float32 per-loop
    coordinates by name, when read (read_mesh(all_uvs=True)), and active_uv the active render map;
    loop_colors likewise every colour attribute's (L, 3) float32 linear RGB per loop (a POINT one
    taken at each loop's vertex), and render_color the render colour attribute's name.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    loops: np.ndarray
    polygons: np.ndarray
    material_index: np.ndarray
    loop_vertices: np.ndarray
    n_polygons: int
    uv: np.ndarray | None = None
    materials: tuple = ()
    loop_uvs: dict | None = None
    active_uv: str = ""
    loop_colors: dict | None = None
    render_color: str = ""

    @property
    def corners(self) -> np.ndarray:
        """(T, 3, 3) world position of each triangle corner."""
        return self.vertices[self.triangles]

    def has_uv_map(self, uv_map: str) -> bool:
        """Whether the map named uv_map ('' = the active render map) was read."""
        return bool(self.loop_uvs) and (uv_map or self.active_uv) in self.loop_uvs

    def triangle_uvs(self, uv_map: str) -> np.ndarray | None:
        """(T, 3, 2) float64 UVs of each triangle corner in the map named uv_map ('' = the active
        render map); None if that map was not read or does not exist."""
        if not self.has_uv_map(uv_map):
            return None
        return self.loop_uvs[uv_map or self.active_uv][self.loops].astype(np.float64)

    def triangle_colors(self, name: str) -> np.ndarray | None:
        """(T, 3, 3) float64 linear RGB of each triangle corner in the colour attribute `name` ('' =
        the render colour attribute); None if the mesh has no such attribute (or they were not read)."""
        key = name or self.render_color
        if not self.loop_colors or key not in self.loop_colors:
            return None
        return self.loop_colors[key][self.loops].astype(np.float64)

    def bake_uvs(self, uv_map: str, owner: str) -> np.ndarray:
        """(T, 3, 2) float64 UVs of the map a bake goes through (see uv_map_name; needs the maps
        read, read_mesh(all_uvs=True)); owner names the object in the error."""
        return self.triangle_uvs(uv_map_name(list(self.loop_uvs or ()), self.active_uv, uv_map, owner))


def _get(collection, key: str, per: int, dtype) -> np.ndarray:
    out = np.empty(len(collection) * per, dtype)
    collection.foreach_get(key, out)
    return out.reshape(-1, per) if per > 1 else out


def loop_vertices(mesh) -> np.ndarray:
    """(L,) int64 vertex index of each loop of a mesh (evaluated or not)."""
    return _get(mesh.loops, "vertex_index", 1, np.int32).astype(np.int64)


def uv_map_name(have: list[str], active: str, uv_map: str, owner: str) -> str:
    """The UV map named uv_map, or the active render one (`active`) when uv_map is empty, of a mesh
    whose maps are `have`; OvradError naming `owner` when it has no map, or none of that name."""
    if not have:
        raise OvradError(f"'{owner}' has no UV map: unwrap it (UV > Unwrap) before baking to an image")
    if uv_map and uv_map not in have:
        raise OvradError(f"'{owner}' has no UV map named '{uv_map}' (it has: {', '.join(have)})")
    return uv_map or active


def _active_uv(layers):
    """The active render UV layer (else the active one, else the first) of a mesh that has some."""
    return next((lay for lay in layers if lay.active_render), layers.active or layers[0])


def _uv_layer(mesh, uv_map: str, owner: str):
    """The UV layer named uv_map, or the active render one when uv_map is empty (uv_map_name)."""
    layers = mesh.uv_layers
    have = [lay.name for lay in layers]
    return layers[uv_map_name(have, _active_uv(layers).name if have else "", uv_map, owner)]


def read_mesh(
    mesh, matrix_world, uv_map: str | None = None, owner: str = "", materials=None, all_uvs: bool = False
) -> MeshData:
    """A mesh (already evaluated) placed by matrix_world (4 x 4) into MeshData.

    uv_map: None reads no UVs, "" the active render UV map, else that map (OvradError if the
    mesh has none of that name, naming `owner`). materials default to the mesh's own. all_uvs:
    also keep every UV map per loop (loop_uvs), for textured materials.
    """
    owner = owner or mesh.name
    co = _get(mesh.vertices, "co", 3, np.float32)
    tris = mesh.loop_triangles
    triangles = _get(tris, "vertices", 3, np.int32).astype(np.int64)
    loops = _get(tris, "loops", 3, np.int32).astype(np.int64)
    uv = None
    if uv_map is not None:
        per_loop = _get(_uv_layer(mesh, uv_map, owner).data, "uv", 2, np.float32)
        uv = per_loop[loops].astype(np.float64)
    local = MeshData(
        vertices=co.astype(np.float64),
        triangles=triangles,
        loops=loops,
        polygons=_get(tris, "polygon_index", 1, np.int32).astype(np.int64),
        material_index=_get(tris, "material_index", 1, np.int32).astype(np.int64),
        loop_vertices=loop_vertices(mesh),
        n_polygons=len(mesh.polygons),
        uv=uv,
        materials=tuple(mesh.materials) if materials is None else tuple(materials),
    )
    if all_uvs and len(mesh.uv_layers):
        local = replace(
            local,
            loop_uvs={lay.name: _get(lay.data, "uv", 2, np.float32) for lay in mesh.uv_layers},
            active_uv=_active_uv(mesh.uv_layers).name,
        )
    if all_uvs and len(mesh.color_attributes):
        local = replace(
            local, loop_colors=_loop_colors(mesh, local.loop_vertices), render_color=_render_color(mesh)
        )
    return placed(local, matrix_world)


def _loop_colors(mesh, loop_vertex: np.ndarray) -> dict:
    """Every colour attribute of a mesh as (L, 3) float32 linear RGB per loop (`color` is scene
    linear for byte and float colours alike); ovrad's own baked attributes are no paint."""
    out = {}
    for attr in mesh.color_attributes:
        if attr.domain not in ("POINT", "CORNER") or attr.name.startswith("ovrad_"):
            continue
        rgb = _get(attr.data, "color", 4, np.float32)[:, :3]
        out[attr.name] = rgb[loop_vertex] if attr.domain == "POINT" else rgb
    return out


def _render_color(mesh) -> str:
    """The name of the colour attribute a Color Attribute node without a name reads ('' if none)."""
    attrs = mesh.color_attributes
    k = attrs.render_color_index
    return attrs[k].name if 0 <= k < len(attrs) else ""


def vertex_positions(mesh, matrix_world) -> np.ndarray:
    """(V, 3) float64 world positions of a mesh's vertices placed by matrix_world (4 x 4)."""
    m = np.array(matrix_world, dtype=np.float64)
    return _get(mesh.vertices, "co", 3, np.float32).astype(np.float64) @ m[:3, :3].T + m[:3, 3]


def placed(data: MeshData, matrix_world) -> MeshData:
    """MeshData moved by matrix_world (4 x 4): one mesh read once, placed for each of its instances."""
    m = np.array(matrix_world, dtype=np.float64)
    triangles, loops, uv = data.triangles, data.loops, data.uv
    if np.linalg.det(m[:3, :3]) < 0.0:
        # A mirroring matrix turns faces inside out; flipping the winding keeps normals as Blender shows them.
        flip = [0, 2, 1]
        triangles, loops = triangles[:, flip], loops[:, flip]
        uv = None if uv is None else uv[:, flip]
    return replace(
        data, vertices=data.vertices @ m[:3, :3].T + m[:3, 3], triangles=triangles, loops=loops, uv=uv
    )


def read_evaluated(ev, uv_map: str | None = None, matrix_world=None, all_uvs: bool = False) -> MeshData:
    """The mesh of an evaluated object (a scene object or an instance's), placed by matrix_world
    (default: the object's own; np.eye(4) keeps it in the object's space); its materials are the
    object's material slots (else the mesh's)."""
    mesh = ev.to_mesh()
    try:
        slots = [s.material for s in ev.material_slots] or list(mesh.materials)
        matrix = ev.matrix_world if matrix_world is None else matrix_world
        return read_mesh(mesh, matrix, uv_map, owner=ev.name, materials=slots, all_uvs=all_uvs)
    finally:
        ev.to_mesh_clear()


def read_object(obj, depsgraph, uv_map: str | None = None) -> MeshData:
    """The evaluated mesh of a mesh object (modifiers applied) in world space; its materials are
    the object's material slots (else the mesh's)."""
    return read_evaluated(obj.evaluated_get(depsgraph), uv_map)


# Blender's Python API has no map from an evaluated mesh back to the original one (Cycles' vertex-
# colour bake reads CD_ORIGINDEX in C). The map is carried through the modifiers instead, by
# temporary attributes on the original mesh: each loop's and each vertex's own index, and a random
# float32 tag of it. Modifiers copy or blend attributes like any others; an element copied from one
# original element keeps its index and that index's tag, while one blended from several rounds its
# index to some integer whose tag the blended tag almost surely is not (a chance of about 1e-7).
ORIGIN_ATTRIBUTES = (
    ".ovrad_origin_loop",
    ".ovrad_origin_loop_tag",
    ".ovrad_origin_vert",
    ".ovrad_origin_vert_tag",
)
ORIGIN_SEED = 0x0DD5EED


def _copies(mesh, index_name: str, tag_name: str, tags: np.ndarray) -> np.ndarray | None:
    """(n,) int64 the original element each element of an evaluated mesh copies, -1 where none;
    None where the modifiers dropped the attributes."""
    try:
        got = attributes.read_attribute(mesh, index_name).astype(np.int64)
        got_tag = attributes.read_attribute(mesh, tag_name)
    except KeyError:
        return None
    ok = (got >= 0) & (got < len(tags))
    ok[ok] = got_tag[ok] == tags[got[ok]]
    return np.where(ok, got, -1)


def keeps_topology(data: MeshData, mesh) -> bool:
    """Whether an object's evaluated mesh (data) has its own mesh's vertices, faces and loops as
    they are (its modifiers keep the topology)."""
    if (len(data.vertices), data.n_polygons) != (len(mesh.vertices), len(mesh.polygons)):
        return False
    return bool(np.array_equal(data.loop_vertices, loop_vertices(mesh)))


def read_with_origins(objects, depsgraph) -> dict:
    """{object name: (MeshData, origin) or OvradError} for mesh objects: each one's evaluated mesh,
    as read_object() reads it, and origin (L_eval,) int64: for each of its loops, the loop of the
    object's own mesh it is a copy of, or -1 (a loop the modifiers made, or blended from several,
    or whose vertex is no copy of that loop's vertex); origin None where the modifiers drop the
    mesh's attributes (a voxel Remesh: colours baked on the mesh would not show).

    A Subdivision modifier keeps a copy of every original corner (at the limit surface), Array and
    Mirror several, a Boolean those it does not cut away, a Bevel those off its bevelled edges.
    Every mesh gets its temporary attributes (ORIGIN_ATTRIBUTES) at once and the depsgraph is
    evaluated once for all of them (linked duplicates share a mesh: one update per object would
    evaluate every user each time); they are removed before this returns, also on error, and the
    depsgraph is evaluated again without them.
    """
    out: dict = {}
    tags: dict = {}  # mesh -> (loop tags, vertex tags)
    made: list = []  # (mesh, attribute name)
    try:
        for obj in objects:
            mesh = obj.data
            if mesh in tags or obj.name in out:
                continue
            clash = [name for name in ORIGIN_ATTRIBUTES if mesh.attributes.get(name) is not None]
            if clash:
                out[obj.name] = OvradError(
                    f"the mesh of '{obj.name}' has an attribute named '{clash[0]}': rename it to bake"
                )
                continue
            rng = np.random.default_rng(ORIGIN_SEED)
            n_loops, n_verts = len(mesh.loops), len(mesh.vertices)
            tags[mesh] = (rng.random(n_loops, np.float32), rng.random(n_verts, np.float32))
            for name, kind, domain, values in zip(
                ORIGIN_ATTRIBUTES,
                ("INT", "FLOAT", "INT", "FLOAT"),
                ("CORNER", "CORNER", "POINT", "POINT"),
                (
                    np.arange(n_loops, dtype=np.int32),
                    tags[mesh][0],
                    np.arange(n_verts, dtype=np.int32),
                    tags[mesh][1],
                ),
                strict=True,
            ):
                made.append((mesh, name))
                attributes.write_attribute(mesh, name, values, kind, domain)
            mesh.update()
        if not tags:
            return out
        depsgraph.update()
        for obj in objects:
            if obj.name in out or obj.data not in tags:
                continue
            loop_tags, vert_tags = tags[obj.data]
            ev = obj.evaluated_get(depsgraph)
            data = read_evaluated(ev)
            loops = _copies(ev.data, ORIGIN_ATTRIBUTES[0], ORIGIN_ATTRIBUTES[1], loop_tags)
            verts = _copies(ev.data, ORIGIN_ATTRIBUTES[2], ORIGIN_ATTRIBUTES[3], vert_tags)
            if loops is None or verts is None:
                out[obj.name] = (data, None)
                continue
            # a loop is a copy only where its vertex is a copy of that loop's vertex
            own = loop_vertices(obj.data)
            keep = loops >= 0
            keep[keep] = verts[data.loop_vertices[keep]] == own[loops[keep]]
            out[obj.name] = (data, np.where(keep, loops, -1))
    finally:
        for mesh, name in made:
            attributes.remove_attribute(mesh, name)
        if made:
            for mesh in tags:
                mesh.update()
            depsgraph.update()
    return out
