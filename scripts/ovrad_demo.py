"""The main job: generate the atlas of every receiving mesh in the open file, save it, render it."""

# Usage: scripts/blender -b scenes/cornell.blend -P scripts/ovrad_demo.py -- \
#            --output out/cornell_ovrad.blend --picture out/cornell_ovrad.png
# Works with the extension installed (bl_ext.user_default.ovrad) or straight from a checkout.

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import sys
import time
from pathlib import Path

import bpy

ROOT = Path(__file__).resolve().parent.parent
EXTENSION = "bl_ext.user_default.ovrad"


def enable_ovrad():
    """The ovrad module, registered: the installed extension if there is one, else this checkout."""
    if hasattr(bpy.types, "OVRAD_OT_generate_atlas"):
        return sys.modules.get(EXTENSION) or sys.modules.get("ovrad")
    try:
        found = importlib.util.find_spec(EXTENSION) is not None
    except ModuleNotFoundError:  # no bl_ext package at all
        found = False
    if found:
        import addon_utils

        module = addon_utils.enable(EXTENSION, default_set=False)
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


def parse(argv: list[str]) -> argparse.Namespace:
    args = argv[argv.index("--") + 1 :] if "--" in argv else []
    p = argparse.ArgumentParser(prog="ovrad_demo.py", description=__doc__)
    p.add_argument(
        "--output", required=True, help="where to save the .blend with the atlas (never the input file)"
    )
    p.add_argument("--picture", help="render a PNG of the atlas coloured by the display quantity")
    p.add_argument("--patch-count", type=int, help="target patch count (default: the file's setting)")
    p.add_argument("--beta", choices=("box", "smooth"), help="beta profile (default: the file's setting)")
    p.add_argument(
        "--display", default="OVERLAP", choices=("OVERLAP", "RANDOM", "BETA"), help="what to colour by"
    )
    p.add_argument("--samples", type=int, default=16, help="Cycles samples for the picture")
    p.add_argument("--resolution", type=int, default=384, help="picture width and height in pixels")
    return p.parse_args(args)


def receivers() -> list:
    """Every mesh that renders, except atlas objects."""
    return [
        o
        for o in bpy.context.view_layer.objects
        if o.type == "MESH" and "ovrad_source" not in o and not o.hide_render and o.visible_get()
    ]


def render(path: str, atlas_objects: list, samples: int, resolution: int) -> float:
    """Render only the atlas objects (their display is emissive), with Cycles on the CPU."""
    scene = bpy.context.scene
    if scene.camera is None:
        raise SystemExit("ovrad_demo: the scene has no camera to render the picture from")
    for obj in scene.objects:
        obj.hide_render = obj not in atlas_objects and obj.type == "MESH"
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = 0  # the patches emit their colour: nothing to bounce
    scene.render.resolution_x = scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    # Standard, not AgX/Filmic: the display's colours are meant to be read as they are.
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = os.path.abspath(path)
    start = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - start


def main() -> int:
    args = parse(sys.argv)
    output = os.path.abspath(args.output)
    if bpy.data.filepath and os.path.realpath(output) == os.path.realpath(bpy.data.filepath):
        print(f"ovrad_demo: refusing to overwrite the input file {bpy.data.filepath}", file=sys.stderr)
        return 2
    module = enable_ovrad()
    print(f"ovrad_demo: using {getattr(module, '__name__', 'ovrad')} from {os.path.dirname(module.__file__)}")
    scene = bpy.context.scene
    if args.patch_count:
        scene.ovrad.patch_count = args.patch_count
        scene.ovrad.size_mode = "COUNT"
    if args.beta:
        scene.ovrad.beta = args.beta
    scene.ovrad.display_quantity = args.display
    sources = receivers()
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in sources)
    bpy.context.view_layer.objects.active = sources[0] if sources else None
    start = time.perf_counter()
    try:
        bpy.ops.ovrad.generate_atlas()
    except RuntimeError as e:  # the operator's error report (no mesh, too many patches, ...)
        print(f"ovrad_demo: {e}".strip(), file=sys.stderr)
        return 1
    seconds = time.perf_counter() - start
    atlases = [o for o in scene.objects if "ovrad_source" in o]
    patches = sum(len(o.data.vertices) for o in atlases)
    os.makedirs(os.path.dirname(output), exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=output, copy=True)
    rendered = ""
    if args.picture:
        os.makedirs(os.path.dirname(os.path.abspath(args.picture)), exist_ok=True)
        took = render(args.picture, atlases, args.samples, args.resolution)
        rendered = f", picture {took:.1f} s -> {args.picture}"
    print(
        f"ovrad demo: {patches} patches on {len(atlases)} objects in {seconds:.2f} s "
        f"(beta {scene.ovrad.beta}) -> {args.output}{rendered}"
    )
    return 0


if __name__ == "__main__":
    code = main()
    if code:
        sys.exit(code)
