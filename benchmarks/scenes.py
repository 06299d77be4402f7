"""Benchmark scenes in Blender (bpy): the Cornell box with receivers subdivided, and Cycles vertex bakes.

Both the Cycles references (make_reference.py) and the speed/error benchmark build their scene
here, so the vertices scored are the same. Subdivision is deterministic: every quad of a receiver
becomes its own bilinear grid of cells no longer than `spacing` (faces are not welded to each
other, so every vertex lies on exactly one planar face and its value is well defined).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CORNELL = ROOT / "scenes" / "cornell.blend"
SPACING = 0.0175  # m: 32 cells along a Cornell wall, about 7 000 vertices in all
EMITTER = "Light"


def _grid(corners: np.ndarray, spacing: float) -> tuple[np.ndarray, list]:
    """A bilinear grid over a quad (4, 3) or a fan of a polygon: vertices and quads, winding kept."""
    p0, p1, p2, p3 = corners
    nu = max(1, math.ceil(max(np.linalg.norm(p1 - p0), np.linalg.norm(p2 - p3)) / spacing))
    nv = max(1, math.ceil(max(np.linalg.norm(p3 - p0), np.linalg.norm(p2 - p1)) / spacing))
    u = np.linspace(0.0, 1.0, nu + 1)[:, None, None]
    v = np.linspace(0.0, 1.0, nv + 1)[None, :, None]
    pts = (1 - u) * (1 - v) * p0 + u * (1 - v) * p1 + u * v * p2 + (1 - u) * v * p3
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
    return pts.reshape(-1, 3), quads.tolist()


def subdivide(obj, spacing: float = SPACING) -> None:
    """Replace a mesh object's faces by grids of cells at most `spacing` long (world == local here).

    Faces that face straight down at floor level (a block's bottom, unseen) stay as they are.
    """
    mesh = obj.data
    co = np.array([v.co[:] for v in mesh.vertices], float)
    verts, faces, mats = [], [], []
    for poly in mesh.polygons:
        corners = co[list(poly.vertices)]
        if len(corners) == 4 and not _unseen(poly, co):
            pts, quads = _grid(corners, spacing)
        else:
            pts, quads = corners, [list(range(len(corners)))]
        base = sum(len(v) for v in verts)
        verts.append(pts)
        faces += [[base + i for i in q] for q in quads]
        mats += [poly.material_index] * len(quads)
    new = bpy.data.meshes.new(mesh.name + "_subdiv")
    new.from_pydata(np.concatenate(verts).tolist(), [], faces)
    for m in mesh.materials:
        new.materials.append(m)
    new.polygons.foreach_set("material_index", mats)
    new.update()
    obj.data = new
    bpy.data.meshes.remove(mesh)


def open_cornell(spacing: float = SPACING, lamps: bool = False):
    """Open scenes/cornell.blend with every receiver subdivided; returns the scene.

    lamps=True: the ceiling light becomes a white diffuse quad and a point lamp and a spot lamp
    (radius 0, hard shadows as ovrad models them) light the box instead.
    """
    bpy.ops.wm.open_mainfile(filepath=str(CORNELL))
    scene = bpy.context.scene
    for obj in scene.objects:
        if obj.type == "MESH" and obj.name != EMITTER:
            subdivide(obj, spacing)
    if lamps:
        light = scene.objects[EMITTER]
        light.data.materials.clear()
        light.data.materials.append(bpy.data.materials["White"])
        subdivide(light, spacing)
        add_lamp(scene, "Point", "POINT", (0.12, 0.30, 0.36), 6.0, (1.0, 0.85, 0.6))
        spot = add_lamp(scene, "Spot", "SPOT", (-0.2, 0.05, 0.45), 15.0, (0.7, 0.8, 1.0))
        spot.data.spot_size = math.radians(50)
        spot.data.spot_blend = 0.3
        aim(spot, (0.05, 0.40, 0.12))
    return scene


def add_lamp(scene, name: str, kind: str, location, power: float, color):
    """A lamp of radius 0 at `location` (world metres), pointing down."""
    data = bpy.data.lights.new(name, kind)
    data.energy = power
    data.color = color
    data.shadow_soft_size = 0.0
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    scene.collection.objects.link(obj)
    return obj


def aim(obj, target) -> None:
    """Point a lamp's -Z axis at a world point."""
    from mathutils import Vector

    d = Vector(target) - obj.location
    obj.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()


def receivers(scene) -> list:
    """The meshes that are baked and scored: every rendered mesh but the emitter (if it emits)."""
    emitting = EMITTER in scene.objects and any(
        n.bl_idname == "ShaderNodeEmission"
        for m in scene.objects[EMITTER].data.materials
        for n in m.node_tree.nodes
    )
    return [
        o
        for o in scene.objects
        if o.type == "MESH" and not o.hide_render and not (emitting and o.name == EMITTER)
    ]


def _unseen(poly, co) -> bool:
    """A face looking straight down at floor level: a block's bottom, which nothing sees."""
    return poly.normal.z < -0.9 and co[list(poly.vertices), 2].max() < 1e-6


def footprints(scene) -> list[np.ndarray]:
    """World XY polygons of every unseen bottom face (the blocks standing on the floor)."""
    out = []
    for obj in scene.objects:
        if obj.type != "MESH":
            continue
        m = np.array(obj.matrix_world)
        co = np.array([v.co[:] for v in obj.data.vertices]) @ m[:3, :3].T + m[:3, 3]
        out += [co[list(p.vertices), :2] for p in obj.data.polygons if _unseen(p, co)]
    return out


def hidden(positions: np.ndarray, polygons: list[np.ndarray], tol: float = 1e-6) -> np.ndarray:
    """Floor points (z ~ 0) strictly inside a footprint: covered by a block, never seen (Cycles: 0)."""
    out = np.zeros(len(positions), bool)
    on_floor = np.abs(positions[:, 2]) < tol
    for poly in polygons:
        sign = []
        for a, b in zip(poly, np.roll(poly, -1, axis=0), strict=True):
            d = positions[:, :2] - a
            sign.append((b - a)[0] * d[:, 1] - (b - a)[1] * d[:, 0])
        sign = np.array(sign)
        out |= on_floor & (np.all(sign > tol, axis=0) | np.all(sign < -tol, axis=0))
    return out


def vertex_table(objects) -> dict:
    """Positions, face normals per vertex, object index and 'scored' flag of the objects' vertices:
    not scored are block bottoms and the floor under the blocks, which nothing sees."""
    pos, nrm, obj_i, scored = [], [], [], []
    for k, obj in enumerate(objects):
        mesh = obj.data
        m = np.array(obj.matrix_world)
        co = np.array([v.co[:] for v in mesh.vertices]) @ m[:3, :3].T + m[:3, 3]
        n = np.zeros_like(co)
        seen = np.ones(len(co), bool)
        for poly in mesh.polygons:
            idx = list(poly.vertices)
            n[idx] = poly.normal[:]
            if _unseen(poly, co):
                seen[idx] = False
        pos.append(co)
        nrm.append(n @ m[:3, :3].T)
        obj_i.append(np.full(len(co), k))
        scored.append(seen)
    pos = np.concatenate(pos)
    under = hidden(pos, footprints(objects[0].users_scene[0])) if objects else np.zeros(0, bool)
    return {
        "positions": pos,
        "normals": np.concatenate(nrm),
        "object": np.concatenate(obj_i),
        "scored": np.concatenate(scored) & ~under,
        "object_names": np.array([o.name for o in objects]),
    }


def setup_cycles(scene, samples: int, seed: int = 0, threads: int = 0, keep_world: bool = False) -> None:
    """Cycles as a converging reference: no adaptive sampling, no denoising, no clamps, 64 diffuse
    bounces; the world is made black unless keep_world (scenes lit by the sky)."""
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = samples
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = seed
    c.use_animated_seed = False
    c.sample_clamp_direct = 0.0
    c.sample_clamp_indirect = 0.0
    c.max_bounces = 64
    c.diffuse_bounces = 64
    c.glossy_bounces = 0
    c.transmission_bounces = 0
    c.transparent_max_bounces = 8
    c.caustics_reflective = False
    c.caustics_refractive = False
    if threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
    b = scene.render.bake
    b.target = "VERTEX_COLORS"
    b.use_pass_direct = b.use_pass_indirect = b.use_pass_color = True
    b.use_pass_emit = False
    b.use_clear = True
    if scene.world is not None and not keep_world:
        scene.world.color = (0, 0, 0)
        bg = scene.world.node_tree.nodes.get("Background") if scene.world.node_tree else None
        if bg is not None:
            bg.inputs["Strength"].default_value = 0.0


BAKE_ATTRIBUTE = "cycles_bake"


def cycles_vertex_bake(
    objects, samples: int, seed: int = 0, keep_world: bool = False
) -> tuple[np.ndarray, float]:
    """Cycles DIFFUSE bake (direct + indirect + colour) to a POINT colour attribute of every object.

    Returns (radiance (V, 3) in vertex_table order, seconds of the bake call).
    """
    scene = bpy.context.scene
    setup_cycles(scene, samples, seed, keep_world=keep_world)
    for obj in objects:
        mesh = obj.data
        old = mesh.color_attributes.get(BAKE_ATTRIBUTE)
        if old is not None:
            mesh.color_attributes.remove(old)
        attr = mesh.color_attributes.new(BAKE_ATTRIBUTE, "FLOAT_COLOR", "POINT")
        mesh.color_attributes.active_color = attr
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in objects)
    bpy.context.view_layer.objects.active = objects[0]
    start = time.perf_counter()
    bpy.ops.object.bake(type="DIFFUSE", pass_filter={"DIRECT", "INDIRECT", "COLOR"}, target="VERTEX_COLORS")
    seconds = time.perf_counter() - start
    out = []
    for obj in objects:
        attr = obj.data.color_attributes[BAKE_ATTRIBUTE]
        a = np.empty(len(obj.data.vertices) * 4, np.float32)
        attr.data.foreach_get("color", a)
        out.append(a.reshape(-1, 4)[:, :3])
    return np.concatenate(out).astype(np.float64), seconds


def relative_rms(values: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """sqrt(sum |v - ref|^2 / sum |ref|^2) over the masked vertices and all channels."""
    d = values[mask] - reference[mask]
    return float(np.sqrt(np.sum(d * d) / np.sum(reference[mask] ** 2)))
