"""A converged Cycles vertex bake of the production room (scripts/make_production_scene.py), as npz.

Run (slow: about an hour at 2 048 samples on 2 cores; `nice` it to keep working beside it):
    scripts/blender -b --python-exit-code 1 -P benchmarks/make_production_reference.py -- \
        [--samples 2048] [--seeds 2]

Cycles as in make_real_reference.py (DIFFUSE bake, direct + indirect + colour, 64 diffuse bounces,
no clamps, no denoising, no adaptive sampling). Baked and scored: every vertex of every mesh the
batch bakes, the BoomBox, Suzanne's eyes inside her head, the leaves' undersides and the zero-area
triangles' vertices included; only the emitting quad is left out (real_scenes.baked_meshes).
The room is built by its own script, so the reference and the benchmark bake the same file.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import real_scenes  # noqa: E402  (benchmarks/ is not a package)
import scenes  # noqa: E402

ROOT = HERE.parent
OUT = HERE / "reference" / "real" / "production.npz"


def build(folder: Path) -> Path:
    """The production room's .blend, from its script in a separate Blender process."""
    blend = folder / "production.blend"
    cmd = [str(ROOT / "scripts" / "blender"), "-b", "--python-exit-code", "1", "-P"]
    cmd += [str(ROOT / "scripts" / "make_production_scene.py"), "--", "--output", str(blend)]
    subprocess.run(cmd, check=True, capture_output=True)
    return blend


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="make_production_reference.py", description=__doc__.split("\n")[0])
    p.add_argument("--samples", type=int, default=2048, help="total samples over all seeds")
    p.add_argument("--seeds", type=int, default=2, help="independent runs the samples are split over")
    p.add_argument("--output", type=Path, default=OUT)
    a = p.parse_args(argv)
    start = time.perf_counter()
    blend = build(Path(tempfile.mkdtemp(prefix="ovrad-production-")))
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    objects = real_scenes.baked_meshes(scene)
    positions, owner = real_scenes.vertex_positions(objects)
    per_seed = a.samples // a.seeds
    runs, seconds = [], []
    for seed in range(1, a.seeds + 1):
        values, took = scenes.cycles_vertex_bake(objects, per_seed, seed=seed, keep_world=False)
        runs.append(values)
        seconds.append(took)
        print(f"make_production_reference: seed {seed}: {per_seed} samples in {took:.1f} s", flush=True)
    runs = np.stack(runs)
    radiance = runs.mean(axis=0)
    noise = float("nan")
    if a.seeds > 1:
        noise = float(np.sqrt(np.sum(runs.var(axis=0, ddof=1)) / np.sum(radiance**2)) / np.sqrt(a.seeds))
    meta = {
        "scene": "production",
        "samples": per_seed * a.seeds,
        "seeds": list(range(1, a.seeds + 1)),
        "diffuse_bounces": 64,
        "bake_seconds": [round(s, 1) for s in seconds],
        "relative_rms_noise": round(noise, 5),
        "vertices": int(len(radiance)),
        "blender": bpy.app.version_string,
    }
    a.output.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        a.output,
        positions=positions.astype(np.float32),
        object=owner.astype(np.int16),
        object_names=np.array([o.name for o in objects]),
        radiance=radiance.astype(np.float32),
        meta=np.array(json.dumps(meta)),
    )
    print(
        f"make_production_reference: {a.output}: {meta['vertices']} vertices, {meta['samples']} samples, "
        f"noise {noise:.4f}, {time.perf_counter() - start:.0f} s",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    sys.exit(main(argv))
