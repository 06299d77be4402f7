"""Headless batch baking with ovrad: generate the atlas, solve, bake to vertex colours or images, save."""

# Usage: blender -b scene.blend -P scripts/ovrad_batch.py -- --output out.blend [options]
#        blender -b -c ovrad --input scene.blend --output out.blend [options]   (extension installed)
# Works with the extension installed (any repository) or straight from a checkout; also shipped inside
# the extension. Exit status 0 on success; on an error one line "ovrad: error: ..." and status 1.

from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import os
import sys
import time
import warnings
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
PROG = "ovrad"


class BatchError(Exception):
    """A user error: printed as one line, exit status 1."""


class Parser(argparse.ArgumentParser):
    def error(self, message):
        raise BatchError(f"{message} (see --help)")


def enable_ovrad():
    """The ovrad module, registered: already enabled, else an installed extension, else this checkout."""
    if hasattr(bpy.types, "OVRAD_OT_generate_atlas"):
        for name, mod in sys.modules.items():
            if (name == "ovrad" or name.endswith(".ovrad")) and hasattr(mod, "register"):
                return mod
        return None
    import addon_utils

    for mod in addon_utils.modules(refresh=False):
        if mod.__name__.startswith("bl_ext.") and mod.__name__.endswith(".ovrad"):
            module = addon_utils.enable(mod.__name__, default_set=False)
            if module is not None and hasattr(bpy.types, "OVRAD_OT_generate_atlas"):
                return module
    # A checkout: load the repository root as the package "ovrad" (the engine is imported relatively).
    spec = importlib.util.spec_from_file_location(
        "ovrad", ROOT / "__init__.py", submodule_search_locations=[str(ROOT)]
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules["ovrad"] = module
    spec.loader.exec_module(module)
    module.register()
    return module


# (group, option, argparse keywords): every option of the batch bake.
OPTIONS = [
    ("files", "--input", dict(help="open this .blend first (needed with -c, where no file is open)")),
    ("files", "--output", dict(help="save the result to this .blend (never the input file)")),
    ("files", "--in-place", dict(action="store_true", help="save over the input file instead")),
    ("files", "--report", dict(help="write a JSON report: patch and ray counts, seconds per stage, ...")),
    ("files", "--picture", dict(help="render a PNG of the baked result with Cycles (emission preview)")),
    ("files", "--picture-size", dict(type=int, default=384, help="picture width and height (px)")),
    ("files", "--picture-samples", dict(type=int, default=16, help="Cycles samples for the picture")),
    (
        "quality",
        "--quality",
        dict(
            choices=("draft", "medium", "high"),
            help="patch count, gather rays and min rays together; the options below override them "
            "(default: the file's settings, which are medium in a new file)",
        ),
    ),
    ("atlas", "--receivers", dict(nargs="+", help="mesh names or a comma list (default: all visible)")),
    ("size", "--patch-count", dict(type=int, help="target number of patches over all receivers")),
    ("size", "--patch-size", dict(type=float, help="patch spacing in scene units")),
    ("atlas", "--overlap", dict(type=float, help="patch radius over the just-covering radius (1 to 4)")),
    ("atlas", "--beta", dict(choices=("box", "smooth"), help="patch weight profile")),
    ("solve", "--solver", dict(choices=("exact", "paper"), help="exact eq. (9) or the paper's rule")),
    ("solve", "--tolerance", dict(type=float, help="stop when unshot light < this fraction of the emitted")),
    ("solve", "--rays-per-point", dict(type=int, help="hemisphere rays per surface sample (form factors)")),
    ("solve", "--min-rays", dict(type=int, help="transport rays cast at least, in all (0: no floor)")),
    ("solve", "--max-rays", dict(type=int, help="transport rays cast at most, in all (0: no ceiling)")),
    (
        "solve",
        "--cluster-angle",
        dict(type=float, help="far transport hits read clusters under this size/distance (0: off)"),
    ),
    (
        "solve",
        "--refine",
        dict(
            type=int,
            default=0,
            help="adaptive patches: this many times, refine the atlas where the solved light varies "
            "and solve again (default 0)",
        ),
    ),
    ("bake", "--target", dict(choices=("vertex", "image"), default="vertex")),
    (
        "bake",
        "--direct",
        dict(
            choices=("points", "patches"),
            default="points",
            help="direct light of lamps, small emitters and the sky computed at every baked point (sharp), "
            "or reconstructed from the patches like the rest (the paper's reconstruction)",
        ),
    ),
    (
        "bake",
        "--gather-rays",
        dict(
            type=int,
            help="final-gather rays per baked vertex or texel for its indirect light (0: from the "
            "patches, as in the paper; with --direct points only)",
        ),
    ),
    ("bake", "--quantity", dict(choices=("radiance", "irradiance"), default="radiance")),
    ("bake", "--attribute", dict(default="ovrad_radiance", help="vertex: colour attribute name")),
    ("bake", "--domain", dict(choices=("POINT", "CORNER"), default="POINT", help="vertex: attribute domain")),
    (
        "bake",
        "--uv",
        dict(
            default="auto",
            help="image: UV map name, or auto (default): the active render UV map when fit for a "
            "lightmap, else the UV map ovrad_lightmap that ovrad makes",
        ),
    ),
    (
        "bake",
        "--texel-density",
        dict(
            type=float,
            help="image: lightmap texels per metre (default 40; times each object's Lightmap Scale)",
        ),
    ),
    ("bake", "--max-size", dict(type=int, help="image: largest width and height from the density (4096)")),
    (
        "bake",
        "--atlas",
        dict(
            choices=("object", "shared"),
            default="object",
            help="image: a lightmap per mesh (object), or the meshes' lightmaps packed into as few "
            "images as --max-size allows (shared; through UV maps ovrad makes)",
        ),
    ),
    (
        "bake",
        "--size",
        dict(type=int, default=0, help="image: width and height in texels (0: from the density)"),
    ),
    (
        "bake",
        "--margin",
        dict(type=int, default=4, help="image: dilation margin and island padding in texels"),
    ),
    (
        "bake",
        "--format",
        dict(
            choices=("exr", "png16"),
            default="exr",
            help="image: 32-bit float OpenEXR, or 16-bit PNG of linear values x 2^-exposure (exposure "
            "in the PNG's metadata and the report)",
        ),
    ),
    (
        "bake",
        "--image-path",
        dict(help="image: file path, {object}: its name (OUTDIR/ovrad/{object}.exr or .png)"),
    ),
]

FORMATS = {"exr": "OPEN_EXR", "png16": "PNG"}


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog=PROG, description=__doc__)
    groups = {g: p.add_argument_group(g) for g in ("files", "quality", "atlas", "solve", "bake")}
    groups["atlas"].description = "default: the file's ovrad settings"
    groups["size"] = groups["atlas"].add_mutually_exclusive_group()
    for group, option, kw in OPTIONS:
        groups[group].add_argument(option, **kw)
    return p


