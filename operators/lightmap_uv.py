"""Lightmap UV maps: which UV map an image bake goes through, and the UV map `ovrad_lightmap` that
ovrad makes where a mesh has none fit for a lightmap.

The map is made with Blender's own unwrappers on a UV layer of its own: Smart UV Project cuts the
mesh into islands where its faces turn (at most ANGLE_LIMIT apart), Pack Islands packs their
bounding boxes (rotated to fit; exact shapes take Blender seconds per mesh) into the unit square
with a margin (a fraction of the image) of at least the bake's padding in texels at the image size
the texel density gives, or, for a mesh too small for its islands' padding at that size, in an
image grown to it (MARGIN_MOST). The mesh's other UV maps are not touched, and its
active and render UV maps, the selection and hidden state of its elements, the selected and active
objects are put back as they were. The mesh keeps a digest of the map ovrad made
(names.PROP_LIGHTMAP_UV): a map of that name whose values differ from it is the user's and is
never replaced.
"""

from __future__ import annotations

import hashlib
import math

import bpy
import numpy as np

from ..ovrad_addon import OvradError, names
from ..ovrad_addon import texels as bake

LIGHTMAP_UV = names.LIGHTMAP_UV
AUTO = "auto"  # a UV Map setting of "" or "auto": the active render map when fit, else LIGHTMAP_UV
ANGLE_LIMIT = math.radians(66.0)  # Smart UV Project's default: faces further apart start an island
MAX_UV_MAPS = 8  # Blender's limit of UV maps per mesh
MULTIPLE = 4  # image sizes from a density are a multiple of this many texels
_PACK_PASSES = 4  # packings tried until the margin is at least the padding at the size it gives
# Pack Islands' margin at most (a fraction of the square): at 0.15 it packed a UV sphere's six
# islands into 1 % of the square, at 0.2 into nothing (0.1: 9 %, 0.05: 28 %). A small mesh whose
# padding needs more gets a larger image instead (more texels per metre than asked).
MARGIN_MOST = 0.1


def is_auto(uv_map: str) -> bool:
    return uv_map.strip().lower() in ("", AUTO)


def uv_values(layer) -> np.ndarray:
    """(L, 2) float32 UVs of a UV layer, one per face corner."""
    out = np.empty(2 * len(layer.data), np.float32)
    layer.data.foreach_get("uv", out)
    return out.reshape(-1, 2)


def digest(layer) -> str:
    return hashlib.sha256(uv_values(layer).tobytes()).hexdigest()


def made_by_ovrad(mesh) -> bool:
    """Whether the mesh's LIGHTMAP_UV map is the one ovrad made (unchanged since)."""
    layer = mesh.uv_layers.get(LIGHTMAP_UV)
    return layer is not None and mesh.get(names.PROP_LIGHTMAP_UV) == digest(layer)


def render_map(mesh) -> str:
    """The name of the mesh's active render UV map ('' when it has none)."""
    return next((lay.name for lay in mesh.uv_layers if lay.active_render), "")


def user_map(mesh) -> str:
    """The UV map an automatic choice tries first: the active render map unless ovrad made it."""
    name = render_map(mesh)
    return "" if name == LIGHTMAP_UV and made_by_ovrad(mesh) else name


def density_per_unit(scene, obj, texel_density: float) -> float:
    """Texels per scene unit on obj: texels per metre x metres per unit x the object's Lightmap Scale."""
    scale = getattr(getattr(obj, "ovrad", None), "lightmap_scale", 1.0)
    return float(texel_density) * float(scene.unit_settings.scale_length) * float(scale)


def world_area(world) -> float:
    """Total area of triangles world (T, 3, 3)."""
    w = np.asarray(world, np.float64).reshape(-1, 3, 3)
    return float(0.5 * np.linalg.norm(np.cross(w[:, 1] - w[:, 0], w[:, 2] - w[:, 0]), axis=1).sum())


