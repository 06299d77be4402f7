"""The real-scenes set: small scenes of the kinds users bring, built in code (bpy), one per class.

Each builder fills an empty factory file with one class of scene that is hard on ovrad (see
the "Real scenes" table in docs/benchmarks.md): a partition with a doorway, a box resting on a
floor that runs under it and a shelf against a wall, an emitter filling an opening of the ceiling,
an emitter, a board and a picture hung a hair off the ceiling, the floor and a wall (covers),
linked duplicates, collection instances, a textured floor, and sky light through a window
(constant and HDR); and lamps_doorway, the doorway's rooms lit by all four lamp types (point,
spot, area, and a sun through a window), the second scene of benchmarks/speed_vs_error.py.
Rooms are one welded-free mesh per surface grid (every vertex lies on one planar face, as in the
Cornell benchmark), furniture is welded like a modeller's cube. Every vertex of every baked mesh
is scored: vertices under a resting box (truth 0), on edges and on rims included. Only emitters
are not scored (Cycles bakes their reflected light, ovrad adds their emission).

    scripts/blender -b --python-exit-code 1 -P scripts/make_real_scenes.py -- --output-dir scenes/real
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import make_cornell  # noqa: E402  (scripts/ is not a package)

SCENE_DIR = ROOT / "scenes" / "real"
SPACING = 0.1  # m: grid cell of room surfaces (a 3 m room: about 5 000 vertices)

WHITE = (0.75, 0.75, 0.75)
WARM = (0.8, 0.55, 0.35)
BLUE = (0.25, 0.35, 0.7)


# --------------------------------------------------------------------------- materials


# The materials are the Cornell box's (scripts/make_cornell.py): a Principled BSDF as a plain Lambert
# surface (roughness 1, no specular), and an Emission shader of colour x strength = radiance.
diffuse = make_cornell.diffuse_material
emission = make_cornell.emission_material


def checker_image(name: str, size: int = 64, cells: int = 8) -> bpy.types.Image:
    """A packed sRGB checker of a warm and a blue colour (8-bit, as a PNG texture would be)."""
    img = bpy.data.images.new(name, size, size, alpha=False)
    # the colour space first: setting it on a generated image regenerates its pixels (black)
    img.colorspace_settings.name = "sRGB"
    y, x = np.mgrid[0:size, 0:size] * cells // size
    odd = ((x + y) % 2).astype(bool)
    # sRGB-encoded values (what an 8-bit texture stores); Cycles decodes them to linear.
    a, b = np.array([0.9, 0.75, 0.55]), np.array([0.35, 0.45, 0.75])
    rgb = np.where(odd[..., None], a, b)
    px = np.concatenate([rgb, np.ones((size, size, 1))], axis=-1).astype(np.float32)
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


def textured(name: str, image) -> bpy.types.Material:
    """Principled BSDF whose Base Color is an Image Texture through the mesh's UV map."""
    mat = diffuse(name, (0.8, 0.8, 0.8))
    tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Linear"  # Blender's default: bilinear between texel centres
    uv = tree.nodes.new("ShaderNodeUVMap")
    tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def painted_material(name: str, attribute: str) -> bpy.types.Material:
    """Principled BSDF whose Base Color is a Color Attribute node reading `attribute` ('' = the
    mesh's render colour attribute), as vertex-painted game art is."""
    mat = diffuse(name, (0.8, 0.8, 0.8))
    tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    node = tree.nodes.new("ShaderNodeVertexColor")
    node.layer_name = attribute
    tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def mixed_material(name: str, blend: str, factor: float, a, b) -> bpy.types.Material:
    """Principled BSDF whose Base Color is a Mix node (colour) of a and b, each an RGB constant, an
    image (through the mesh's UV map) or a colour attribute's name."""
    mat = diffuse(name, (0.8, 0.8, 0.8))
    tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    mix = tree.nodes.new("ShaderNodeMix")
    mix.data_type, mix.blend_type = "RGBA", blend
    sockets = {s.identifier: s for s in mix.inputs}
    sockets["Factor_Float"].default_value = factor
    for source, socket in ((a, sockets["A_Color"]), (b, sockets["B_Color"])):
        if isinstance(source, bpy.types.Image):
            tex = tree.nodes.new("ShaderNodeTexImage")
            tex.image, tex.interpolation = source, "Linear"
            uv = tree.nodes.new("ShaderNodeUVMap")
            tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
            tree.links.new(tex.outputs["Color"], socket)
        elif isinstance(source, str):
            node = tree.nodes.new("ShaderNodeVertexColor")
            node.layer_name = source
            tree.links.new(node.outputs["Color"], socket)
        else:
            socket.default_value = (*source, 1.0)
    out = next(s for s in mix.outputs if s.identifier == "Result_Color")
    tree.links.new(out, bsdf.inputs["Base Color"])
    return mat


def paint(me, name: str, data_type: str, domain: str, colour) -> None:
    """A colour attribute on a mesh, each vertex or face corner coloured colour(position (k, 3))
    (k, 3) in linear RGB, made the mesh's render colour attribute."""
    attr = me.color_attributes.new(name, data_type, domain)
    co = np.empty(3 * len(me.vertices))
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    if domain == "CORNER":
        loops = np.empty(len(me.loops), np.int32)
        me.loops.foreach_get("vertex_index", loops)
        # per corner: the corner's vertex, pulled a little toward its face's centre, so that a
        # vertex's corners differ between faces as painted corners do
        poly = np.empty(len(me.loops), np.int32)
        for p in me.polygons:
            poly[p.loop_start : p.loop_start + p.loop_total] = p.index
        centre = np.array([p.center[:] for p in me.polygons])
        co = 0.7 * co[loops] + 0.3 * centre[poly]
    rgb = np.clip(np.asarray(colour(co), np.float32), 0.0, 1.0)
    attr.data.foreach_set("color", np.column_stack([rgb, np.ones(len(rgb), np.float32)]).ravel())
    me.color_attributes.render_color_index = me.color_attributes.find(name)
    me.color_attributes.active_color_index = me.color_attributes.find(name)