def parse(argv: list[str]) -> argparse.Namespace:
    args = build_parser().parse_args(argv)
    if args.in_place and args.output:
        raise BatchError("--output and --in-place exclude each other")
    if not args.in_place and not args.output:
        raise BatchError("nothing would be saved: give --output OUT.blend (or --in-place)")
    for name in ("patch_count", "picture_size", "picture_samples", "rays_per_point"):
        v = getattr(args, name)
        if v is not None and v < 1:
            raise BatchError(f"--{name.replace('_', '-')} must be at least 1, got {v}")
    if args.gather_rays is not None and args.gather_rays < 0:
        raise BatchError(f"--gather-rays must be at least 0, got {args.gather_rays}")
    if args.min_rays is not None and not 0 <= args.min_rays <= 1 << 28:
        raise BatchError(f"--min-rays must be between 0 and {1 << 28}, got {args.min_rays}")
    if args.max_rays is not None and not 0 <= args.max_rays <= 1 << 30:
        raise BatchError(f"--max-rays must be between 0 and {1 << 30}, got {args.max_rays}")
    if args.cluster_angle is not None and not 0 <= args.cluster_angle <= 2:
        raise BatchError(f"--cluster-angle must be between 0 and 2, got {args.cluster_angle}")
    if args.patch_size is not None and not args.patch_size > 0:
        raise BatchError(f"--patch-size must be positive, got {args.patch_size}")
    if args.tolerance is not None and not 0 < args.tolerance < 1:
        raise BatchError(f"--tolerance must be between 0 and 1, got {args.tolerance}")
    if not 0 <= args.size <= 16384:
        raise BatchError(f"--size must be between 0 and 16384, got {args.size}")
    if args.max_size is not None and not 4 <= args.max_size <= 16384:
        raise BatchError(f"--max-size must be between 4 and 16384, got {args.max_size}")
    if args.texel_density is not None and not 0 < args.texel_density <= 1e5:
        raise BatchError(f"--texel-density must be positive (at most 100000), got {args.texel_density}")
    if not 0 <= args.margin <= 256:
        raise BatchError(f"--margin must be between 0 and 256, got {args.margin}")
    if args.receivers:
        args.receivers = [n for item in args.receivers for n in item.split(",") if n]
    return args


