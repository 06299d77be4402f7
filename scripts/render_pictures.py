"""Render the pictures under docs/img/ with Cycles (CPU): Cornell atlas by overlap, box vs smooth beta,
figure 3."""

# Usage: scripts/blender -b -P scripts/render_pictures.py -- [--out docs/img] [--samples 32]
# Writes cornell_overlap.png, beta_box_smooth.png and figure3_box_smooth.png.

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
from ovrad_demo import enable_ovrad  # noqa: E402  (scripts/ is not a package)

RED = (0.8, 0.03, 0.02)
GREEN = (0.03, 0.55, 0.04)
BACKGROUND = (0.02, 0.02, 0.025)


def parse(argv):
    args = argv[argv.index("--") + 1 :] if "--" in argv else []
    p = argparse.ArgumentParser(prog="render_pictures.py", description=__doc__)
    p.add_argument("--out", default=str(ROOT / "docs" / "img"), help="folder for the PNGs")
    p.add_argument("--samples", type=int, default=32)
    return p.parse_args(args)


def new_scene():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    return bpy.context.scene


def render(path: Path, width: int, height: int, samples: int) -> None:
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = 0  # everything shown is emissive: nothing to bounce
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"  # colours as they are, no tone mapping
    scene.view_settings.look = "None"
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.compression = 100  # these files live in git: smallest, lossless anyway
    if scene.world is None:
        scene.world = bpy.data.worlds.new("background")
    scene.world.color = BACKGROUND
    for node in scene.world.node_tree.nodes if scene.world.node_tree else ():
        if node.bl_idname == "ShaderNodeBackground":
            node.inputs["Color"].default_value = (*BACKGROUND, 1.0)
    scene.render.filepath = str(path)
    start = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    print(f"render_pictures: {path.name} in {time.perf_counter() - start:.1f} s")


def top_camera(width: float, center=(0.0, 0.0)):
    cam = bpy.data.objects.new("top", bpy.data.cameras.new("top"))
    cam.data.type, cam.data.ortho_scale = "ORTHO", width
    cam.location = (center[0], center[1], 10.0)
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam


def emissive(name: str, color=None, attribute: str | None = None):
    """A flat material: a constant colour, or a colour attribute of the mesh."""
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    emit = nodes.new("ShaderNodeEmission")
    if attribute:
        attr = nodes.new("ShaderNodeAttribute")
        attr.attribute_type, attr.attribute_name = "GEOMETRY", attribute
        links.new(attr.outputs["Color"], emit.inputs["Color"])
    else:
        emit.inputs["Color"].default_value = (*color, 1.0)
    links.new(emit.outputs[0], nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    return mat


def label(text: str, location, size=0.32):
    curve = bpy.data.curves.new(text, "FONT")
    curve.body, curve.size, curve.align_x = text, size, "CENTER"
    obj = bpy.data.objects.new(text, curve)
    obj.location = location
    obj.data.materials.append(emissive("label", (0.9, 0.9, 0.9)))
    bpy.context.scene.collection.objects.link(obj)


def plane(name: str, size_x: float, size_y: float, x: float):
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(x, 0.0, 0.0))
    obj = bpy.context.active_object
    obj.name = name
    obj.scale = (size_x, size_y, 1.0)
    return obj


def generate(objects, **settings):
    props = bpy.context.scene.ovrad
    for key, value in settings.items():
        setattr(props, key, value)
    for o in bpy.context.view_layer.objects:
        o.select_set(o in objects)
    bpy.context.view_layer.objects.active = objects[0]
    bpy.ops.ovrad.generate_atlas()
    for o in objects:
        o.hide_render = True  # the atlas display is drawn over it; the surface itself is not the subject
    return [a for a in bpy.data.objects if a.get("ovrad_source") in {o.name for o in objects}]


def cornell_overlap(out: Path, samples: int) -> None:
    bpy.ops.wm.open_mainfile(filepath=str(ROOT / "scenes" / "cornell.blend"))
    meshes = [o for o in bpy.context.view_layer.objects if o.type == "MESH"]
    generate(meshes, display_quantity="OVERLAP")
    render(out / "cornell_overlap.png", 512, 512, samples)


def beta_box_smooth(out: Path, samples: int) -> None:
    new_scene()
    left, right = plane("box", 3.0, 2.0, -1.7), plane("smooth", 3.0, 2.0, 1.7)
    generate([left], patch_count=40, beta="box", display_quantity="BETA")
    generate([right], patch_count=40, beta="smooth", display_quantity="BETA")
    label("box β", (-1.7, 1.2, 0.0))
    label("smooth β", (1.7, 1.2, 0.0))
    top_camera(7.0, (0.0, 0.2))
    render(out / "beta_box_smooth.png", 800, 400, samples)