def world(scene, colour=(0.0, 0.0, 0.0), strength: float = 0.0, image=None) -> None:
    """The world: a constant Background colour, or an equirectangular Environment Texture."""
    w = bpy.data.worlds.new("World")
    w.color = colour
    tree = make_cornell.node_tree(w)
    bg = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBackground")
    bg.inputs["Color"].default_value = (*colour, 1.0)
    bg.inputs["Strength"].default_value = strength
    if image is not None:
        env = tree.nodes.new("ShaderNodeTexEnvironment")
        env.image = image
        tree.links.new(env.outputs["Color"], bg.inputs["Color"])
    scene.world = w


def equirect_directions(width: int, height: int) -> np.ndarray:
    """World directions (height, width, 3) of the pixel centres of an equirectangular image as
    Cycles maps them: u = 0.5 - atan2(y, x) / 2pi, v = 0.5 + elevation / pi (row 0 at the bottom)."""
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    el, phi = np.meshgrid((v - 0.5) * np.pi, (0.5 - u) * 2 * np.pi, indexing="ij")
    return np.stack([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.sin(el)], axis=-1)


SUN_DIRECTION = (0.0, -math.cos(math.radians(35)), math.sin(math.radians(35)))  # from the south


def sky_image(name: str, width: int = 128) -> bpy.types.Image:
    """A float equirectangular sky: blue gradient above, dark ground below, a bright soft sun in
    the south, 35 degrees up (it shines through the window of the sky scenes)."""
    h = width // 2
    img = bpy.data.images.new(name, width, h, alpha=False, float_buffer=True)
    d = equirect_directions(width, h)
    up = np.clip(d[..., 2:], 0, 1)
    sky = (1 - up) * np.array([0.9, 0.95, 1.0]) + up * np.array([0.3, 0.5, 1.0])
    rgb = np.where(d[..., 2:] > 0, sky, np.array([0.15, 0.12, 0.1]))
    sun = np.exp((d @ np.array(SUN_DIRECTION) - 1.0) / 0.004)[..., None]
    rgb = rgb + 30.0 * sun * np.array([1.0, 0.9, 0.75])
    px = np.concatenate([rgb, np.ones((h, width, 1))], axis=-1).astype(np.float32)
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


# --------------------------------------------------------------------------- geometry


def grid(corners, spacing: float = SPACING) -> tuple[np.ndarray, np.ndarray]:
    """A bilinear grid of quads over a quad (4, 3) (winding kept): vertices (V, 3), quads (Q, 4)."""
    p0, p1, p2, p3 = (np.asarray(c, float) for c in corners)
    nu = max(1, math.ceil(max(np.linalg.norm(p1 - p0), np.linalg.norm(p2 - p3)) / spacing - 1e-9))
    nv = max(1, math.ceil(max(np.linalg.norm(p3 - p0), np.linalg.norm(p2 - p1)) / spacing - 1e-9))
    u = np.linspace(0.0, 1.0, nu + 1)[:, None, None]
    v = np.linspace(0.0, 1.0, nv + 1)[None, :, None]
    pts = (1 - u) * (1 - v) * p0 + u * (1 - v) * p1 + u * v * p2 + (1 - u) * v * p3
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1).reshape(-1, 4)
    return pts.reshape(-1, 3), quads


def mesh(name: str, quads_corners, material, spacing: float = SPACING, collection=None, uv: bool = False):
    """One object of planar quads, each subdivided into its own grid (not welded to the others)."""
    verts, faces, base = [], [], 0
    for corners in quads_corners:
        pts, q = grid(corners, spacing)
        verts.append(pts)
        faces.append(q + base)
        base += len(pts)
    me = bpy.data.meshes.new(name)
    me.from_pydata(np.concatenate(verts).tolist(), [], np.concatenate(faces).tolist())
    if uv:
        layer = me.uv_layers.new(name="UVMap")
        co = np.concatenate(verts)
        loops = np.empty(len(me.loops), np.int32)
        me.loops.foreach_get("vertex_index", loops)
        layer.data.foreach_set("uv", (co[loops, :2] / 1.0).astype(np.float32).ravel())  # 1 m per tile
    me.materials.append(material)
    me.update()
    obj = bpy.data.objects.new(name, me)
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def box_mesh(name: str, size, material, cuts: int = 4) -> bpy.types.Mesh:
    """A welded box mesh of size (x, y, z) m standing on z = 0 at the origin, faces split in a grid."""
    import bmesh

    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)
    for v in bm.verts:
        v.co.x *= size[0]
        v.co.y *= size[1]
        v.co.z = (v.co.z + 0.5) * size[2]
    bm.to_mesh(me)
    bm.free()
    me.materials.append(material)
    return me


