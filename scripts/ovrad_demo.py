"""The main job: bake the bundled Cornell box to vertex colours headless, render it, score it.

Usage: scripts/blender -b scenes/cornell.blend -P scripts/ovrad_demo.py -- \
           --output out/cornell_ovrad.blend --picture out/cornell_ovrad.png [batch options]

The receivers are subdivided first, as a user would for smooth vertex colours (the grid the
stored Cycles reference was baked on), then scripts/ovrad_batch.py generates the atlas, solves
and bakes. One line reports patches, wall time and the relative RMS error against the stored
4 096-sample Cycles reference, beside what Cycles' own bake reached in benchmarks/results.
Works with the extension installed or straight from a checkout.
"""

from __future__ import annotations

import csv
import importlib.util
import sys
from pathlib import Path

import bpy
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))
import make_reference  # noqa: E402  (benchmarks/ is not a package)

import scenes  # noqa: E402

REFERENCE = ROOT / "benchmarks" / "reference" / "cornell_4096.npz"
CYCLES_RESULTS = ROOT / "benchmarks" / "results" / "speed_vs_error.csv"
DEFAULTS = ["--patch-count", "1500", "--beta", "box"]


def batch_module():
    spec = importlib.util.spec_from_file_location("ovrad_batch", ROOT / "scripts" / "ovrad_batch.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def baked(objects, name: str) -> np.ndarray:
    """(V, 3) values of the POINT colour attribute `name` over the objects, in order."""
    out = []
    for obj in objects:
        attr = obj.data.color_attributes[name]
        a = np.empty(len(attr.data) * 4, np.float32)
        attr.data.foreach_get("color", a)
        out.append(a.reshape(-1, 4)[:, :3])
    return np.concatenate(out).astype(np.float64)


def cycles_at(seconds: float) -> str:
    """What Cycles' DIFFUSE bake reached in the stored benchmark, for comparison."""
    if not CYCLES_RESULTS.is_file():
        return ""
    with open(CYCLES_RESULTS, newline="") as fh:
        # The Cornell rows, scored over the vertices something sees as the demo scores itself.
        rows = sorted(
            (float(r["seconds"]), float(r.get("error_seen") or r["error"]), r["samples"])
            for r in csv.DictReader(fh)
            if r["method"] == "cycles" and r.get("scene", "cornell") == "cornell"
        )
    if not rows:
        return ""
    t, e, spp = min(rows, key=lambda r: abs(np.log(r[0] / seconds)))
    return f"; Cycles in benchmarks/results: {e:.3f} at {spp} spp ({t:.1f} s)"


def main() -> int:
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    batch = batch_module()
    try:
        args = batch.parse(DEFAULTS + argv)
        ref = make_reference.load(REFERENCE)
        scene = bpy.context.scene
        for obj in list(scene.objects):
            if obj.type == "MESH" and obj.name != scenes.EMITTER:
                scenes.subdivide(obj, ref["meta"]["spacing_m"])
        scored_objects = scenes.receivers(scene)
        table = scenes.vertex_table(scored_objects)
        n = len(table["positions"])  # the reference lists the emitter's vertices after these
        if n > len(ref["positions"]) or np.abs(table["positions"] - ref["positions"][:n]).max() > 1e-5:
            raise batch.BatchError(
                "the open file is not the bundled Cornell box: its reference does not apply"
            )
        report = batch.run(args)
    except batch.BatchError as e:
        print(f"ovrad demo: error: {e}", file=sys.stderr, flush=True)
        return 1
    values = baked(scored_objects, args.attribute)
    err = scenes.relative_rms(values, ref["radiance"][:n], ref["scored"][:n])
    s = report["seconds"]
    bake = s["generate"] + s["solve"] + s["bake"]
    picture = f" and {args.picture}" if args.picture else ""
    print(
        f"ovrad demo ({report['ovrad']}): {report['patches']} patches ({report['beta']} beta), "
        f"bake {bake:.2f} s "
        f"(atlas {s['generate']:.2f}, solve {s['solve']:.2f}, vertex colours {s['bake']:.2f}); "
        f"relative RMS error {err:.4f} against the Cycles 4096-spp reference over "
        f"{int(ref['scored'][:n].sum())} vertices{cycles_at(bake)} -> {report['output']}{picture}",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    batch_module().exit_on_failure(main)
