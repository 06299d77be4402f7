"""The share of a Principled BSDF's diffuse light that Cycles' diffuse bake reports, measured.

Run:
    scripts/blender -b --python-exit-code 1 -P benchmarks/principled_layer.py

A Principled BSDF layers a dielectric specular lobe over its diffuse one; Cycles weights the
diffuse lobe by 1 - the specular lobe's albedo towards the viewer, and a bake views each point
along its normal. The DIFFUSE bake's colour pass of a white Principled BSDF is that weight. This
script bakes it for a grid of roughness x F0 (F0 = ((IOR - 1) / (IOR + 1))^2, Specular IOR Level
0.5) and prints the table that operators/principled.py holds (BAKE_WEIGHT). The colour pass has no
noise: the weight depends on the material and the view only.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import bpy
import numpy as np

ROUGHNESS = np.linspace(0.0, 1.0, 11)
F0 = (0.0, 0.02, 0.04, 0.08, 0.16, 0.32, 0.64)


def ior_of(f0: float) -> float:
    s = np.sqrt(f0)
    return float((1 + s) / (1 - s))


def measure(roughness=ROUGHNESS, f0s=F0, level: float = 0.5) -> np.ndarray:
    """(len(roughness), len(f0s)) the colour pass of white Principled BSDFs, one plane each."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    for i, r in enumerate(roughness):
        for j, f0 in enumerate(f0s):
            mat = bpy.data.materials.new(f"m{i}_{j}")
            mat.use_nodes = True
            bsdf = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
            bsdf.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
            bsdf.inputs["Roughness"].default_value = float(r)
            bsdf.inputs["IOR"].default_value = ior_of(f0) if f0 > 0 else 1.5
            bsdf.inputs["Specular IOR Level"].default_value = level if f0 > 0 else 0.0
            mesh = bpy.data.meshes.new(f"p{i}_{j}")
            mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
            mesh.materials.append(mat)
            obj = bpy.data.objects.new(mesh.name, mesh)
            obj.location = (2.0 * i, 2.0 * j, 0.0)
            scene.collection.objects.link(obj)
            mesh.color_attributes.new("weight", "FLOAT_COLOR", "POINT")
    # baking needs the objects in a saved file's view layer
    path = Path(tempfile.mkdtemp(prefix="ovrad-principled-")) / "layer.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    for obj in scene.objects:
        obj.select_set(True)
        obj.data.color_attributes.active_color = obj.data.color_attributes["weight"]
    bpy.context.view_layer.objects.active = scene.objects[0]
    bpy.ops.object.bake(type="DIFFUSE", pass_filter={"COLOR"}, target="VERTEX_COLORS")
    out = np.zeros((len(roughness), len(f0s)))
    for i in range(len(roughness)):
        for j in range(len(f0s)):
            data = scene.objects[f"p{i}_{j}"].data.color_attributes["weight"].data
            v = np.empty(len(data) * 4, np.float32)
            data.foreach_get("color", v)
            out[i, j] = v.reshape(-1, 4)[:, 0].mean()
    return out


def main() -> int:
    table = measure()
    print(f"# Blender {bpy.app.version_string}; rows: roughness {ROUGHNESS.tolist()}; columns: F0 {list(F0)}")
    print("BAKE_WEIGHT = (")
    for row in table:
        print("    (" + ", ".join(f"{x:.5f}" for x in row) + "),")
    print(")")
    return 0


if __name__ == "__main__":
    sys.exit(main())