def place(name: str, data, location, collection=None, rotation_z: float = 0.0):
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    obj.rotation_euler = (0.0, 0.0, rotation_z)
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def room_faces(w: float, d: float, h: float, skip=()) -> dict:
    """The six inward-facing faces of a room [0, w] x [0, d] x [0, h], by name."""
    faces = {
        "floor": [(0, 0, 0), (w, 0, 0), (w, d, 0), (0, d, 0)],
        "ceiling": [(0, 0, h), (0, d, h), (w, d, h), (w, 0, h)],
        "south": [(0, 0, 0), (0, 0, h), (w, 0, h), (w, 0, 0)],
        "north": [(0, d, 0), (w, d, 0), (w, d, h), (0, d, h)],
        "west": [(0, 0, 0), (0, d, 0), (0, d, h), (0, 0, h)],
        "east": [(w, 0, 0), (w, 0, h), (w, d, h), (w, d, 0)],
    }
    return {k: v for k, v in faces.items() if k not in skip}


def wall_with_hole(x0, x1, z0, z1, hole, y: float, facing: int) -> list:
    """Quads of a wall in the plane y (x in [x0, x1], z in [z0, z1]) around a rectangular hole
    (hx0, hx1, hz0, hz1); facing +1 (+Y) or -1."""
    hx0, hx1, hz0, hz1 = hole
    rects = [
        (x0, hx0, z0, z1),
        (hx1, x1, z0, z1),
        (hx0, hx1, z0, hz0),
        (hx0, hx1, hz1, z1),
    ]
    out = []
    for a0, a1, b0, b1 in rects:
        if a1 - a0 < 1e-9 or b1 - b0 < 1e-9:
            continue
        q = [(a0, y, b0), (a1, y, b0), (a1, y, b1), (a0, y, b1)]  # normal -Y
        out.append(q if facing < 0 else q[::-1])
    return out


def area_lamp(scene, name: str, location, size: float, power: float, color=(1.0, 1.0, 1.0)):
    data = bpy.data.lights.new(name, "AREA")
    data.size = size
    data.energy = power
    data.color = color
    obj = bpy.data.objects.new(name, data)
    obj.location = location  # default orientation: shines down (-Z)
    scene.collection.objects.link(obj)
    return obj


def camera(scene, location, target) -> None:
    from mathutils import Vector

    cam = bpy.data.cameras.new("Camera")
    cam.lens = 18.0
    obj = bpy.data.objects.new("Camera", cam)
    obj.location = location
    obj.rotation_euler = (Vector(target) - Vector(location)).to_track_quat("-Z", "Y").to_euler()
    scene.collection.objects.link(obj)
    scene.camera = obj


# --------------------------------------------------------------------------- the scenes


def _new_scene(name: str):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.name = name
    scene.render.engine = "CYCLES"
    scene.render.resolution_x = scene.render.resolution_y = 384
    world(scene)
    return scene


def doorway():
    """Two 2.4 m rooms side by side, a 10 cm partition with the same doorway in both faces and
    reveal faces between them; an area lamp in the first room only."""
    scene = _new_scene("doorway")
    white = diffuse("White", WHITE)
    w, d, h, t = 2.4, 2.4, 2.4, 0.1
    # Both rooms in one mesh: x from 0 to 2w + t, the partition at x in [w, w + t].
    outer = room_faces(2 * w + t, d, h)
    mesh("Rooms", list(outer.values()), white)
    door = (0.8, 1.6, 0.0, 2.0)  # y range, z range of the doorway
    faces = []
    for x, facing in ((w, 1), (w + t, -1)):
        # wall in the plane x, built in (y, z) then mapped: wall_with_hole works in x/z at fixed y.
        for q in wall_with_hole(0.0, d, 0.0, h, door, 0.0, facing):
            faces.append([(x, p[0], p[2]) for p in q])
    y0, y1, _, z1 = door
    # reveals: the doorway's jambs and lintel, facing into the opening
    faces.append([(w, y0, 0), (w + t, y0, 0), (w + t, y0, z1), (w, y0, z1)])  # faces +Y
    faces.append([(w, y1, 0), (w, y1, z1), (w + t, y1, z1), (w + t, y1, 0)])  # faces -Y
    faces.append([(w, y0, z1), (w + t, y0, z1), (w + t, y1, z1), (w, y1, z1)])  # faces -Z
    mesh("Partition", faces, white)
    area_lamp(scene, "Lamp", (0.9, 1.2, h - 0.05), 0.6, 250.0)
    camera(scene, (0.3, 0.2, 1.7), (2 * w, 1.6, 0.8))
    return scene


def _lamp(scene, name: str, kind: str, location, power: float, color, radius: float = 0.0):
    """A point, spot or sun lamp at `location`, pointing down until aimed."""
    data = bpy.data.lights.new(name, kind)
    data.energy = power
    data.color = color
    if kind != "SUN":
        data.shadow_soft_size = radius
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    scene.collection.objects.link(obj)
    return obj


def _aim(obj, direction) -> None:
    """Turn a lamp so its -Z axis (where it shines) runs along `direction`."""
    from mathutils import Vector

    obj.rotation_euler = Vector(direction).to_track_quat("-Z", "Y").to_euler()


# Where the lamps_doorway sun shines: 40 degrees up, from 20 degrees west of south (travel direction).
LAMPS_SUN = (
    math.cos(math.radians(40)) * math.sin(math.radians(20)),
    math.cos(math.radians(40)) * math.cos(math.radians(20)),
    -math.sin(math.radians(40)),
)


