"""Converged Cycles DIFFUSE vertex bakes of the benchmark scenes, stored compactly as npz (float32).

Run (slow: about 7 minutes per 4 096 samples for 8 500 vertices on 2 cores):
    scripts/blender -b --python-exit-code 1 -P benchmarks/make_reference.py -- --scene cornell
    scripts/blender -b --python-exit-code 1 -P benchmarks/make_reference.py -- --scene lamps

The scene is scenes/cornell.blend with its receivers subdivided (benchmarks/scenes.py, the same
geometry the speed/error benchmark scores). Cycles: DIFFUSE bake with direct + indirect + colour
(outgoing diffuse radiance rho E / pi), to a POINT FLOAT_COLOR attribute, 64 diffuse bounces,
clamps 0, denoising and adaptive sampling off, world black. The samples are split over
`--seeds` independent runs (fixed seeds 1, 2, ...) that are averaged: the same estimator as one
run of all the samples, and the spread between runs measures the noise left in the reference.
Emitters are not baked; their vertices get their emission radiance and are flagged `emitter`.
Scored are all other vertices but those nothing sees (block bottoms, the floor under the blocks).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import bpy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import scenes  # noqa: E402  (benchmarks/ is not a package)

OUT = Path(__file__).resolve().parent / "reference"


def emitter_table(scene) -> tuple[dict, np.ndarray] | None:
    """Vertices of the emitting Light quad and its emission radiance (colour x strength)."""
    if scene.objects.get(scenes.EMITTER) is None or scene.objects[scenes.EMITTER] in scenes.receivers(scene):
        return None
    light = scene.objects[scenes.EMITTER]
    emit = next(n for n in light.data.materials[0].node_tree.nodes if n.bl_idname == "ShaderNodeEmission")
    radiance = np.array(emit.inputs["Color"].default_value[:3]) * emit.inputs["Strength"].default_value
    table = scenes.vertex_table([light])
    return table, np.tile(radiance, (len(table["positions"]), 1))


def make(scene_name: str, samples: int, seeds: int, spacing: float) -> dict:
    """Bake one scene; returns the arrays to store."""
    scene = scenes.open_cornell(spacing, lamps=scene_name == "lamps")
    objects = scenes.receivers(scene)
    table = scenes.vertex_table(objects)
    per_seed = samples // seeds
    runs, seconds = [], []
    for seed in range(1, seeds + 1):
        values, took = scenes.cycles_vertex_bake(objects, per_seed, seed=seed)
        runs.append(values)
        seconds.append(took)
        print(f"make_reference: {scene_name} seed {seed}: {per_seed} samples in {took:.1f} s", flush=True)
    runs = np.stack(runs)
    radiance = runs.mean(axis=0)
    mask = table["scored"]
    if seeds > 1:
        # The mean of k runs has 1/k of one run's variance; runs differ by sqrt(2) x one run's noise.
        spread = np.sqrt(np.sum(runs.var(axis=0, ddof=1)[mask]) / np.sum(radiance[mask] ** 2))
        noise = float(spread / np.sqrt(seeds))
    else:
        noise = float("nan")
    emitter = np.zeros(len(radiance), bool)
    extra = emitter_table(scene)
    if extra is not None:
        et, er = extra
        names = list(table["object_names"]) + list(et["object_names"])
        for key in ("positions", "normals", "scored"):
            table[key] = np.concatenate([table[key], et[key] if key != "scored" else np.zeros(len(er), bool)])
        table["object"] = np.concatenate([table["object"], et["object"] + len(table["object_names"])])
        table["object_names"] = np.array(names)
        radiance = np.concatenate([radiance, er])
        emitter = np.concatenate([emitter, np.ones(len(er), bool)])
    meta = {
        "scene": scene_name,
        "samples": per_seed * seeds,
        "seeds": list(range(1, seeds + 1)),
        "diffuse_bounces": 64,
        "clamps": 0,
        "spacing_m": spacing,
        "bake_seconds": [round(s, 1) for s in seconds],
        "relative_rms_noise": round(noise, 5),
        "vertices": int(len(radiance)),
        "blender": bpy.app.version_string,
    }
    return {
        "positions": table["positions"].astype(np.float32),
        "normals": table["normals"].astype(np.float32),
        "object": table["object"].astype(np.int16),
        "object_names": table["object_names"],
        "radiance": radiance.astype(np.float32),
        "emitter": emitter,
        "scored": table["scored"] & ~emitter,
        "meta": np.array(json.dumps(meta)),
    }


def load(path: Path) -> dict:
    """A stored reference: its arrays (radiance float64) and its metadata dict under 'meta'."""
    with np.load(path) as z:
        out = {k: z[k] for k in z.files}
    out["radiance"] = out["radiance"].astype(np.float64)
    out["meta"] = json.loads(str(out["meta"]))
    return out


def rescore(path: Path) -> None:
    """Recompute the 'scored' flags of a stored reference (same scene, no bake) and save it again."""
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    meta = json.loads(str(data["meta"]))
    scene = scenes.open_cornell(meta["spacing_m"], lamps=meta["scene"] == "lamps")
    table = scenes.vertex_table(scenes.receivers(scene))
    n = len(table["positions"])
    if np.abs(table["positions"] - data["positions"][:n]).max() > 1e-5:
        raise SystemExit(f"make_reference: {path} does not match the scene's vertices")
    data["scored"] = np.concatenate([table["scored"], np.zeros(len(data["scored"]) - n, bool)])
    data["scored"] &= ~data["emitter"]
    np.savez_compressed(path, **data)
    print(f"make_reference: {path}: {int(data['scored'].sum())} of {len(data['scored'])} vertices scored")


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="make_reference.py", description=__doc__.split("\n")[0])
    p.add_argument("--scene", choices=("cornell", "lamps"), default="cornell")
    p.add_argument("--samples", type=int, default=4096, help="total samples over all seeds")
    p.add_argument("--seeds", type=int, default=2, help="independent runs the samples are split over")
    p.add_argument("--spacing", type=float, default=scenes.SPACING, help="subdivision cell size (m)")
    p.add_argument("--output", help="npz path (default benchmarks/reference/<scene>_<samples>.npz)")
    p.add_argument("--rescore", help="only recompute which vertices are scored in this stored npz")
    a = p.parse_args(argv)
    if a.rescore:
        rescore(Path(a.rescore))
        return 0
    start = time.perf_counter()
    data = make(a.scene, a.samples, a.seeds, a.spacing)
    out = Path(a.output) if a.output else OUT / f"{a.scene}_{a.samples}.npz"
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, **data)
    meta = json.loads(str(data["meta"]))
    print(
        f"make_reference: {out} ({out.stat().st_size // 1024} KiB): {meta['vertices']} vertices, "
        f"{meta['samples']} samples, noise {meta['relative_rms_noise']:.4f}, "
        f"{time.perf_counter() - start:.0f} s"
    )
    return 0


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    sys.exit(main(argv))
