"""Build a production-like scene: a lit room with ~100 k messy triangles (run with scripts/blender -b -P).

Usage: scripts/blender -b --python-exit-code 1 -P scripts/make_production_scene.py -- \
           --output scenes/production.blend [--npz surfaces.npz]

What real models bring and the Cornell box does not: the BoomBox glTF model (CC0, from
/work/shared/assets or --boombox), Suzanne subdivided and displaced (her eyes intersect her
head), a boolean, an array of thin open shells, thousands of small separate pieces (bent open
"leaves" and tiny cubes) in one mesh, non-manifold fins and zero-area triangles. The room has a
floor, four walls and a ceiling, and an emissive quad under the ceiling. Deterministic: a fixed
random seed, no dependence on the user's startup file. --npz also writes the scene's surfaces
(world-space triangles per object, reflectance, emission) for engine benchmarks and tests.
"""

import argparse
import math
import os
import sys

import bpy
import numpy as np

BOOMBOX = "/work/shared/assets/BoomBox/BoomBox.gltf"
ROOM = (6.0, 6.0, 3.0)  # x, y, height (m); floor centred on the origin at z = 0
LIGHT_RADIANCE = (12.0, 11.0, 9.0)


def material(name, colour, emission=0.0):
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    if mat.node_tree is None:
        mat.use_nodes = True
    bsdf = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    bsdf.inputs["Emission Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bsdf.inputs["Emission Strength"].default_value = emission
    return mat


def link(name, verts, faces, mat):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(map(float, v)) for v in verts], [], [tuple(map(int, f)) for f in faces])
    mesh.update()
    mesh.materials.append(mat)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def room(white, light_mat):
    """Floor, ceiling and walls (each a quad split 4 x 4, facing into the room) and the light."""
    sx, sy, h = ROOM[0] / 2, ROOM[1] / 2, ROOM[2]

    def quad(name, origin, u, v, mat, cuts=4):
        o, u, v = np.array(origin, float), np.array(u, float), np.array(v, float)
        g = np.linspace(0.0, 1.0, cuts + 1)
        verts = [o + a * u + b * v for b in g for a in g]
        n = cuts + 1
        faces = [
            (j * n + i, j * n + i + 1, (j + 1) * n + i + 1, (j + 1) * n + i)
            for j in range(cuts)
            for i in range(cuts)
        ]
        return link(name, verts, faces, mat)

    quad("Floor", (-sx, -sy, 0), (2 * sx, 0, 0), (0, 2 * sy, 0), white)
    quad("Ceiling", (-sx, -sy, h), (0, 2 * sy, 0), (2 * sx, 0, 0), white)
    quad("WallNorth", (-sx, sy, 0), (2 * sx, 0, 0), (0, 0, h), white)
    quad("WallSouth", (-sx, -sy, 0), (0, 0, h), (2 * sx, 0, 0), white)
    quad("WallEast", (sx, -sy, 0), (0, 0, h), (0, 2 * sy, 0), white)
    quad("WallWest", (-sx, -sy, 0), (0, 2 * sy, 0), (0, 0, h), white)
    quad("Light", (-0.6, -0.6, h - 0.01), (0, 1.2, 0), (1.2, 0, 0), light_mat, cuts=1)


def boombox(path, mat):
    import addon_utils

    addon_utils.enable("io_scene_gltf2")
    before = set(bpy.data.objects)
    bpy.ops.import_scene.gltf(filepath=path)
    objs = [o for o in bpy.data.objects if o not in before and o.type == "MESH"]
    obj = objs[0]
    obj.name = "BoomBox"
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    obj.scale = (40.0, 40.0, 40.0)
    obj.rotation_euler = (math.pi / 2, 0.0, 0.3)
    obj.location = (-1.2, 1.0, 0.0)
    bpy.context.view_layer.update()
    lowest = min((obj.matrix_world @ v.co).z for v in obj.data.vertices)
    obj.location.z -= lowest
    return obj