def check_density(name: str, world, density: float, max_size: int) -> None:
    """OvradError when a surface of triangles world (T, 3, 3) holds less than one texel at density
    (texels per unit), or more than a max_size x max_size image."""
    area = world_area(world)
    if area * density**2 < 1.0:
        raise OvradError(
            f"'{name}' is smaller than one texel at this texel density ({area:.3g} square units): "
            "raise the texel density or its Lightmap Scale, or bake it to vertex colours"
        )
    if math.sqrt(area) * density > max_size:
        raise OvradError(
            f"'{name}' needs more than {max_size} x {max_size} texels at this texel density: lower the "
            "texel density or its Lightmap Scale, or raise Max Size"
        )


def _mesh_triangles(obj) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3) loop indices and (T, 3, 3) world corners of the original mesh's loop triangles."""
    mesh = obj.data
    mesh.calc_loop_triangles()
    loops = np.empty(3 * len(mesh.loop_triangles), np.int64)
    mesh.loop_triangles.foreach_get("loops", loops)
    loops = loops.reshape(-1, 3)
    verts = np.empty(len(mesh.loops), np.int64)
    mesh.loops.foreach_get("vertex_index", verts)
    co = np.empty(3 * len(mesh.vertices), np.float64)
    mesh.vertices.foreach_get("co", co)
    m = np.array(obj.matrix_world, np.float64)
    co = co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]
    return loops, co[verts[loops]]


def _flags(mesh) -> dict:
    """The selection and hidden state of the mesh's vertices, edges and faces."""
    out = {}
    for part in ("vertices", "edges", "polygons"):
        coll = getattr(mesh, part)
        for key in ("select", "hide"):
            a = np.empty(len(coll), bool)
            coll.foreach_get(key, a)
            out[part, key] = a
    return out


def _set_flags(mesh, flags: dict) -> None:
    for (part, key), a in flags.items():
        coll = getattr(mesh, part)
        now = np.empty(len(coll), bool)
        coll.foreach_get(key, now)
        if not np.array_equal(now, a):
            coll.foreach_set(key, a)


def make(context, obj, density: float, padding: float) -> int:
    """Make (or make again) the mesh's UV map LIGHTMAP_UV; returns the image size (texels per side,
    a multiple of MULTIPLE) at which it gives at least `density` texels per scene unit and its
    islands are at least `padding` texels apart. OvradError, with the mesh as it was, when a UV
    map of that name is the user's or the mesh has no room for another UV map."""
    return make_shared(context, [obj], [density], padding)


def check_room(obj) -> None:
    """OvradError when ovrad cannot make its UV map on obj's mesh: a map of that name is the user's,
    or the mesh has Blender's most UV maps already."""
    layers = obj.data.uv_layers
    if LIGHTMAP_UV in layers and not made_by_ovrad(obj.data):
        raise OvradError(
            f"'{obj.name}' has a UV map '{LIGHTMAP_UV}' that ovrad did not make: rename it, or name "
            "it as the UV map to bake through"
        )
    if LIGHTMAP_UV not in layers and len(layers) >= MAX_UV_MAPS:
        raise OvradError(
            f"'{obj.name}' has {len(layers)} UV maps, Blender's most: name one of them as the UV map "
            "to bake through"
        )


def make_shared(context, objects: list, densities: list, padding: float) -> int:
    """make() for several objects at once (each its own mesh): their LIGHTMAP_UV maps are
    unwrapped and packed together into one unit square, each object's islands at its own density
    (texels per scene unit) relative to the others; returns the image size giving every object
    at least its density. Every mesh is checked before any is changed."""
    for obj in objects:
        check_room(obj)
    kept = []  # per mesh: its active and render UV map names, put back afterwards
    try:
        for obj in objects:
            layers = obj.data.uv_layers
            kept.append((obj, layers.active.name if layers.active else "", render_map(obj.data)))
            layer = layers.get(LIGHTMAP_UV) or layers.new(name=LIGHTMAP_UV, do_init=False)
            if layer is None:
                raise OvradError(f"'{obj.name}': Blender refused a new UV map")
            layers.active = layer
        size = _unwrap(context, objects, densities, padding)
    finally:
        for obj, active, render in kept:
            layers = obj.data.uv_layers
            if active:
                layers.active = layers[active]
            if render:
                layers[render].active_render = True
    for obj in objects:
        obj.data[names.PROP_LIGHTMAP_UV] = digest(obj.data.uv_layers[LIGHTMAP_UV])
    return size