def lamps_doorway():
    """The doorway's two rooms with all four lamp types: a point lamp and a spot lamp (its cone's
    edge across the floor and the west wall) in the first room, an area lamp in the second, and a
    sun shining through a window in the second room's south wall onto its floor. The world is
    black: the sun is the only light from outside."""
    scene = _new_scene("lamps_doorway")
    white = diffuse("White", WHITE)
    w, d, h, t = 2.4, 2.4, 2.4, 0.1
    outer = room_faces(2 * w + t, d, h, skip=("south",))
    window = (w + t + 0.5, w + t + 1.5, 0.9, 1.9)  # x range, z range of the second room's window
    south = wall_with_hole(0.0, 2 * w + t, 0.0, h, window, 0.0, 1)
    mesh("Rooms", list(outer.values()) + south, white)
    door = (0.8, 1.6, 0.0, 2.0)
    faces = []
    for x, facing in ((w, 1), (w + t, -1)):
        for q in wall_with_hole(0.0, d, 0.0, h, door, 0.0, facing):
            faces.append([(x, p[0], p[2]) for p in q])
    y0, y1, _, z1 = door
    faces.append([(w, y0, 0), (w + t, y0, 0), (w + t, y0, z1), (w, y0, z1)])
    faces.append([(w, y1, 0), (w, y1, z1), (w + t, y1, z1), (w + t, y1, 0)])
    faces.append([(w, y0, z1), (w + t, y0, z1), (w + t, y1, z1), (w, y1, z1)])
    mesh("Partition", faces, white)
    _lamp(scene, "Point", "POINT", (1.6, 1.8, 1.9), 150.0, (1.0, 0.85, 0.6), radius=0.05)
    spot = _lamp(scene, "Spot", "SPOT", (1.9, 0.4, 2.25), 1000.0, (0.7, 0.8, 1.0), radius=0.05)
    spot.data.spot_size = math.radians(50)
    spot.data.spot_blend = 0.1
    _aim(spot, (0.6 - 1.9, 1.5 - 0.4, 0.0 - 2.25))
    area_lamp(scene, "Area", (w + t + 0.9, 1.6, h - 0.05), 0.5, 120.0)
    sun = _lamp(scene, "Sun", "SUN", (w + t + 1.0, -1.0, 3.0), 30.0, (1.0, 0.95, 0.85))
    _aim(sun, LAMPS_SUN)
    camera(scene, (0.3, 0.2, 1.7), (2 * w, 1.6, 0.8))
    return scene


def contact():
    """A room whose floor runs under a welded box resting on it, and a shelf touching a wall."""
    scene = _new_scene("contact")
    white, warm = diffuse("White", WHITE), diffuse("Warm", WARM)
    w, d, h = 2.4, 2.4, 2.2
    mesh("Room", list(room_faces(w, d, h).values()), white)
    place("Box", box_mesh("Box", (0.6, 0.6, 0.6), warm), (1.4, 1.0, 0.0), rotation_z=0.3)
    place("Shelf", box_mesh("Shelf", (0.8, 0.3, 0.05), white, cuts=3), (0.8, d - 0.15, 1.2))
    area_lamp(scene, "Lamp", (1.0, 1.4, h - 0.05), 0.5, 180.0)
    camera(scene, (0.2, 0.1, 1.6), (1.6, 1.6, 0.4))
    return scene