def suzanne(mat):
    """Suzanne subdivided twice and displaced by noise: her eyes are separate, intersecting parts."""
    bpy.ops.mesh.primitive_monkey_add(size=1.2, location=(1.2, 1.0, 0.6))
    obj = bpy.context.active_object
    obj.name = "Suzanne"
    obj.data.materials.append(mat)
    sub = obj.modifiers.new("subsurf", "SUBSURF")
    sub.levels = sub.render_levels = 2
    tex = bpy.data.textures.new("noise", "CLOUDS")
    tex.noise_scale = 0.2
    disp = obj.modifiers.new("displace", "DISPLACE")
    disp.texture = tex
    disp.strength = 0.02
    tri = obj.modifiers.new("triangulate", "TRIANGULATE")
    tri.quad_method = "BEAUTY"
    return obj


def boolean_block(mat):
    """A cube with a sphere cut out of a corner, and a thin shell array through it (intersecting)."""
    bpy.ops.mesh.primitive_cube_add(size=0.8, location=(1.6, -1.4, 0.4))
    cube = bpy.context.active_object
    cube.name = "Carved"
    cube.data.materials.append(mat)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=0.5, location=(1.9, -1.1, 0.7))
    ball = bpy.context.active_object
    ball.hide_render = True
    ball.hide_set(True)
    mod = cube.modifiers.new("carve", "BOOLEAN")
    mod.operation = "DIFFERENCE"
    mod.object = ball
    cube.modifiers.new("triangulate", "TRIANGULATE")
    bpy.context.view_layer.objects.active = cube
    bpy.ops.object.modifier_apply(modifier="carve")
    bpy.data.objects.remove(ball)
    # Open tubes (no caps: open edges), a row of them through the cube.
    bpy.ops.mesh.primitive_cylinder_add(
        vertices=24, radius=0.12, depth=1.0, end_fill_type="NOTHING", location=(0.9, -1.4, 0.3)
    )
    tube = bpy.context.active_object
    tube.name = "Tubes"
    tube.rotation_euler = (0.0, math.pi / 2, 0.0)
    tube.data.materials.append(mat)
    arr = tube.modifiers.new("array", "ARRAY")
    arr.count = 8
    arr.relative_offset_displace = (0.0, 1.2, 0.0)
    tube.modifiers.new("triangulate", "TRIANGULATE")
    return cube, tube


def scatter(mat, rng, n_leaves=3000, n_cubes=2000):
    """Thousands of small separate pieces in one mesh: bent open leaves (3 x 3 grids, a smooth
    curved chart each) and tiny cubes, some intersecting; a few non-manifold fins and zero-area
    triangles."""
    verts, faces = [], []
    g = np.linspace(-1.0, 1.0, 4)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    leaf_uv = np.stack([gx.ravel(), gy.ravel()], 1)
    leaf_faces = [(i * 4 + j, (i + 1) * 4 + j, (i + 1) * 4 + j + 1) for i in range(3) for j in range(3)]
    leaf_faces += [(i * 4 + j, (i + 1) * 4 + j + 1, i * 4 + j + 1) for i in range(3) for j in range(3)]
    for _ in range(n_leaves):
        size = rng.uniform(0.01, 0.05)
        bend = rng.uniform(0.1, 0.5)
        p = np.column_stack([leaf_uv * size, bend * size * (leaf_uv[:, 0] ** 2 + leaf_uv[:, 1] ** 2) / 2])
        a, b = rng.uniform(0, 2 * math.pi), rng.uniform(0, math.pi)
        ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
        rot = np.array([[ca, -sa, 0], [sa, ca, 0], [0, 0, 1]]) @ np.array(
            [[1, 0, 0], [0, cb, -sb], [0, sb, cb]]
        )
        centre = np.array([rng.uniform(-2.5, 0.5), rng.uniform(-2.5, -0.3), rng.uniform(0.02, 0.5)])
        base = len(verts)
        verts.extend(p @ rot.T + centre)
        faces.extend(tuple(base + k for k in f) for f in leaf_faces)
    cube_v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    cube_f = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    for _ in range(n_cubes):
        size = rng.uniform(0.005, 0.03)
        centre = np.array([rng.uniform(0.3, 2.7), rng.uniform(0.3, 2.7), size + rng.uniform(0.0, 0.3)])
        base = len(verts)
        verts.extend(cube_v * size + centre)
        faces.extend(tuple(base + k for k in f) for f in cube_f)
    for _ in range(50):  # fins: a third triangle on an edge of a leaf (non-manifold edge)
        f = faces[int(rng.integers(0, 9 * 2 * n_leaves))]
        a, b = np.array(verts[f[0]]), np.array(verts[f[1]])
        base = len(verts)
        verts.extend([a, b, (a + b) / 2 + np.array([0.0, 0.0, 0.03])])
        faces.append((f[0], f[1], base + 2))
    for _ in range(50):  # zero-area triangles: three distinct vertices on one line / one point
        p = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(0.1, 1)])
        d = rng.normal(size=3) * 0.01
        base = len(verts)
        verts.extend([p, p + d, p + 2 * d])
        faces.append((base, base + 1, base + 2))
    return link("Scatter", verts, faces, mat)