def visible_meshes(scene, names) -> list:
    """Every mesh that renders and is visible, except ovrad atlas objects (names: ovrad's names module)."""
    return [
        o
        for o in bpy.context.view_layer.objects
        if o.type == "MESH" and names.PROP_SOURCE not in o and not o.hide_render and o.visible_get()
    ]


def unbakeable(obj, depsgraph) -> str | None:
    """Why a mesh object cannot be baked, as its modifiers leave it (None: it can): no faces, or
    coordinates that are not finite numbers."""
    mesh = obj.evaluated_get(depsgraph).data
    if len(mesh.polygons) == 0:
        return "has no faces after its modifiers"
    co = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", co)
    if not np.all(np.isfinite(co)):
        return "has NaN or infinite vertex coordinates (fix the mesh)"
    return None


def pick_receivers(scene, wanted: list[str] | None, names) -> tuple[list, list[dict]]:
    """(the receivers to bake, [{object, why}] of those skipped). One object never stops the bake:
    a named object that is not a mesh, or a mesh that cannot be baked, is skipped with a warning
    and the others are baked."""
    skipped = []
    if not wanted:
        found = visible_meshes(scene, names)
        if not found:
            raise BatchError("the scene has no visible mesh to bake")
    else:
        found = []
        for name in wanted:
            obj = scene.objects.get(name)
            if obj is None:
                meshes = ", ".join(o.name for o in visible_meshes(scene, names)) or "none"
                raise BatchError(f"no object named '{name}' in the scene (meshes: {meshes})")
            if obj.type != "MESH":
                skipped.append(dict(object=name, why=f"is not a mesh ({obj.type.lower()})"))
                continue
            found.append(obj)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = []
    for obj in found:
        why = unbakeable(obj, depsgraph)
        if why is None:
            out.append(obj)
        else:
            skipped.append(dict(object=obj.name, why=why))
    if not out:
        raise BatchError("; ".join(f"'{s['object']}' {s['why']}" for s in skipped) + ": nothing to bake")
    for s in skipped:
        print(f"ovrad: warning: '{s['object']}' {s['why']}: skipped", flush=True)
    return out, skipped


def operator(op, **kw) -> None:
    """Run an ovrad operator; its error report becomes a BatchError."""
    try:
        result = op(**kw)
    except RuntimeError as e:
        lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
        raise BatchError((lines[0] if lines else str(e)).removeprefix("Error: ")) from None
    if "FINISHED" not in result:
        raise BatchError(f"{op.idname_py()} did not finish ({', '.join(result)})")


def select(objects) -> None:
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in objects)
    bpy.context.view_layer.objects.active = objects[0] if objects else None


SOLVE_PROPS = {
    "solver": "solve_rule",
    "tolerance": "solve_tolerance",
    "rays_per_point": "rays_per_point",
    "min_rays": "min_rays",
    "max_rays": "max_rays",
    "cluster_angle": "cluster_angle",
}


def apply_settings(props, args, module) -> None:
    """The options given, onto the scene's ovrad settings (the rest stay as the file has them):
    --quality first, then the options that override it."""
    if args.quality:
        module.operators.properties.apply_quality(props, args.quality.upper())
    if args.gather_rays is not None:
        most = module.ovrad_addon.MAX_GATHER_RAYS
        if args.gather_rays > most:
            raise BatchError(f"--gather-rays must be between 0 and {most}, got {args.gather_rays}")
        props.gather_rays = args.gather_rays
    if args.patch_count is not None:
        props.size_mode, props.patch_count = "COUNT", args.patch_count
    if args.patch_size is not None:
        props.size_mode, props.patch_size = "SIZE", args.patch_size
    if args.overlap is not None:
        if not 1.0 <= args.overlap <= 4.0:
            raise BatchError(f"--overlap must be between 1 and 4, got {args.overlap}")
        props.overlap = args.overlap
    if args.beta:
        props.beta = args.beta
    if not 0 <= args.refine <= 4:
        raise BatchError(f"--refine must be between 0 and 4 passes, got {args.refine}")
    for opt, prop in SOLVE_PROPS.items():
        if getattr(args, opt) is not None:
            setattr(props, prop, getattr(args, opt))
    props.bake_target, props.bake_quantity = args.target.upper(), args.quantity.upper()
    props.bake_attribute, props.bake_domain = args.attribute, args.domain
    props.bake_direct = args.direct == "points"
    if args.texel_density is not None:
        props.bake_texel_density = args.texel_density
    if args.max_size is not None:
        props.bake_max_size = args.max_size
    props.bake_image_format = FORMATS[args.format]
    props.bake_atlas = args.atlas.upper()