def principled(name: str, colour, roughness: float = 0.5, metallic: float = 0.0, level: float = 0.5):
    """A Principled BSDF as users leave it: its specular layer on (IOR 1.5, Specular IOR Level 0.5
    unless given), a roughness, a metallic share."""
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    bsdf = next(n for n in make_cornell.node_tree(mat).nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["IOR"].default_value = 1.5
    bsdf.inputs["Specular IOR Level"].default_value = level
    bsdf.inputs["Metallic"].default_value = metallic
    return mat


def layered():
    """The contact room in Principled materials as users leave them (a specular layer on every
    surface): walls at roughness 0.5, a floor at 0.8, a half-metallic box, a glossier shelf
    (Specular IOR Level 0.8, roughness 0.3)."""
    scene = _new_scene("layered")
    w, d, h = 2.4, 2.4, 2.2
    faces = room_faces(w, d, h)
    floor = faces.pop("floor")
    mesh("Room", list(faces.values()), principled("Walls", WHITE))
    mesh("Floor", [floor], principled("Floor", (0.55, 0.5, 0.45), roughness=0.8))
    box = principled("Box", WARM, roughness=0.6, metallic=0.5)
    place("Box", box_mesh("Box", (0.6, 0.6, 0.6), box), (1.4, 1.0, 0.0), rotation_z=0.3)
    shelf = principled("Shelf", BLUE, roughness=0.3, level=0.8)
    place("Shelf", box_mesh("Shelf", (0.8, 0.3, 0.05), shelf, cuts=3), (0.8, d - 0.15, 1.2))
    area_lamp(scene, "Lamp", (1.0, 1.4, h - 0.05), 0.5, 180.0)
    camera(scene, (0.2, 0.1, 1.6), (1.6, 1.6, 0.4))
    return scene


def ceiling_opening():
    """A ceiling with a rectangular opening in which an emissive quad sits, coplanar."""
    scene = _new_scene("ceiling_opening")
    white = diffuse("White", WHITE)
    w, d, h = 2.4, 2.4, 2.2
    faces = room_faces(w, d, h, skip=("ceiling",))
    mesh("Room", list(faces.values()), white)
    hole = (0.9, 1.5, 0.9, 1.5)
    ceiling = [[(p[0], p[2], h) for p in q] for q in wall_with_hole(0, w, 0, d, hole, 0.0, 1)]
    mesh("Ceiling", ceiling, white)
    x0, x1, y0, y1 = hole
    mesh("Light", [[(x0, y0, h), (x0, y1, h), (x1, y1, h), (x1, y0, h)]], emission("Emit", (8.0, 8.0, 8.0)))
    place("Box", box_mesh("Box", (0.5, 0.5, 0.8), diffuse("Warm", WARM)), (0.7, 1.5, 0.0))
    camera(scene, (0.2, 0.1, 1.2), (1.4, 1.4, 1.6))
    return scene


def covers():
    """Things hung a hair off a surface: an emissive panel 1 cm under an intact ceiling (its back
    lights the ceiling over it, Cycles' emission being two-sided), a board floating 4 cm over the
    floor and a picture 2 cm off a wall. The surface under each cover sees other light than the
    surface beside it; a patch straddling the cover's outline mixes the two."""
    scene = _new_scene("covers")
    white, warm = diffuse("White", WHITE), diffuse("Warm", WARM)
    w, d, h = 2.4, 2.4, 2.2
    mesh("Room", list(room_faces(w, d, h).values()), white)
    x0, x1, y0, y1, z = 0.9, 1.5, 0.9, 1.5, h - 0.01
    mesh("Panel", [[(x0, y0, z), (x0, y1, z), (x1, y1, z), (x1, y0, z)]], emission("Emit", (8.0, 8.0, 8.0)))
    place("Board", box_mesh("Board", (0.9, 0.6, 0.03), warm, cuts=3), (0.8, 1.6, 0.04), rotation_z=0.2)
    place(
        "Picture", box_mesh("Picture", (0.6, 0.03, 0.4), diffuse("Blue", BLUE), cuts=3), (1.4, d - 0.035, 1.0)
    )
    camera(scene, (0.2, 0.1, 1.2), (1.4, 1.6, 0.8))
    return scene


def duplicates():
    """Two benches sharing one mesh (linked duplicates), one under the lamp and one in a corner."""
    scene = _new_scene("duplicates")
    white, warm = diffuse("White", WHITE), diffuse("Warm", WARM)
    w, d, h = 2.8, 2.4, 2.2
    mesh("Room", list(room_faces(w, d, h).values()), white)
    bench = box_mesh("Bench", (0.9, 0.35, 0.45), warm)
    place("BenchA", bench, (0.9, 1.2, 0.0))
    place("BenchB", bench, (2.2, 0.4, 0.0), rotation_z=math.pi / 2)
    area_lamp(scene, "Lamp", (0.9, 1.2, h - 0.05), 0.5, 180.0)
    camera(scene, (0.2, 0.1, 1.6), (1.6, 1.4, 0.4))
    return scene


def instances():
    """Pillars that exist only as a collection instance (an empty instancing a hidden collection)."""
    scene = _new_scene("instances")
    white, blue = diffuse("White", WHITE), diffuse("Blue", BLUE)
    w, d, h = 3.0, 2.4, 2.2
    mesh("Room", list(room_faces(w, d, h).values()), white)
    pillars = bpy.data.collections.new("Pillars")  # not linked to the scene: only instanced
    pillar = box_mesh("Pillar", (0.25, 0.25, 1.6), blue, cuts=3)
    for i, x in enumerate((0.0, 0.8)):
        place(f"Pillar{i}", pillar, (x, 0.0, 0.0), collection=pillars)
    empty = bpy.data.objects.new("PillarRow", None)
    empty.instance_type = "COLLECTION"
    empty.instance_collection = pillars
    empty.location = (1.1, 1.0, 0.0)
    scene.collection.objects.link(empty)
    area_lamp(scene, "Lamp", (1.5, 1.6, h - 0.05), 0.5, 200.0)
    camera(scene, (0.2, 0.1, 1.6), (1.8, 1.6, 0.5))
    return scene


def _room_apart_from_its_floor(name: str):
    """A new scene holding a white 2.4 x 2.4 x 2.2 m room without its floor; (scene, the floor's quad)."""
    scene = _new_scene(name)
    white = diffuse("White", WHITE)
    faces = room_faces(2.4, 2.4, 2.2)
    floor = faces.pop("floor")
    mesh("Room", list(faces.values()), white)
    return scene, floor


def textured_floor():
    """A floor whose Base Color is an sRGB checker image through its UV map."""
    scene, floor = _room_apart_from_its_floor("textured")
    h = 2.2
    mesh("Floor", [floor], textured("Checker", checker_image("checker.png")), uv=True)
    area_lamp(scene, "Lamp", (1.2, 1.2, h - 0.05), 0.6, 200.0)
    camera(scene, (0.2, 0.1, 1.6), (1.4, 1.4, 0.0))
    return scene


def painted():
    """A room whose floor's Base Color is a named byte colour attribute per face corner (stripes of
    dark and light paint, mean about 0.5), and a box whose Base Color reads the render colour
    attribute, float colours per vertex (a gradient)."""
    scene, floor = _room_apart_from_its_floor("painted")
    h = 2.2
    fl = mesh("Floor", [floor], painted_material("FloorPaint", "Paint"))

    def stripes(p):
        s = 0.5 + 0.4 * np.sin(2.0 * np.pi * p[:, 0] / 0.8)
        return np.column_stack([s, 0.6 * s + 0.2, 0.9 - 0.7 * s])

    paint(fl.data, "Paint", "BYTE_COLOR", "CORNER", stripes)
    box = box_mesh("Box", (0.6, 0.6, 0.6), painted_material("BoxPaint", ""))
    paint(
        box,
        "Col",
        "FLOAT_COLOR",
        "POINT",
        lambda p: np.column_stack([p[:, 2] / 0.6, 0.3 + 0 * p[:, 0], 1 - p[:, 2] / 0.6]),
    )
    place("Box", box, (1.5, 1.0, 0.0), rotation_z=0.3)
    area_lamp(scene, "Lamp", (1.0, 1.4, h - 0.05), 0.5, 180.0)
    camera(scene, (0.2, 0.1, 1.6), (1.6, 1.6, 0.4))
    return scene


def mixed():
    """A floor whose Base Color is a checker image multiplied by a colour attribute (per face
    corner), and a box whose Base Color mixes a constant with its render colour attribute."""
    scene, floor = _room_apart_from_its_floor("mixed")
    d, h = 2.4, 2.2
    checker = checker_image("checker.png")
    fl = mesh("Floor", [floor], mixed_material("FloorMix", "MULTIPLY", 1.0, checker, "Dirt"), uv=True)
    paint(fl.data, "Dirt", "BYTE_COLOR", "CORNER", lambda p: np.column_stack([0.4 + 0.6 * p[:, 1] / d] * 3))
    box = box_mesh("Box", (0.6, 0.6, 0.6), mixed_material("BoxMix", "MIX", 0.6, WARM, ""))
    paint(
        box,
        "Col",
        "FLOAT_COLOR",
        "POINT",
        lambda p: np.column_stack([0.2 + 0 * p[:, 0], p[:, 2] / 0.6, 0.9 - 0.5 * p[:, 2]]),
    )
    place("Box", box, (1.5, 1.0, 0.0), rotation_z=0.3)
    area_lamp(scene, "Lamp", (1.0, 1.4, h - 0.05), 0.5, 180.0)
    camera(scene, (0.2, 0.1, 1.6), (1.6, 1.6, 0.4))
    return scene


def screen(spacing: float = 0.05):
    """A dark room lit only by a screen on its north wall: a Principled BSDF whose Emission Color is
    an sRGB image (warm, dark and cool bands) through the screen's UV map, strength 6; the screen's
    quad cut into cells of `spacing`."""
    scene = _new_scene("screen")
    white = diffuse("White", WHITE)
    w, d, h = 2.4, 2.4, 2.2
    mesh("Room", list(room_faces(w, d, h).values()), white)
    img = bpy.data.images.new("screen.png", 48, 32, alpha=False)
    img.colorspace_settings.name = "sRGB"
    x = np.arange(48) * 3 // 48  # three bands across the screen
    bands = np.array([[1.0, 0.7, 0.4], [0.15, 0.15, 0.15], [0.4, 0.6, 1.0]])[x]
    px = np.concatenate([np.broadcast_to(bands, (32, 48, 3)), np.ones((32, 48, 1))], axis=-1)
    img.pixels.foreach_set(px.astype(np.float32).ravel())
    img.pack()
    mat = diffuse("Screen", (0.05, 0.05, 0.05))
    tree = mat.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image, tex.interpolation = img, "Linear"
    tree.links.new(tex.outputs["Color"], bsdf.inputs["Emission Color"])
    bsdf.inputs["Emission Strength"].default_value = 6.0
    # a 1.2 x 0.7 m screen 2 cm off the north wall, its UVs spanning the image once
    x0, x1, z0, z1, y = 0.6, 1.8, 0.9, 1.6, d - 0.02
    obj = mesh("Screen", [[(x0, y, z0), (x1, y, z0), (x1, y, z1), (x0, y, z1)]], mat, spacing=spacing)
    me = obj.data
    co = np.empty(3 * len(me.vertices))
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    loops = np.empty(len(me.loops), np.int32)
    me.loops.foreach_get("vertex_index", loops)
    uv = np.column_stack([(co[:, 0] - x0) / (x1 - x0), (co[:, 2] - z0) / (z1 - z0)])
    me.uv_layers.new(name="UVMap").data.foreach_set("uv", uv[loops].astype(np.float32).ravel())
    camera(scene, (1.2, 0.2, 1.4), (1.2, 2.4, 1.0))
    return scene


def screen_quad():
    """The screen scene with the screen one quad (two triangles), as a television is often modelled:
    its image's bands and their blends, a texel or more, lie inside its triangles."""
    return screen(spacing=10.0)


def leaf_image(name: str, size: int = 128) -> bpy.types.Image:
    """A packed 8-bit RGBA image of leaves: alpha 1 inside six rotated ellipses, 0 between them
    (an alpha-cut mask, as foliage cards use), green of varying shade."""
    img = bpy.data.images.new(name, size, size, alpha=True)
    img.colorspace_settings.name = "sRGB"
    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size
    inside = np.zeros((size, size), bool)
    shade = np.zeros((size, size))
    rng = np.random.default_rng(11)
    for k in range(6):
        cx, cy = rng.uniform(0.25, 0.75, 2)
        turn = rng.uniform(0, np.pi)
        u = (x - cx) * np.cos(turn) + (y - cy) * np.sin(turn)
        v = -(x - cx) * np.sin(turn) + (y - cy) * np.cos(turn)
        leaf = (u / 0.22) ** 2 + (v / 0.09) ** 2 <= 1.0
        shade[leaf] = 0.6 + 0.4 * k / 5
        inside |= leaf
    rgb = np.array([0.35, 0.6, 0.25]) * shade[..., None]  # sRGB-encoded, as an 8-bit texture stores
    px = np.concatenate([rgb, inside[..., None].astype(float)], axis=-1).astype(np.float32)
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


def foliage():
    """A terrace under a canopy of alpha-cut leaf cards, lit by a sun and a blue sky: a Principled
    BSDF whose Base Color and Alpha come from one RGBA image through each card's UV map. The floor
    and two walls are scored; the cards are not (see baked_meshes)."""
    scene = _new_scene("foliage")
    white = diffuse("White", WHITE)
    w = 4.0
    mesh("Floor", [[(0, 0, 0), (w, 0, 0), (w, w, 0), (0, w, 0)]], white)
    mesh("WallNorth", [[(0, w, 0), (w, w, 0), (w, w, 2.6), (0, w, 2.6)]], diffuse("Warm", WARM))
    mesh("WallWest", [[(0, 0, 0), (0, w, 0), (0, w, 2.6), (0, 0, 2.6)]], white)
    leaves = textured("Leaves", leaf_image("leaves.png"))
    tree = leaves.node_tree
    bsdf = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    tex = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeTexImage")
    tree.links.new(tex.outputs["Alpha"], bsdf.inputs["Alpha"])
    # 48 cards of 0.7 m, tilted up to 25 degrees, 2.2-2.6 m up over the terrace
    rng = np.random.default_rng(5)
    verts, faces, uvs = [], [], []
    for k in range(48):
        c = np.array([rng.uniform(0.6, 3.6), rng.uniform(0.4, 3.4), rng.uniform(2.2, 2.6)])
        turn, tilt = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(0, 25))
        a = np.array([np.cos(turn), np.sin(turn), 0.0])
        b = np.array([-np.sin(turn) * np.cos(tilt), np.cos(turn) * np.cos(tilt), np.sin(tilt)])
        corners = [c + 0.35 * (i * a + j * b) for i, j in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        verts += corners
        faces.append([4 * k + i for i in range(4)])
        uvs += [(0, 0), (1, 0), (1, 1), (0, 1)]
    me = bpy.data.meshes.new("Leaves")
    me.from_pydata([tuple(v) for v in verts], [], faces)
    me.uv_layers.new(name="UVMap").data.foreach_set("uv", np.array(uvs, np.float32).ravel())
    me.materials.append(leaves)
    me.update()
    scene.collection.objects.link(bpy.data.objects.new("Leaves", me))
    sun = _lamp(scene, "Sun", "SUN", (2, 2, 5), 3.0, (1.0, 0.95, 0.85))
    sun.data.angle = math.radians(1.0)
    _aim(sun, (0.35, 0.45, -0.82))
    world(scene, (0.45, 0.6, 1.0), 0.6)
    camera(scene, (3.8, 0.2, 1.7), (1.5, 3.0, 0.8))
    return scene


def _window_room(scene):
    white = diffuse("White", WHITE)
    w, d, h = 2.4, 2.4, 2.2
    faces = room_faces(w, d, h, skip=("south",))
    mesh("Room", list(faces.values()), white)
    window = (0.7, 1.7, 0.8, 1.8)
    mesh("WindowWall", wall_with_hole(0, w, 0, h, window, 0.0, 1), white)
    camera(scene, (1.2, 2.3, 1.6), (1.2, 0.0, 0.6))


def sky_constant():
    """A room lit only by a constant world colour through a window."""
    scene = _new_scene("sky_constant")
    _window_room(scene)
    world(scene, (0.6, 0.75, 1.0), 3.0)
    return scene


def sky_hdr():
    """A room lit only by an equirectangular HDR sky (with a sun) through a window."""
    scene = _new_scene("sky_hdr")
    _window_room(scene)
    world(scene, (0.0, 0.0, 0.0), 1.0, image=sky_image("sky.hdr"))
    return scene


def bulb():
    """A room lit only by an emissive mesh: a smooth UV sphere of 64 x 32 segments (4 032
    triangles) 5 cm over a side table near a corner, as users model a bulb; walls, floor and
    table within a few of its radii."""
    import bmesh

    scene = _new_scene("bulb")
    white, warm = diffuse("White", WHITE), diffuse("Warm", WARM)
    w, d, h = 2.4, 2.4, 2.2
    mesh("Room", list(room_faces(w, d, h).values()), white)
    place("Table", box_mesh("Table", (0.5, 0.5, 0.5), warm), (0.4, d - 0.4, 0.0))
    place("Box", box_mesh("Box", (0.6, 0.6, 0.6), white), (1.5, 1.0, 0.0), rotation_z=0.3)
    me = bpy.data.meshes.new("Bulb")
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=64, v_segments=32, radius=0.12)
    for f in bm.faces:
        f.smooth = True
    bm.to_mesh(me)
    bm.free()
    me.materials.append(emission("Glow", (60.0, 48.0, 34.0)))
    place("Bulb", me, (0.4, d - 0.4, 0.67))
    camera(scene, (2.2, 0.2, 1.6), (0.6, 2.0, 0.6))
    return scene


