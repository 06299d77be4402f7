"""Benchmark: ray throughput of the transport and solve time, error and memory on the Cornell box.

Run: .venv/bin/python benchmarks/transport_bench.py [--sizes 1600 6400 25000] [--beta box]
Each size runs in its own process so peak memory (max RSS) is that size's alone. Per size:
- raw embreex closest-hit rays/s on the same geometry and the same kind of rays (cosine
  directions from the receiver points, in the transport's batch size), and the transport's
  effective rays/s (all of gather_transport: directions, casts, alpha at the hits, summing G);
- atlas, overlap (C) and transport seconds; solve seconds to 1e-3 unshot;
- the reconstructed radiance at 20 000 surface points against the same problem solved to 1e-7
  (the converged reference of equation (9)): relative RMS error of stopping at 1e-3;
- peak RSS.
Writes benchmarks/results/transport.csv and prints a table.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import per_process  # noqa: E402  (benchmarks/ is not a package)

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "transport.csv"


def one(count: int, beta: str) -> dict:
    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    import numpy as np

    import scenes
    from ovrad_addon.atlas import build_atlas
    from ovrad_addon.pipeline import SolveSettings, prepare, radiance_at, solve
    from ovrad_addon.settings import AtlasSettings
    from ovrad_addon.transport import cosine_directions

    s = scenes.cornell()
    t0 = time.perf_counter()
    atlas = build_atlas(s, AtlasSettings(patch_count=count, beta=beta))
    t_atlas = time.perf_counter() - t0
    settings = SolveSettings()
    problem = prepare(s, atlas, settings)
    T = problem.transport
    # raw embree on the same rays: one batch the size the transport uses
    rp = T.points
    rng = np.random.default_rng(0)
    m = min(len(rp.owner), (1 << 20) // settings.rays_per_point)
    dirs = cosine_directions(rp.normals[:m], settings.rays_per_point, rng).reshape(-1, 3)
    origins = np.repeat(rp.points[:m] + 1e-6 * s.extent * rp.normals[:m], settings.rays_per_point, axis=0)
    problem.index.rays.closest_hit(origins, dirs, np.inf)  # warm-up
    t = time.perf_counter()
    reps = 3
    for _ in range(reps):
        problem.index.rays.closest_hit(origins, dirs, np.inf)
    raw = reps * len(dirs) / (time.perf_counter() - t)
    effective = T.rays / problem.seconds["transport"]
    t = time.perf_counter()
    state = solve(problem, (), settings)
    t_solve = time.perf_counter() - t
    converged = solve(problem, (), SolveSettings(tolerance=1e-7))
    pts, tri = scenes.sample_surface(s, 20000, seed=3)
    recv = s.receiver[s.object_index[tri]]
    pts, tri = pts[recv], tri[recv]
    L = radiance_at(problem, state.radiosity, pts, tri, 1)
    L_ref = radiance_at(problem, converged.radiosity, pts, tri, 1)
    err = float(np.sqrt(np.sum((L - L_ref) ** 2) / np.sum(L_ref**2)))
    return {
        "target": count,
        "beta": beta,
        "patches": len(atlas),
        "raw_rays_per_s": round(raw),
        "transport_rays_per_s": round(effective),
        "ratio": round(effective / raw, 3),
        "atlas_s": round(t_atlas, 2),
        "overlap_s": round(problem.seconds["overlap"], 2),
        "transport_s": round(problem.seconds["transport"], 2),
        "solve_s": round(t_solve, 2),
        "total_s": round(t_atlas + sum(problem.seconds.values()) + t_solve, 2),
        "transport_rays": T.rays,
        "G_entries": int(T.geometric.nnz),
        "solve_method": state.method,
        "error_vs_converged": f"{err:.2e}",
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1600, 6400, 25000])
    ap.add_argument("--beta", default="box")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one, a.beta)))
        return
    rows = per_process.run_sizes(
        __file__, a.sizes, ["--beta", a.beta], lambda r: " ".join(f"{k}={v}" for k, v in r.items())
    )
    per_process.write_csv(rows, OUT)


if __name__ == "__main__":
    main()