def output_paths(args) -> tuple[str, str]:
    """(input path, output path), refusing to overwrite the input unless --in-place."""
    src = bpy.data.filepath
    if args.in_place:
        if not src:
            raise BatchError("--in-place needs a saved .blend file open")
        return src, src
    out = os.path.abspath(args.output)
    if not out.lower().endswith(".blend"):
        raise BatchError(f"--output must be a .blend file, got '{args.output}'")
    if src and os.path.realpath(out) == os.path.realpath(src):
        raise BatchError(f"refusing to overwrite the input file {src}: use --in-place to do that")
    return src, out


def check_writable(path: str, what: str) -> None:
    """Make the folder of `path` and check it is a folder we can write into."""
    folder = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError as e:
        raise BatchError(f"cannot write the {what} '{path}': {e.strerror}") from None
    if not os.access(folder, os.W_OK) or os.path.isdir(path):
        raise BatchError(f"cannot write the {what} '{path}'")


def run_solve(module) -> dict:
    """Run ovrad.solve; return its statistics (rays, unshot fraction, shots, converged, ...), which
    the finished job reports to the listener the solve operators offer."""
    jobs = []
    remove = module.operators.solve.add_listener(jobs.append)
    try:
        operator(bpy.ops.ovrad.solve)
    finally:
        remove()
    return jobs[-1].stats() if jobs else {}


def show_bake(obj, args, names, image=None) -> np.ndarray:
    """Give a receiver an emission-only material showing its bake (image: its entry in the report's
    `images`); return its baked RGB values."""
    mat = bpy.data.materials.new(f"{obj.name}_ovrad_picture")
    if mat.node_tree is None:
        mat.use_nodes = True  # Blender < 5.0
    tree = mat.node_tree
    tree.nodes.clear()
    emit = tree.nodes.new("ShaderNodeEmission")
    tree.links.new(emit.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    if args.target == "vertex":
        src = tree.nodes.new("ShaderNodeAttribute")
        src.attribute_name = args.attribute
        data = obj.data.color_attributes.get(args.attribute)
        values = np.empty(len(data.data) * 4 if data else 0, np.float32)
        if data:
            data.data.foreach_get("color", values)
    else:
        src = tree.nodes.new("ShaderNodeTexImage")
        src.image = bpy.data.images.get(image.get("image", obj.name + names.IMAGE_SUFFIX)) if image else None
        values = np.empty(len(src.image.pixels) if src.image else 0, np.float32)
        if src.image:
            src.image.pixels.foreach_get(values)
            uv = tree.nodes.new("ShaderNodeUVMap")
            uv.uv_map = image["uv_map"]
            tree.links.new(uv.outputs["UV"], src.inputs["Vector"])
            scale = 2.0 ** (image["exposure"] or 0)  # a 16-bit PNG holds values x 2^-exposure
            emit.inputs["Strength"].default_value = scale
            values[np.arange(len(values)) % 4 != 3] *= scale
    tree.links.new(src.outputs["Color"], emit.inputs["Color"])
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    values = values.reshape(-1, 4)
    return values[values[:, 3] > 0, :3]


def render_picture(scene, receivers, atlases, args, names, images) -> None:
    """After saving: receivers show their bake as emission, lamps and atlases hidden, Cycles, no
    bounces (images: the report's entries of an image bake)."""
    for obj in scene.objects:
        if obj.type == "LIGHT" or obj in atlases:
            obj.hide_render = True
    by_object = {e["object"]: e for e in images}
    shown = [show_bake(o, args, names, by_object.get(o.name)) for o in receivers]
    values = np.concatenate([np.zeros((1, 3)), *shown])
    bright = float(np.percentile(values.max(axis=1), 95))  # exposure: this maps to 0.8
    c = scene.cycles
    scene.render.engine, c.device, c.samples = "CYCLES", "CPU", args.picture_samples
    c.use_adaptive_sampling = c.use_denoising = False
    c.max_bounces = 0  # the surfaces emit their baked light: nothing to bounce
    if scene.world is not None:
        scene.world.color = (0, 0, 0)
        bg = scene.world.node_tree.nodes.get("Background") if scene.world.node_tree else None
        if bg is not None:
            bg.inputs["Strength"].default_value = 0.0
    scene.render.resolution_x = scene.render.resolution_y = args.picture_size
    scene.render.resolution_percentage = 100
    view = scene.view_settings
    view.view_transform, view.look = "Standard", "None"
    view.exposure = float(np.clip(np.log2(0.8 / max(bright, 1e-6)), -10, 10))
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = os.path.abspath(args.picture)
    bpy.ops.render.render(write_still=True)


def open_input(args) -> tuple[str, str]:
    """Open --input (if given) and check every file the batch will write; (input, output) paths."""
    if args.input:
        if not os.path.isfile(args.input):
            raise BatchError(f"cannot open '{args.input}': no such file")
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.input))
    elif not bpy.data.filepath:
        raise BatchError("no .blend file is open: pass one to blender before -P, or use --input FILE.blend")
    src, out = output_paths(args)
    for path, what in ((out, "output"), (args.report, "report"), (args.picture, "picture")):
        if path:
            check_writable(path, what)
    return src, out