SCENES = {
    "doorway": doorway,
    "lamps_doorway": lamps_doorway,
    "contact": contact,
    "layered": layered,
    "ceiling_opening": ceiling_opening,
    "covers": covers,
    "duplicates": duplicates,
    "instances": instances,
    "textured": textured_floor,
    "painted": painted,
    "mixed": mixed,
    "screen": screen,
    "screen_quad": screen_quad,
    "bulb": bulb,
    "foliage": foliage,
    "sky_constant": sky_constant,
    "sky_hdr": sky_hdr,
}


# Scenes scored against another scene's reference: screen_quad is the screen scene's room under the
# same emitted light (the same image through the same planar UVs), only the screen's mesh is cut
# differently; the screen is not baked, and Cycles' converged bake of the room does not depend on
# how its emitter is cut.
REFERENCE_OF = {"screen_quad": "screen"}


def build(name: str, path: str | Path):
    """Build scene `name`, save it to `path` (.blend) and open it there; returns the scene.

    Reopened from the file: operators such as Cycles' bake need the context a loaded file has.
    """
    SCENES[name]()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True, check_existing=False)
    backup = Path(str(path) + "1")
    if backup.exists():
        backup.unlink()
    bpy.ops.wm.open_mainfile(filepath=str(path))
    return bpy.context.scene


