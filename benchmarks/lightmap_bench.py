"""Lightmaps of the real-scenes set against a 64-sample Cycles bake of the same texels.

    scripts/blender -b --python-exit-code 1 -P benchmarks/lightmap_bench.py -- [--scene NAME ...]
        [--batch-args "--texel-density 64"] [--samples 64] [--output CSV]

For each scene: build it (benchmarks/real_scenes.py), bake it with the batch command
`--target image` (its defaults, plus --batch-args), open the saved result and score each lightmap
at every vertex of every scored mesh against benchmarks/reference/real/<scene>.npz: the image
sampled bilinearly at each face corner's UV (texel centres at (i + 0.5) / size, as Blender and
engines filter), the corners of a vertex averaged (so seams count). Then Cycles bakes the same
meshes into images of the same sizes through the same UV maps (the report's `images`: the map
ovrad used, `ovrad_lightmap` where it made one), with the same margin: a DIFFUSE bake, direct +
indirect + colour, as the references are made (benchmarks/scenes.py setup_cycles: 64 diffuse
bounces, no denoiser, no adaptive sampling, no clamps), at --samples samples; scored the same way.

Times: ovrad's is the batch's generate + solve + bake (its report's stages; `ovrad_bake_s` the
image bake alone), Cycles' its bake call. Writes benchmarks/results/lightmaps.csv.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from per_process import write_csv  # noqa: E402
from real_scenes_bench import bake  # noqa: E402

import real_scenes  # noqa: E402  (benchmarks/ is not a package)
import scenes  # noqa: E402
from make_real_reference import load  # noqa: E402

RESULTS = HERE / "results" / "lightmaps.csv"
DEFAULT_SCENES = ("doorway", "lamps_doorway", "contact", "textured", "foliage")
STAGES = ("generate", "solve", "refine", "bake")  # the batch's stages ovrad's time counts
MARGIN = 4  # the batch's default --margin: Cycles fills as many texels around the islands


def image_pixels(image) -> np.ndarray:
    """(H, W, 3) float64 RGB of an image, row 0 at the bottom (Blender's order)."""
    a = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(a)
    return a.reshape(image.size[1], image.size[0], -1)[..., :3].astype(np.float64)


def bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(m, 3) bilinear samples of img (H, W, 3) at UVs (m, 2), texel centres at (i + 0.5) / size,
    clamped to the image's edge texels."""
    h, w = img.shape[:2]
    x, y = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
    x0 = np.clip(np.floor(x).astype(np.int64), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(np.int64), 0, h - 2)
    fx, fy = np.clip(x - x0, 0.0, 1.0)[:, None], np.clip(y - y0, 0.0, 1.0)[:, None]
    bottom = img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx
    top = img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx
    return bottom * (1 - fy) + top * fy


def vertex_values(obj, img: np.ndarray, uv_map: str) -> np.ndarray:
    """(V, 3): img sampled at each face corner's UV in uv_map, the mean over each vertex's corners."""
    me = obj.data
    uv = np.empty(2 * len(me.loops), np.float32)
    me.uv_layers[uv_map].data.foreach_get("uv", uv)
    vi = np.empty(len(me.loops), np.int64)
    me.loops.foreach_get("vertex_index", vi)
    s = bilinear(img, uv.reshape(-1, 2).astype(np.float64))
    acc, n = np.zeros((len(me.vertices), 3)), np.zeros(len(me.vertices))
    np.add.at(acc, vi, s)
    np.add.at(n, vi, 1.0)
    out = acc / np.maximum(n, 1.0)[:, None]
    out[n == 0] = np.nan
    return out


def scored_values(scene, object_names, entries: dict, image_of) -> np.ndarray:
    """(V, 3) per vertex of the named objects, in order: their lightmap (image_of(name)) sampled
    through the UV map of their entry; NaN for an object without one."""
    out = []
    for name in map(str, object_names):
        obj = scene.objects[name]
        e = entries.get(name)
        if e is None:
            out.append(np.full((len(obj.data.vertices), 3), np.nan))
            continue
        out.append(vertex_values(obj, image_pixels(image_of(name)), e["uv_map"]))
    return np.concatenate(out)


def cycles_lightmaps(scene, objects, entries: dict, samples: int) -> tuple[dict, float]:
    """Cycles DIFFUSE bakes of objects into new float images of their entry's size through its UV
    map (made the active render map of a single-user copy of the mesh, each material a copy with
    the image in an active Image Texture node). Returns (object name -> image, seconds of the bake
    call)."""
    scenes.setup_cycles(scene, samples, seed=1, keep_world=True)
    b = scene.render.bake
    b.target = "IMAGE_TEXTURES"
    b.margin, b.margin_type = MARGIN, "EXTEND"
    images = {}
    for obj in objects:
        e = entries[obj.name]
        obj.data = obj.data.copy()  # linked duplicates each get their own light
        obj.data.uv_layers[e["uv_map"]].active_render = True
        img = bpy.data.images.new(f"cycles_{obj.name}", e["size"], e["size"], alpha=True, float_buffer=True)
        img.colorspace_settings.name = "Non-Color"
        images[obj.name] = img
        for slot in obj.material_slots:
            if slot.material is None:
                continue
            mat = slot.material.copy()
            mat.use_nodes = True
            node = mat.node_tree.nodes.new("ShaderNodeTexImage")
            node.image = img
            mat.node_tree.nodes.active = node
            slot.material = mat
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in objects)
    bpy.context.view_layer.objects.active = objects[0]
    start = time.perf_counter()
    bpy.ops.object.bake(type="DIFFUSE", pass_filter={"DIRECT", "INDIRECT", "COLOR"}, target="IMAGE_TEXTURES")
    return images, time.perf_counter() - start