def generate(scene, receivers, names) -> list:
    """Generate the receivers' atlases; returns the atlas objects."""
    select(receivers)
    operator(bpy.ops.ovrad.generate_atlas)
    chosen = {o.name for o in receivers}
    return [o for o in scene.objects if o.get(names.PROP_SOURCE) in chosen]


def refine(scene, receivers, atlases, names) -> list | None:
    """Refine the atlases where the solved light varies; the new atlas objects, or None when no
    patch was refined (the atlas objects are then the same)."""
    count = sum(len(o.data.vertices) for o in atlases)
    operator(bpy.ops.ovrad.refine_atlas)
    chosen = {o.name for o in receivers}
    finer = [o for o in scene.objects if o.get(names.PROP_SOURCE) in chosen]
    return None if sum(len(o.data.vertices) for o in finer) == count else finer


def bake(args, receivers, out: str, module) -> tuple[list[dict], list[dict]]:
    """Bake to vertex colours or images; returns (one {object, path, uv_map, size, format,
    exposure, image} per object baked to an image, one {object, why} per receiver not baked to an image)."""
    if args.target == "vertex":
        operator(
            bpy.ops.ovrad.bake_vertex,
            attribute=args.attribute,
            domain=args.domain,
            quantity=args.quantity.upper(),
        )
        return [], []
    template = args.image_path or os.path.join(os.path.dirname(out), "ovrad", "{object}")
    if args.in_place and not args.image_path:
        template = "//ovrad/{object}"  # the operator adds the format's extension
    props = bpy.context.scene.ovrad
    select(receivers)
    results = []
    remove = module.operators.bake_image.add_listener(results.append)
    try:
        operator(
            bpy.ops.ovrad.bake_image,
            uv_map=args.uv,
            size=args.size,
            texel_density=props.bake_texel_density,
            max_size=props.bake_max_size,
            margin=args.margin,
            quantity=args.quantity.upper(),
            file_format=FORMATS[args.format],
            filepath=template,
            atlas=args.atlas.upper(),
        )
    finally:
        remove()
    result = results[-1]
    for n in result["not_baked"]:
        print(f"ovrad: warning: '{n['object']}' not baked to an image: {n['why']}", flush=True)
    return result["images"], result["not_baked"]


def save(args, out: str) -> None:
    if args.in_place:
        bpy.ops.wm.save_mainfile(filepath=out)
    else:
        bpy.ops.wm.save_as_mainfile(filepath=out, copy=True)