def baked_meshes(scene) -> list:
    """What the batch bakes by default and the reference scores: every visible mesh object that
    neither emits nor is see-through. Emitters: Cycles bakes their reflected light, ovrad adds their
    emission. See-through surfaces (a material's Alpha below 1 or from an image): Cycles bakes
    alpha x their reflected light (0 at a leaf card's cut-out corners), ovrad the light of the
    surface where it is there."""
    out = []
    for obj in scene.objects:
        if obj.type != "MESH" or obj.hide_render or "ovrad_source" in obj:
            continue
        if any(m is not None and (_emits(m) or _see_through(m)) for m in obj.data.materials):
            continue
        out.append(obj)
    return sorted(out, key=lambda o: o.name)


def _emits(mat) -> bool:
    """An Emission shader, or a Principled BSDF with emission (a non-black colour, or one from nodes)."""
    if mat.node_tree is None:
        return False
    for n in mat.node_tree.nodes:
        if n.bl_idname == "ShaderNodeEmission":
            return True
        if n.bl_idname == "ShaderNodeBsdfPrincipled":
            colour, strength = n.inputs["Emission Color"], n.inputs["Emission Strength"]
            lit = colour.is_linked or max(colour.default_value[:3]) > 0
            if strength.default_value > 0 and lit:
                return True
    return False


