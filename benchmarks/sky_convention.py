"""Check Cycles' equirect layout + Mapping Z rotation sign against ovrad's Sky."""
import sys, math
sys.path[:0] = ["/work/wtsky", "/work/wtsky/benchmarks", "/work/wtsky/tests"]
import bpy, numpy as np
import real_scenes as rs
import scenes as bscenes
from ovrad_addon.sky import Sky, sky_irradiance
from ovrad_addon.rays import make_rays

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
# six separate unit quads of a cube, normals outward
faces = {
    "+X": [(1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)],
    "-X": [(-1, -1, -1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1)],
    "+Y": [(-1, 1, -1), (-1, 1, 1), (1, 1, 1), (1, 1, -1)],
    "-Y": [(-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)],
    "+Z": [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)],
    "-Z": [(-1, -1, -1), (-1, 1, -1), (1, 1, -1), (1, -1, -1)],
}
white = rs.diffuse("W", (1.0, 1.0, 1.0))
objs = []
for name, q in faces.items():
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, p)) for p in q], [], [(0, 1, 2, 3)])
    me.materials.append(white)
    o = bpy.data.objects.new(name, me)
    scene.collection.objects.link(o)
    objs.append(o)
W, H = 64, 32
img = bpy.data.images.new("blob", W, H, alpha=False, float_buffer=True)
u0, v0 = float(sys.argv[-2]), float(sys.argv[-1])
uu = (np.arange(W) + 0.5) / W; vv = (np.arange(H) + 0.5) / H
du = np.minimum(np.abs(uu[None] - u0), 1 - np.abs(uu[None] - u0)); dv = vv[:, None] - v0
blob = np.exp(-(du**2 + dv**2) / (2 * 0.04**2))
rgb = 0.02 + 20.0 * blob[..., None] * np.ones(3)
img.pixels.foreach_set(np.concatenate([rgb, np.ones((H, W, 1))], -1).astype(np.float32).ravel())
img.pack()
rs.world(scene, (0, 0, 0), 1.0, image=img)
tree = scene.world.node_tree
env = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeTexEnvironment")
theta = math.radians(float(sys.argv[-3]))
if theta:
    mp = tree.nodes.new("ShaderNodeMapping"); tc = tree.nodes.new("ShaderNodeTexCoord")
    mp.inputs["Rotation"].default_value = (0, 0, theta)
    tree.links.new(tc.outputs["Generated"], mp.inputs["Vector"]); tree.links.new(mp.outputs["Vector"], env.inputs["Vector"])
bpy.ops.wm.save_as_mainfile(filepath="/tmp/wtsky/conv.blend", check_existing=False)
bpy.ops.wm.open_mainfile(filepath="/tmp/wtsky/conv.blend")
scene = bpy.context.scene
objs = [scene.objects[n] for n in faces]
img = bpy.data.images["blob"]
px = np.array(img.pixels[:], np.float32).reshape(H, W, 4)[..., :3]
import importlib.util
spec = importlib.util.spec_from_file_location("bscenes2", "/work/wtsky/benchmarks/scenes.py")
bs = importlib.util.module_from_spec(spec); spec.loader.exec_module(bs)
rad, sec = bs.cycles_vertex_bake(objs, int(sys.argv[-4]), keep_world=True)
cyc = rad.reshape(6, 4, 3).mean(axis=1)[:, 0]
# ovrad: the six faces' centres (just off them), the cube as occluder
V = np.array([p for q in faces.values() for p in q], float)
T = np.array([[4 * k, 4 * k + 1, 4 * k + 2] for k in range(6)] + [[4 * k, 4 * k + 2, 4 * k + 3] for k in range(6)])
rays = make_rays(V, T)
N = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
P = N * 1.0
for label, rot in (("rot=-theta", -theta), ("rot=+theta", theta)):
    E = sky_irradiance(Sky(image=px, rotation_z=rot), rays, P, N, 2.0, 8192)[0][:, 0]
    print("ovrad", label, np.round(E / np.pi, 4))
print("cycles      ", np.round(cyc, 4), f"{sec:.1f}s")
s = Sky(image=px)
# Sky.radiance at the blob's predicted direction
el, phi = (v0 - 0.5) * np.pi, (0.5 - u0) * 2 * np.pi
d = np.array([[math.cos(el) * math.cos(phi), math.cos(el) * math.sin(phi), math.sin(el)]])
print("blob dir", np.round(d, 3), "Sky.radiance there", s.radiance(d)[0, 0], "max", px.max())