def make_report(
    args, module, props, paths, receivers, atlases, stats, images, skipped, skipped_objects
) -> dict:
    """The JSON report (without its seconds); images: one {object, path, uv_map, size, format,
    exposure} per lightmap; skipped: [{object, why}] of the receivers an image bake left out;
    skipped_objects: [{object, why}] of the objects that could not be baked at all."""
    src, out = paths
    keys = ("rays", "unshot_fraction", "shots", "converged")
    report = dict(input=src, output=out, ovrad=module.__name__)
    report |= dict(receivers=[o.name for o in receivers], patches=sum(len(o.data.vertices) for o in atlases))
    report |= {k: stats.get(k) for k in keys} | dict(solver=props.solve_rule, beta=props.beta)
    # the solve's own stages (index, overlap: C, transport) and how many patches' C it found kept
    report["solve_seconds"] = {k: round(v, 3) for k, v in (stats.get("prepare_seconds") or {}).items()}
    report["solve_peak_memory_mb"] = stats.get("prepare_peak_mb") or {}
    report["overlaps_kept"] = stats.get("overlaps_kept")
    report |= dict(overlap=round(props.overlap, 6), tolerance=float(f"{props.solve_tolerance:.6g}"))
    report |= dict(quality=props.quality.lower(), gather_rays=props.gather_rays, min_rays=props.min_rays)
    report |= dict(max_rays=props.max_rays, transport_rays=stats.get("transport_rays"))
    report["cluster_angle"] = round(props.cluster_angle, 6)
    report["transport_escaped"] = stats.get("transport_escaped")
    report |= dict(target=args.target, quantity=args.quantity, images=images, not_baked=skipped)
    report["skipped"] = skipped_objects
    report["attribute"] = args.attribute if args.target == "vertex" else None
    return report


class Stages:
    """Seconds per named stage of a run, and its peak resident memory once `peaks` is set (the
    engine's memory.StagePeaks, known once ovrad is enabled)."""

    def __init__(self):
        self.start = time.perf_counter()
        self.seconds: dict[str, float] = {}
        self.peaks = None

    def run(self, name: str, fn, *args):
        t = time.perf_counter()
        if self.peaks is None:
            result = fn(*args)
        else:
            with self.peaks.stage(name):
                result = fn(*args)
        self.seconds[name] = time.perf_counter() - t
        return result

    def rounded(self) -> dict[str, float]:
        seconds = self.seconds | {"total": time.perf_counter() - self.start}
        return {k: round(v, 3) for k, v in seconds.items()}


def run(args) -> dict:
    stages = Stages()
    src, out = open_input(args)
    module = enable_ovrad()
    if module is None:
        raise BatchError("ovrad's operators are registered but its module was not found")
    engine = module.ovrad_addon
    stages.peaks = engine.StagePeaks()
    try:
        scene = bpy.context.scene
        if args.picture and scene.camera is None:
            raise BatchError("the scene has no camera to render --picture from")
        apply_settings(scene.ovrad, args, module)
        receivers, skipped_objects = pick_receivers(scene, args.receivers, engine.names)
        atlases = stages.run("generate", generate, scene, receivers, engine.names)
        stats = stages.run("solve", run_solve, module)
        for k in range(args.refine):
            finer = stages.run(f"refine{k + 1}", refine, scene, receivers, atlases, engine.names)
            if finer is None:
                break
            atlases = finer
            stats = stages.run(f"solve{k + 2}", run_solve, module)
        images, skipped = stages.run("bake", bake, args, receivers, out, module)
        stages.run("save", save, args, out)
        report = make_report(
            args, module, scene.ovrad, (src, out), receivers, atlases, stats, images, skipped, skipped_objects
        )
        if args.picture:
            stages.run("picture", render_picture, scene, receivers, atlases, args, engine.names, images)
    except engine.errors.OvradError as e:  # a user error the engine found: one line, like ours
        raise BatchError(str(e).splitlines()[0]) from None
    report["seconds"] = stages.rounded()
    report["peak_memory_mb"] = dict(stages.peaks.mb)  # per stage: MiB resident at most
    if args.report:
        with open(args.report, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=2)
    return report


def exit_on_failure(main) -> None:
    """Run a script's main() as `blender -b -P` runs it: a failure ends Blender with main's exit
    status; success returns, so Blender goes on with the arguments after the script."""
    code = main()
    if code:
        sys.exit(code)


def main(argv: list[str] | None = None) -> int:
    """Run a batch bake; returns the exit status (0 success, 1 error with one line on stderr)."""
    if argv is None:
        argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    try:
        with warnings.catch_warnings():  # numpy's RuntimeWarnings would break the one-line contract
            warnings.simplefilter("ignore", RuntimeWarning)
            report = run(parse(argv))
    except SystemExit as e:  # --help
        return e.code if isinstance(e.code, int) else 0
    except BatchError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr, flush=True)
        return 1
    except Exception as e:  # anything unforeseen: still one line, naming its type
        print(f"{PROG}: error: {type(e).__name__}: {e}".splitlines()[0], file=sys.stderr, flush=True)
        return 1
    s = report["seconds"]
    print(
        f"ovrad: {report['patches']} patches, {report['rays'] or 0:,} rays, solved in {s['solve']:.2f} s, "
        f"total {s['total']:.2f} s -> {report['output']}",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    exit_on_failure(main)