def _see_through(mat) -> bool:
    """A Principled BSDF whose Alpha is below 1 or driven by nodes."""
    if mat.node_tree is None:
        return False
    for n in mat.node_tree.nodes:
        if n.bl_idname == "ShaderNodeBsdfPrincipled":
            alpha = n.inputs["Alpha"]
            if alpha.is_linked or alpha.default_value < 1.0:
                return True
    return False


def vertex_positions(objects) -> tuple[np.ndarray, np.ndarray]:
    """World positions (V, 3) of the objects' vertices, in order, and the object index of each."""
    pos, idx = [], []
    for k, obj in enumerate(objects):
        me = obj.data
        co = np.empty(3 * len(me.vertices), np.float64)
        me.vertices.foreach_get("co", co)
        m = np.array(obj.matrix_world)
        pos.append(co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3])
        idx.append(np.full(len(me.vertices), k))
    return np.concatenate(pos), np.concatenate(idx)


BAKED = "ovrad_radiance"  # the batch's default vertex-colour attribute


def baked_values(scene, object_names, attribute: str = BAKED) -> tuple[np.ndarray, list[str]]:
    """The POINT colour `attribute` (V, 3) of the named objects, in order (NaN where an object has
    none), and the names of the objects without it."""
    out, missing = [], []
    for name in object_names:
        obj = scene.objects[str(name)]
        me = obj.data
        attr = me.color_attributes.get(attribute)
        if attr is None or attr.domain != "POINT":
            out.append(np.full((len(me.vertices), 3), np.nan))
            missing.append(str(name))
            continue
        a = np.empty(4 * len(me.vertices), np.float32)
        attr.data.foreach_get("color", a)
        out.append(a.reshape(-1, 4)[:, :3].astype(np.float64))
    return np.concatenate(out), missing


def score(reference: dict, values: np.ndarray) -> dict:
    """Relative RMS error over every vertex that has a value (all channels), and per object."""
    ref = reference["radiance"]
    have = np.all(np.isfinite(values), axis=1)

    def rel(mask):
        d = values[mask] - ref[mask]
        return float(np.sqrt(np.sum(d * d) / max(np.sum(ref[mask] ** 2), 1e-300)))

    per_object = {}
    for k, name in enumerate(reference["object_names"]):
        m = (reference["object"] == k) & have
        if m.any():
            per_object[str(name)] = rel(m)
    places = {}
    for place, mask in room_places(reference["positions"], have).items():
        if mask.any():
            ratio = float(np.sum(values[mask]) / max(np.sum(ref[mask]), 1e-300))
            places[place] = {"rel_rms": rel(mask), "ratio": ratio, "count": int(mask.sum())}
    return {
        "rel_rms": rel(have),
        "scored": int(have.sum()),
        "vertices": int(len(ref)),
        "per_object": per_object,
        "places": places,
    }


def room_places(positions: np.ndarray, have: np.ndarray, tolerance: float = 1e-4) -> dict:
    """Masks of the scored vertices by where they sit in an axis-aligned room (the bounding box of
    the scored vertices): "edge", on two of its faces (where a wall meets the floor, the ceiling or
    another wall), "corner", on three; the rest are neither."""
    p = np.asarray(positions, np.float64)
    lo, hi = p[have].min(axis=0), p[have].max(axis=0)
    faces = ((np.abs(p - lo) < tolerance) | (np.abs(p - hi) < tolerance)).sum(axis=1)
    return {"edge": have & (faces == 2), "corner": have & (faces == 3)}