def figure3_colors(ovrad, beta: str, points: np.ndarray) -> np.ndarray:
    """Colour reconstructed by the engine from a red and a green disk (paper fig. 3) at points on z = 0."""
    engine = ovrad.ovrad_addon
    from_arrays = engine.Surfaces.from_arrays
    quad = np.array([[-3, -2, 0], [3, -2, 0], [3, 2, 0], [-3, 2, 0]], float)
    surfaces = from_arrays(quad, [[0, 1, 2], [0, 2, 3]])
    index = engine.index_surfaces(surfaces, engine.AtlasSettings())
    sheet = int(index.sheet_table[0, 0])
    two = np.ones(2)
    atlas = engine.Atlas(
        centers=np.array([[-0.55, 0.0, 0.0], [0.55, 0.0, 0.0]]),
        normals=np.array([[0.0, 0.0, 1.0]] * 2),
        tangents=np.array([[1.0, 0.0, 0.0]] * 2),
        radii=two.copy(),
        shapes=np.zeros(2, np.int8),
        sheet=np.full(2, sheet),
        source_object=np.zeros(2, np.int64),
        thickness=0.01 * two,
        min_cos=0.9 * two,
        support_area=np.pi * two,
        effective_area=np.zeros(2),
        overlap_count=np.ones(2, np.int64),
        random=np.array([0.25, 0.75]),
        beta=beta,
    )
    down = np.tile([0.0, 0.0, -1.0], (len(points), 1))
    _, tri = index.rays.closest_hit(points - down, down, 2.0)  # the triangle under each point
    alpha = engine.alpha_at(
        atlas, index, engine.find_contacts(atlas, index), points, tri, np.ones(len(points))
    )
    color = engine.reconstruct(alpha, np.array([RED, GREEN]))
    covered = np.asarray(alpha.sum(axis=1)).ravel() > 0.5
    return np.where(covered[:, None], color, BACKGROUND)


def ring(name: str, center, radius: float, width: float, segments: int = 128):
    """A thin dark annulus on the rim of a disk, drawn just above the plane."""
    t = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    inner = np.stack([radius * np.cos(t), radius * np.sin(t), np.full(segments, 0.001)], 1)
    outer = inner * [(radius + width) / radius, (radius + width) / radius, 1.0]
    verts = np.concatenate([inner, outer]) + [center[0], center[1], 0.0]
    k = np.arange(segments)
    faces = np.stack([k, (k + 1) % segments, segments + (k + 1) % segments, segments + k], 1)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts.tolist(), [], faces.tolist())
    obj = bpy.data.objects.new(name, mesh)
    obj.data.materials.append(emissive("rim", (0.85, 0.85, 0.85)))
    bpy.context.scene.collection.objects.link(obj)


def figure3(ovrad, out: Path, samples: int) -> None:
    new_scene()
    material = emissive("reconstructed", attribute="fig3")
    for beta, x in (("box", -1.95), ("smooth", 1.95)):
        bpy.ops.mesh.primitive_grid_add(
            x_subdivisions=360, y_subdivisions=240, size=1.0, location=(x, 0.0, 0.0)
        )
        grid = bpy.context.active_object
        grid.scale = (3.6, 2.4, 1.0)
        bpy.context.view_layer.update()
        n = len(grid.data.vertices)
        co = np.empty(3 * n, np.float32)
        grid.data.vertices.foreach_get("co", co)
        local = co.reshape(-1, 3).astype(np.float64) * [3.6, 2.4, 0.0]
        color = figure3_colors(ovrad, beta, local)
        ovrad.operators.attributes.write_point_attribute(grid.data, "fig3", color, "FLOAT_COLOR")
        grid.data.materials.append(material)
        for cx in (-0.55, 0.55):
            ring(f"rim {beta}", (x + cx, 0.0), 1.0, 0.012)
        label(f"{beta} β", (x, 1.3, 0.0))
    top_camera(8.0, (0.0, 0.15))
    render(out / "figure3_box_smooth.png", 800, 360, samples)


def main() -> int:
    args = parse(sys.argv)
    out = Path(os.path.abspath(args.out))
    out.mkdir(parents=True, exist_ok=True)
    ovrad = enable_ovrad()
    cornell_overlap(out, args.samples)
    beta_box_smooth(out, args.samples)
    figure3(ovrad, out, args.samples)
    return 0


if __name__ == "__main__":
    sys.exit(main())
