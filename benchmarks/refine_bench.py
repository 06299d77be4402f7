"""Adaptive patches (ovrad_addon/refine.py) against uniform ones on the Cornell box, every vertex scored.

Run (a few minutes on 2 cores):
    scripts/blender -b --python-exit-code 1 -P benchmarks/refine_bench.py -- [--scene cornell|lamps]

For each atlas (a patch count, then 0-3 refinement passes) the solve is scored two ways against the
stored 4 096-sample Cycles reference: the paper's reconstruction from the patches alone (direct
light included: --direct patches) and the default bake (direct light at the vertices, 256-ray final
gather with the near field). Seconds cover generate, prepare (C and transport) and solve of every
pass, and the reconstruction. Writes benchmarks/results/refine[_<scene>].csv.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import make_reference  # noqa: E402  (benchmarks/ is not a package)
import speed_vs_error  # noqa: E402
from per_process import write_csv  # noqa: E402

import scenes  # noqa: E402

RUNS = [(1000, 0), (1000, 1), (1000, 2), (1000, 3), (2000, 0), (4000, 0)]


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="refine_bench.py", description=__doc__.split("\n")[0])
    p.add_argument("--scene", choices=("cornell", "lamps"), default="cornell")
    a = p.parse_args(argv)
    ref = make_reference.load(HERE / "reference" / f"{a.scene}_4096.npz")
    scene = scenes.open_cornell(ref["meta"]["spacing_m"], lamps=a.scene == "lamps")
    receivers = scenes.receivers(scene)
    *read, _ = speed_vs_error.read_scene(scene, receivers, len(ref["positions"]))
    surfaces, lamps, read_s, points, tri = read
    speed_vs_error.ovrad_package()
    engine = importlib.import_module("ovrad.ovrad_addon")
    rows = []
    for count, passes in RUNS:
        t = time.perf_counter()
        atlas = engine.build_atlas(surfaces, engine.AtlasSettings(patch_count=count))
        settings = engine.SolveSettings()
        problem, state, replaced = engine.solve_adaptive(surfaces, atlas, lamps, settings, passes=passes)
        solve_s = time.perf_counter() - t
        for direct in ("patches", "points"):
            t = time.perf_counter()
            if direct == "points":
                light = engine.direct_light(problem, lamps, settings)
                L = engine.radiance_at(
                    problem, engine.BakeRequest(state.radiosity, state.first_shot, light), points, tri, 1
                )
            else:
                L = engine.radiance_at(problem, engine.BakeRequest(state.radiosity), points, tri, 1)
            rec_s = time.perf_counter() - t
            err = scenes.relative_rms(L, ref["radiance"], ref["scored"])
            row = dict(
                scene=a.scene,
                patches=len(atlas),
                passes=passes,
                replaced=" ".join(map(str, replaced)),
                refined_patches=len(problem.atlas),
                direct=direct,
                seconds=round(read_s + solve_s + rec_s, 2),
                error=round(err, 5),
            )
            rows.append(row)
            print("refine_bench:", row, flush=True)
    out = HERE / "results" / ("refine.csv" if a.scene == "cornell" else f"refine_{a.scene}.csv")
    write_csv(rows, out, tag="refine_bench")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []))