def run_scene(name: str, folder: Path, extra: list[str], samples: int) -> dict:
    blend, out, report = folder / f"{name}.blend", folder / f"{name}_baked.blend", folder / f"{name}.json"
    real_scenes.build(name, blend)
    proc, _ = bake(blend, out, report, ["--target", "image", *extra])
    row = {"scene": name, "batch_args": " ".join(extra), "exit": proc.returncode}
    if proc.returncode != 0:
        row["error"] = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return row
    rep = json.loads(report.read_text())
    ref = load(name)
    bpy.ops.wm.open_mainfile(filepath=str(out))
    scene = bpy.context.scene
    entries = {e["object"]: e for e in rep["images"]}
    values = scored_values(
        scene, ref["object_names"], entries, lambda n: bpy.data.images[entries[n].get("image", n + "_ovrad")]
    )
    s = real_scenes.score(ref, values)
    secs = rep["seconds"]
    row.update(
        images=len(entries),
        sizes=" ".join(str(entries[n]["size"]) for n in sorted(entries)),
        texels=sum(entries[n]["size"] ** 2 for n in entries),
        ovrad_error=round(s["rel_rms"], 4),
        ovrad_s=round(sum(v for k, v in secs.items() if k.startswith(STAGES)), 2),
        ovrad_bake_s=secs.get("bake"),
        scored=s["scored"],
        vertices=s["vertices"],
        reference_noise=ref["meta"]["relative_rms_noise"],
    )
    objects = [scene.objects[str(n)] for n in ref["object_names"] if str(n) in entries]
    images, seconds = cycles_lightmaps(scene, objects, entries, samples)
    values = scored_values(scene, ref["object_names"], entries, images.__getitem__)
    c = real_scenes.score(ref, values)
    row.update(cycles_samples=samples, cycles_error=round(c["rel_rms"], 4), cycles_s=round(seconds, 2))
    row["error_ratio"] = round(row["ovrad_error"] / max(row["cycles_error"], 1e-12), 3)
    return row


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="lightmap_bench.py", description=__doc__.split("\n")[0])
    p.add_argument("--scene", nargs="*", choices=tuple(real_scenes.SCENES), help=f"default: {DEFAULT_SCENES}")
    p.add_argument("--batch-args", default="", help="extra batch options, one string")
    p.add_argument("--samples", type=int, default=64, help="Cycles samples per texel")
    p.add_argument("--output", default=str(RESULTS))
    p.add_argument("--append", action="store_true", help="add the rows to the CSV instead of replacing it")
    a = p.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="ovrad-lightmap-bench-"))
    rows = []
    for name in a.scene or DEFAULT_SCENES:
        row = run_scene(name, folder, shlex.split(a.batch_args), a.samples)
        rows.append(row)
        print("lightmap_bench:", json.dumps(row), flush=True)
    write_csv(rows, a.output, append=a.append, tag="lightmap_bench")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []))
