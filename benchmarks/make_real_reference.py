"""Converged Cycles vertex bakes of the real-scenes set (benchmarks/real_scenes.py), stored as npz.

Run (each scene about 5 000 vertices; a few minutes per scene at 2 048 samples on 2 cores):
    scripts/blender -b --python-exit-code 1 -P benchmarks/make_real_reference.py -- --scene contact
    scripts/blender -b --python-exit-code 1 -P benchmarks/make_real_reference.py -- --scene all

Cycles as in make_reference.py (DIFFUSE bake, direct + indirect + colour, 64 diffuse bounces, no
clamps, no denoising, no adaptive sampling), the world kept as the scene has it (the sky scenes
are lit by it). Meshes shared by several objects (linked duplicates) are made single-user for the
bake only, so each object gets its own light. EVERY vertex of every baked mesh is stored and scored
(under resting objects, on edges and rims too); emitters are not baked (see real_scenes.py).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import real_scenes  # noqa: E402  (benchmarks/ is not a package)
import scenes  # noqa: E402

OUT = Path(__file__).resolve().parent / "reference" / "real"


def make(name: str, samples: int, seeds: int, folder: Path) -> dict:
    scene = real_scenes.build(name, folder / f"{name}.blend")
    objects = real_scenes.baked_meshes(scene)
    for obj in objects:
        if obj.data.users > 1:
            obj.data = obj.data.copy()
    positions, owner = real_scenes.vertex_positions(objects)
    per_seed = samples // seeds
    runs, seconds = [], []
    for seed in range(1, seeds + 1):
        values, took = scenes.cycles_vertex_bake(objects, per_seed, seed=seed, keep_world=True)
        runs.append(values)
        seconds.append(took)
        print(f"make_real_reference: {name} seed {seed}: {per_seed} samples in {took:.1f} s", flush=True)
    runs = np.stack(runs)
    radiance = runs.mean(axis=0)
    noise = float("nan")
    if seeds > 1:
        spread = np.sqrt(np.sum(runs.var(axis=0, ddof=1)) / np.sum(radiance**2))
        noise = float(spread / np.sqrt(seeds))
    meta = {
        "scene": name,
        "samples": per_seed * seeds,
        "seeds": list(range(1, seeds + 1)),
        "diffuse_bounces": 64,
        "bake_seconds": [round(s, 1) for s in seconds],
        "relative_rms_noise": round(noise, 5),
        "vertices": int(len(radiance)),
        "blender": bpy.app.version_string,
    }
    return {
        "positions": positions.astype(np.float32),
        "object": owner.astype(np.int16),
        "object_names": np.array([o.name for o in objects]),
        "radiance": radiance.astype(np.float32),
        "meta": np.array(json.dumps(meta)),
    }


def load(name: str) -> dict:
    """A stored reference of the real-scenes set: arrays (radiance float64) and 'meta' as a dict
    (a scene of real_scenes.REFERENCE_OF: the other scene's)."""
    with np.load(OUT / f"{real_scenes.REFERENCE_OF.get(name, name)}.npz") as z:
        out = {k: z[k] for k in z.files}
    out["radiance"] = out["radiance"].astype(np.float64)
    out["meta"] = json.loads(str(out["meta"]))
    return out


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="make_real_reference.py", description=__doc__.split("\n")[0])
    own = [n for n in real_scenes.SCENES if n not in real_scenes.REFERENCE_OF]  # the others share one
    p.add_argument("--scene", choices=(*own, "all"), required=True)
    p.add_argument("--samples", type=int, default=2048, help="total samples over all seeds")
    p.add_argument("--seeds", type=int, default=2, help="independent runs the samples are split over")
    a = p.parse_args(argv)
    names = own if a.scene == "all" else [a.scene]
    OUT.mkdir(parents=True, exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix="ovrad-real-"))
    for name in names:
        start = time.perf_counter()
        data = make(name, a.samples, a.seeds, folder)
        out = OUT / f"{name}.npz"
        np.savez_compressed(out, **data)
        meta = json.loads(str(data["meta"]))
        print(
            f"make_real_reference: {out} ({out.stat().st_size // 1024} KiB): {meta['vertices']} vertices, "
            f"{meta['samples']} samples, noise {meta['relative_rms_noise']:.4f}, "
            f"{time.perf_counter() - start:.0f} s",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    sys.exit(main(argv))
