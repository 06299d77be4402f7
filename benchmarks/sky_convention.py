"""Check ovrad's equirectangular layout and a Mapping node's Z turn against Cycles.

Six unwelded outward quads of a cube (white), lit only by an equirectangular map that is dark
except for one bright spot at (u, v); a Mapping (Point) node may turn the lookup by THETA degrees
about Z. Prints each face's Cycles vertex bake (radiance = E / pi for white) next to ovrad's
sky_irradiance / pi with Sky.rotation_z = -THETA and +THETA: the layout holds when the lit faces
agree, and the sign of the turn is the one whose row matches.

    scripts/blender -b -P benchmarks/sky_convention.py -- SAMPLES THETA U V
    (measured: 64 0 0.45 0.4 and 64 60 0.45 0.4 agree within 1 % with rotation_z = -THETA)
"""

from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "benchmarks")]

import real_scenes as rs  # noqa: E402
import scenes as bench  # noqa: E402
from ovrad_addon import Sky, make_rays, sky_irradiance  # noqa: E402

FACES = {
    "+X": [(1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)],
    "-X": [(-1, -1, -1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1)],
    "+Y": [(-1, 1, -1), (-1, 1, 1), (1, 1, 1), (1, 1, -1)],
    "-Y": [(-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)],
    "+Z": [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)],
    "-Z": [(-1, -1, -1), (-1, 1, -1), (1, 1, -1), (1, -1, -1)],
}
W, H = 64, 32


def spot_map(u0: float, v0: float) -> np.ndarray:
    uu, vv = (np.arange(W) + 0.5) / W, (np.arange(H) + 0.5) / H
    du = np.minimum(np.abs(uu[None] - u0), 1 - np.abs(uu[None] - u0))
    blob = np.exp(-(du**2 + (vv[:, None] - v0) ** 2) / (2 * 0.04**2))
    return 0.02 + 20.0 * blob[..., None] * np.ones(3)


def build(theta: float, u0: float, v0: float, path: Path) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    white = rs.diffuse("W", (1.0, 1.0, 1.0))
    for name, q in FACES.items():
        me = bpy.data.meshes.new(name)
        me.from_pydata([tuple(map(float, p)) for p in q], [], [(0, 1, 2, 3)])
        me.materials.append(white)
        scene.collection.objects.link(bpy.data.objects.new(name, me))
    img = bpy.data.images.new("spot", W, H, alpha=False, float_buffer=True)
    rgb = spot_map(u0, v0)
    img.pixels.foreach_set(np.concatenate([rgb, np.ones((H, W, 1))], -1).astype(np.float32).ravel())
    img.pack()
    rs.world(scene, (0, 0, 0), 1.0, image=img)
    if theta:
        tree = scene.world.node_tree
        env = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeTexEnvironment")
        mapping, coords = tree.nodes.new("ShaderNodeMapping"), tree.nodes.new("ShaderNodeTexCoord")
        mapping.inputs["Rotation"].default_value = (0, 0, theta)
        tree.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
        tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    bpy.ops.wm.save_as_mainfile(filepath=str(path), check_existing=False)
    bpy.ops.wm.open_mainfile(filepath=str(path))  # the bake operator needs a loaded file's context


def main() -> None:
    samples, degrees, u0, v0 = (float(a) for a in sys.argv[sys.argv.index("--") + 1 :][:4])
    theta = math.radians(degrees)
    with tempfile.TemporaryDirectory() as tmp:
        build(theta, u0, v0, Path(tmp) / "convention.blend")
        objs = [bpy.context.scene.objects[n] for n in FACES]
        rad, seconds = bench.cycles_vertex_bake(objs, int(samples), keep_world=True)
    cycles = rad.reshape(6, 4, 3).mean(axis=1)[:, 0]
    pixels = np.array(bpy.data.images["spot"].pixels[:], np.float32).reshape(H, W, 4)[..., :3]
    V = np.array([p for q in FACES.values() for p in q], float)
    T = np.array([[4 * k, 4 * k + j, 4 * k + j + 1] for k in range(6) for j in (1, 2)])
    N = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    print("faces            ", list(FACES))
    for label, rot in (("rotation_z=-THETA", -theta), ("rotation_z=+THETA", theta)):
        E = sky_irradiance(Sky(image=pixels, rotation_z=rot), make_rays(V, T), N, N, 2.0, 8192)[0]
        print(label, np.round(E[:, 0] / np.pi, 4))
    print("Cycles           ", np.round(cycles, 4), f"({seconds:.1f} s)")


main()
