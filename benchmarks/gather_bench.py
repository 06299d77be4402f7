"""Final gather (ovrad_addon/gather.py) on the Cornell box: error and time per gather ray count.

Run:
    scripts/blender -b --python-exit-code 1 -P benchmarks/gather_bench.py -- [--rays 0 64 128 256]

One atlas (default settings unless --count), one prepare and one solve; then the vertices are baked
(direct light at the vertices) with each gather ray count, 0 being the reconstruction from the
patches. Scored by relative RMS against the stored reference (benchmarks/reference/cornell_4096.npz)
over every non-emitter vertex ("all": the floor under the blocks too, whose reference is ~0) and
over the reference's 'scored' mask (vertices something sees); per object as well. Writes
benchmarks/results/gather.csv (and the baked radiance per ray count, gather.npz).
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import make_reference  # noqa: E402  (benchmarks/ is not a package)
import speed_vs_error  # noqa: E402

import scenes  # noqa: E402


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="gather_bench.py", description=__doc__.split("\n")[0])
    p.add_argument("--rays", type=int, nargs="+", default=[0, 64, 128, 256])
    p.add_argument("--count", type=int, default=None, help="patch count (default: AtlasSettings')")
    a = p.parse_args(argv)
    ref = make_reference.load(HERE / "reference" / "cornell_4096.npz")
    scene = scenes.open_cornell(ref["meta"]["spacing_m"])
    receivers = scenes.receivers(scene)
    read = speed_vs_error.read_scene(scene, receivers, len(ref["positions"]))
    surfaces, lamps, read_s, points, tri, _ = read
    if np.abs(points - ref["positions"]).max() > 1e-5:
        raise SystemExit("gather_bench: vertices do not match the reference")
    speed_vs_error.ovrad_package()
    from ovrad.ovrad_addon import (
        AtlasSettings,
        BakeRequest,
        SolveSettings,
        build_atlas,
        direct_light,
        prepare,
        radiance_at,
        solve,
    )

    t = time.perf_counter()
    atlas = build_atlas(surfaces, AtlasSettings() if a.count is None else AtlasSettings(patch_count=a.count))
    problem = prepare(surfaces, atlas, SolveSettings())
    state = solve(problem, lamps, SolveSettings())
    base_s = read_s + time.perf_counter() - t
    masks = {"all": ~ref["emitter"].astype(bool), "scored": ref["scored"].astype(bool)}
    names = [str(n) for n in ref["object_names"]]
    rows, baked = [], {}
    for rays in a.rays:
        light = direct_light(problem, lamps, SolveSettings(gather_rays=rays))
        t = time.perf_counter()
        L = radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), points, tri, 1)
        bake_s = time.perf_counter() - t
        row = dict(patches=len(atlas), rays=rays, solve_s=round(base_s, 2), bake_s=round(bake_s, 2))
        for key, m in masks.items():
            row[key] = round(scenes.relative_rms(L, ref["radiance"], m), 5)
        for k, name in enumerate(names):
            m = masks["all"] & (ref["object"] == k)
            if m.any():
                row[name] = round(scenes.relative_rms(L, ref["radiance"], m), 5)
        rows.append(row)
        baked[f"rays_{rays}"] = L
        print("gather_bench:", row, flush=True)
    out = HERE / "results" / "gather.csv"
    out.parent.mkdir(exist_ok=True)
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    np.savez_compressed(out.with_suffix(".npz"), **baked)
    print(f"gather_bench: wrote {out} and the baked radiance, {out.with_suffix('.npz')}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []))
