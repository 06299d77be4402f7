"""Benchmark: ray throughput of the transport, and time and memory of every stage against patch count.

Run: .venv/bin/python benchmarks/transport_bench.py [--scene cornell|interior]
         [--sizes 1600 6400 25000 100000] [--beta box] [--name transport]
Each size runs in its own process, so its memory is its own. Scenes: the Cornell box (engine
arrays, tests/scenes.py), or the large interior of benchmarks/large_interior.py (16 furnished rooms,
~1 M triangles) for 10^5-10^6 patches. Per size:
- raw embreex closest-hit rays/s on the same geometry and the same kind of rays (cosine
  directions from the receiver points, in the transport's batch size), and the transport's
  effective rays/s (all of gather_transport: directions, casts, alpha at the hits, summing G);
- seconds of the atlas (placement and C, which the solve then reuses as Generate keeps it), the
  transport, the solve to 1e-3 unshot, and a bake of 20 000 surface points (final gather), and the
  peak resident memory of each (memory.py);
- the reconstructed radiance at those points against the same solve continued to 1e-7
  (the converged reference of equation (9)): relative RMS error of stopping at 1e-3.
Writes benchmarks/results/<name>.csv and <name>.png (log-log: seconds and peak memory against
patches) and prints a table.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import per_process  # noqa: E402  (benchmarks/ is not a package)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def one(count: int, beta: str, scene: str) -> dict:
    sys.path[:0] = [str(ROOT), str(ROOT / "tests"), str(ROOT / "benchmarks")]
    import numpy as np

    import scenes
    from ovrad_addon import (
        AtlasSettings,
        BakeRequest,
        SolveSettings,
        StagePeaks,
        build_atlas_and_overlaps,
        cosine_directions,
        direct_light,
        keep,
        prepare,
        radiance_at,
        solve,
    )

    peaks = StagePeaks()
    if scene == "interior":
        import large_interior

        s = large_interior.large_interior()
    else:
        s = scenes.cornell()
    t0 = time.perf_counter()
    st = AtlasSettings(patch_count=count, beta=beta, max_patches=4_000_000)
    with peaks.stage("atlas"):
        atlas, C, q, _ = build_atlas_and_overlaps(s, st)
    t_atlas = time.perf_counter() - t0
    settings = SolveSettings()
    with peaks.stage("prepare"):
        # C as Generate keeps it with the atlas: the solve uses it instead of integrating it again
        problem = prepare(s, atlas, settings, kept=[keep(s, atlas, C, q, st.crease_angle)])
    assert problem.kept == len(atlas)
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
    with peaks.stage("solve"):
        state = solve(problem, (), settings)
    t_solve = time.perf_counter() - t
    # the reference: the same solve continued to 1e-7 (its first shot, the direct light at every
    # receiver point, is not computed a second time)
    converged = solve(problem, (), SolveSettings(tolerance=1e-7), state=copy.deepcopy(state))
    pts, tri = scenes.sample_surface(s, 20000, seed=3)
    recv = s.receiver[s.object_index[tri]]
    pts, tri = pts[recv], tri[recv]
    L = radiance_at(problem, BakeRequest(state.radiosity), pts, tri, 1)
    L_ref = radiance_at(problem, BakeRequest(converged.radiosity), pts, tri, 1)
    err = float(np.sqrt(np.sum((L - L_ref) ** 2) / np.sum(L_ref**2)))
    light = direct_light(problem, (), settings)
    t = time.perf_counter()
    with peaks.stage("bake"):
        radiance_at(problem, BakeRequest(state.radiosity, state.first_shot, light), pts, tri, 1)
    t_bake = time.perf_counter() - t
    mb = peaks.mb | {f"prepare_{k}": v for k, v in problem.memory.items()}
    return {
        "scene": scene,
        "target": count,
        "beta": beta,
        "triangles": len(s.triangles),
        "patches": len(atlas),
        "raw_rays_per_s": round(raw),
        "transport_rays_per_s": round(effective),
        "ratio": round(effective / raw, 3),
        "atlas_s": round(t_atlas, 2),
        "transport_s": round(problem.seconds["transport"], 2),
        "solve_s": round(t_solve, 2),
        "bake_20k_s": round(t_bake, 2),
        "total_s": round(t_atlas + sum(problem.seconds.values()) + t_solve + t_bake, 2),
        "transport_rays": T.rays,
        "G_entries": T.entries,  # near G, and the cluster links and their weights
        "C_entries": int(problem.C.nnz),
        "steps": len(state.history) - 1,
        "error_vs_converged": f"{err:.2e}",
        "atlas_mb": mb.get("atlas"),
        "transport_mb": mb.get("prepare_transport"),
        "solve_mb": mb.get("solve"),
        "bake_mb": mb.get("bake"),
        "peak_mb": max(v for v in mb.values()),
    }


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["patches"] for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for key, label in (("atlas_s", "atlas (C)"), ("transport_s", "transport"), ("solve_s", "solve")):
        axes[0].loglog(n, [max(r[key], 1e-2) for r in rows], "o-", label=label)
    axes[0].loglog(n, [r["total_s"] for r in rows], "k.-", label="total (with a 20 k-point bake)")
    for key, label in (("atlas_mb", "atlas"), ("transport_mb", "transport"), ("solve_mb", "solve")):
        axes[1].loglog(n, [r[key] for r in rows], "o-", label=label)
    axes[0].set(xlabel="patches", ylabel="seconds", title=f"time ({rows[0]['scene']}, 2 cores)")
    axes[1].set(xlabel="patches", ylabel="peak resident memory (MiB)", title="memory per stage")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1600, 6400, 25000, 100000])
    ap.add_argument("--beta", default="box")
    ap.add_argument("--scene", choices=("cornell", "interior"), default="cornell")
    ap.add_argument("--name", default="transport", help="results file name without .csv")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one, a.beta, a.scene)))
        return
    rows = per_process.run_sizes(
        __file__,
        a.sizes,
        ["--beta", a.beta, "--scene", a.scene],
        lambda r: " ".join(f"{k}={v}" for k, v in r.items()),
    )
    out = RESULTS / f"{a.name}.csv"
    per_process.write_csv(rows, out)
    plot(rows, out.with_suffix(".png"))


if __name__ == "__main__":
    main()