def _scale_islands(objects, factors) -> None:
    """Scale each object's active UV layer about the origin by its factor (Object Mode)."""
    for obj, f in zip(objects, factors, strict=True):
        if f != 1.0:
            layer = obj.data.uv_layers.active
            layer.data.foreach_set("uv", (uv_values(layer) * np.float32(f)).ravel())


def _unwrap(context, objects: list, densities: list, padding: float) -> int:
    """Smart UV Project and Pack Islands on the objects' active UV layers, in Edit Mode on them alone."""
    view_layer = context.view_layer
    selected = [o for o in view_layer.objects if o.select_get()]
    active = view_layer.objects.active
    hidden = [o.hide_get() for o in objects]
    flags = [_flags(o.data) for o in objects]
    tris = [_mesh_triangles(o) for o in objects]
    top = max(densities)
    texels = sum(world_area(w) * d * d for (_, w), d in zip(tris, densities, strict=True))
    # A first guess of the image size (islands filling 70 % of it) sets the first margin.
    margin = min(MARGIN_MOST, padding / max(math.sqrt(texels / 0.7), 1.0))
    size = MULTIPLE
    for o in selected:
        o.select_set(False)
    try:
        for o in objects:
            o.hide_set(False)
            o.select_set(True)
        view_layer.objects.active = objects[0]
        bpy.ops.object.mode_set(mode="EDIT")  # every selected mesh: multi-object editing
        bpy.ops.mesh.reveal(select=False)
        bpy.ops.mesh.select_all(action="SELECT")
        bpy.ops.uv.smart_project(
            angle_limit=ANGLE_LIMIT,
            island_margin=0.0,
            area_weight=0.0,
            correct_aspect=True,
            scale_to_bounds=False,
        )
        if len(set(densities)) > 1:  # islands of objects at a lower density drawn smaller
            bpy.ops.object.mode_set(mode="OBJECT")
            _scale_islands(objects, [d / top for d in densities])
            bpy.ops.object.mode_set(mode="EDIT")
        for k in range(_PACK_PASSES):
            if k:
                bpy.ops.object.mode_set(mode="EDIT")
            bpy.ops.uv.select_all(action="SELECT")
            bpy.ops.uv.pack_islands(
                rotate=True, scale=True, margin_method="FRACTION", margin=margin, shape_method="AABB"
            )
            bpy.ops.object.mode_set(mode="OBJECT")  # the mesh's UVs are read in Object Mode
            size = max(
                bake.density_size(
                    uv_values(o.data.uv_layers.active).astype(np.float64)[loops], world, d, MULTIPLE
                )
                for o, (loops, world), d in zip(objects, tris, densities, strict=True)
            )
            if margin * size >= padding:
                break
            if margin >= MARGIN_MOST:  # the image grows to the padding instead
                size = MULTIPLE * math.ceil(padding / margin / MULTIPLE)
                break
            margin = min(MARGIN_MOST, 1.02 * padding / size)
    finally:
        if bpy.context.mode != "OBJECT":
            bpy.ops.object.mode_set(mode="OBJECT")
        for o, f, h in zip(objects, flags, hidden, strict=True):
            _set_flags(o.data, f)
            o.select_set(False)
            o.hide_set(h)
        for o in selected:
            o.select_set(True)
        view_layer.objects.active = active
    return size


def problem(uv, world, size: int) -> str | None:
    """Why a UV map (T, 3, 2) of triangles world (T, 3, 3) is unfit for a size x size lightmap."""
    return bake.lightmap_problem(uv, world, size, size)