def build(boombox_path):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.name = "Production"
    scene.render.engine = "CYCLES"
    rng = np.random.default_rng(20240601)
    white = material("White", (0.75, 0.73, 0.7))
    grey = material("Grey", (0.5, 0.5, 0.5))
    red = material("Red", (0.6, 0.1, 0.08))
    green = material("Green", (0.15, 0.45, 0.1))
    light_mat = material("Light", (0.0, 0.0, 0.0), emission=1.0)
    node = next(n for n in light_mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    strength = max(LIGHT_RADIANCE)
    node.inputs["Emission Color"].default_value = (*(c / strength for c in LIGHT_RADIANCE), 1.0)
    node.inputs["Emission Strength"].default_value = strength
    room(white, light_mat)
    boombox(boombox_path, grey)
    suzanne(red)
    boolean_block(green)
    scatter(grey, rng)
    world = bpy.data.worlds.new("World")
    world.color = (0.0, 0.0, 0.0)
    scene.world = world
    return scene


def surfaces_arrays(scene):
    """World-space triangles of every rendered mesh, per object (evaluated, modifiers applied)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = {"vertices": [], "triangles": [], "object_index": [], "reflectance": [], "emission": []}
    names, base = [], 0
    for obj in sorted(
        (o for o in scene.objects if o.type == "MESH" and not o.hide_render), key=lambda o: o.name
    ):
        ev = obj.evaluated_get(depsgraph)
        mesh = ev.to_mesh()
        mesh.calc_loop_triangles()
        co = np.empty(3 * len(mesh.vertices), np.float32)
        mesh.vertices.foreach_get("co", co)
        tri = np.empty(3 * len(mesh.loop_triangles), np.int32)
        mesh.loop_triangles.foreach_get("vertices", tri)
        mat = ev.material_slots[0].material if ev.material_slots else None
        ev.to_mesh_clear()
        m = np.array(ev.matrix_world, np.float64)
        v = co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]
        t = tri.reshape(-1, 3).astype(np.int64)
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        rho = np.array(bsdf.inputs["Base Color"].default_value[:3], float)
        em = (
            np.array(bsdf.inputs["Emission Color"].default_value[:3], float)
            * bsdf.inputs["Emission Strength"].default_value
        )
        out["vertices"].append(v)
        out["triangles"].append(t + base)
        out["object_index"].append(np.full(len(t), len(names)))
        out["reflectance"].append(np.tile(rho, (len(t), 1)))
        out["emission"].append(np.tile(em, (len(t), 1)))
        names.append(obj.name)
        base += len(v)
    arrays = {k: np.concatenate(v) for k, v in out.items()}
    arrays["object_names"] = np.array(names)
    return arrays


def main(argv):
    parser = argparse.ArgumentParser(prog="make_production_scene.py", description=__doc__)
    parser.add_argument("--output", help="the .blend file to write")
    parser.add_argument("--npz", help="also write the scene's surfaces as arrays to this .npz")
    parser.add_argument("--boombox", default=BOOMBOX, help="path of BoomBox.gltf")
    args = parser.parse_args(argv)
    scene = build(args.boombox)
    if args.output:
        out = os.path.abspath(args.output)
        os.makedirs(os.path.dirname(out), exist_ok=True)
        bpy.ops.wm.save_as_mainfile(filepath=out, compress=True, check_existing=False)
        if os.path.exists(out + "1"):
            os.remove(out + "1")
        print(f"wrote {out} ({os.path.getsize(out)} bytes, {len(bpy.data.objects)} objects)")
    if args.npz:
        arrays = surfaces_arrays(scene)
        np.savez_compressed(args.npz, **arrays)
        print(
            f"wrote {args.npz} ({len(arrays['triangles'])} triangles, {len(arrays['object_names'])} objects)"
        )


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else [])
