"""Speed against error: ovrad (patch counts x beta x solver) and Cycles DIFFUSE vertex bakes, one run.

Run (about 15 minutes on 2 cores):
    scripts/blender -b --python-exit-code 1 -P benchmarks/speed_vs_error.py -- [--scene cornell]

Both bake the same vertices (benchmarks/scenes.py: scenes/cornell.blend with receivers subdivided)
and are scored by relative RMS error against the stored converged reference
(benchmarks/reference/<scene>_4096.npz, make_reference.py): "error" over the reference's 'scored'
vertices (those something sees), "all" over every receiving vertex but the emitters' (the floor
under the blocks and the blocks' bottoms too, whose reference is ~0: a leak shows there). ovrad's
bake points get the final gather (--gather rays per vertex, 0: indirect light from the patches,
as in the paper) when their direct light is computed at the vertices. ovrad is timed over what a
user waits for: reading the scene, generating the atlas, prepare (C and form factors), solve, and
reconstruction at the vertices; exact and paper solvers
share one atlas and prepare, whose measured times count in full for both. Cycles is timed over
the bake call. Writes benchmarks/results/speed_vs_error.csv and .png (log-log), or
speed_vs_error_<scene>.csv / .png for another scene.

With --quality, only ovrad's quality levels are run (operators/properties.QUALITY: patch count,
gather rays, min_rays; smooth beta, exact solver, direct at the vertices), to
benchmarks/results/quality.csv (or quality_<scene>.csv).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import sys
import time
from dataclasses import replace
from pathlib import Path

import bpy
import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import make_reference  # noqa: E402  (benchmarks/ is not a package)

import scenes  # noqa: E402

RESULTS = HERE / "results"
FIELDS = [
    "method",
    "beta",
    "solver",
    "direct",
    "patches",
    "samples",
    "seconds",
    "error",
    "read_s",
    "generate_s",
]
FIELDS += ["prepare_s", "solve_s", "reconstruct_s", "rays", "unshot", "gather", "min_rays", "all", "quality"]


def ovrad_package():
    """The checkout as the package 'ovrad' (imported, not registered: only its engine and scene_io)."""
    if "ovrad" not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            "ovrad", ROOT / "__init__.py", submodule_search_locations=[str(ROOT)]
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules["ovrad"] = module
        spec.loader.exec_module(module)
    return sys.modules["ovrad"]


def vertex_triangles(surfaces, n_vertices: int) -> np.ndarray:
    """A triangle using each of the first n_vertices surface vertices (each lies on one face)."""
    tri_of = np.full(len(surfaces.vertices), -1, np.int64)
    for k in range(3):
        tri_of[surfaces.triangles[:, k]] = np.arange(len(surfaces.triangles))
    return tri_of[:n_vertices]


def run_ovrad(read, ref, counts, betas, solvers, rows, gathers=(256,), min_rays=None, quality="") -> None:
    from ovrad.ovrad_addon.atlas import build_atlas
    from ovrad.ovrad_addon.pipeline import SolveSettings, direct_light, prepare, radiance_at, solve
    from ovrad.ovrad_addon.settings import AtlasSettings

    surfaces, lamps, read_s, points, tri = read
    mask = ref["scored"]
    everything = ~ref["emitter"].astype(bool)
    base = SolveSettings() if min_rays is None else SolveSettings(min_rays=min_rays)
    for count in counts:
        for beta in betas:
            t = time.perf_counter()
            atlas = build_atlas(surfaces, AtlasSettings(patch_count=count, beta=beta))
            gen_s = time.perf_counter() - t
            t = time.perf_counter()
            problem = prepare(surfaces, atlas, base)
            prep_s = time.perf_counter() - t
            for rule in solvers:
                t = time.perf_counter()
                state = solve(problem, lamps, replace(base, rule=rule))
                solve_s = time.perf_counter() - t
                runs = [("points", g) for g in gathers] + ([] if quality else [("patches", 0)])
                for direct, gather in runs:
                    t = time.perf_counter()
                    if direct == "points":
                        light = direct_light(problem, lamps, replace(base, gather_rays=gather))
                        L = radiance_at(problem, state.radiosity, points, tri, 1, state.first_shot, light)
                    else:
                        L = radiance_at(problem, state.radiosity, points, tri, 1)
                    rec_s = time.perf_counter() - t
                    total = read_s + gen_s + prep_s + solve_s + rec_s
                    err = scenes.relative_rms(L, ref["radiance"], mask)
                    err_all = scenes.relative_rms(L, ref["radiance"], everything)
                    unshot = state.history[-1][1] if state.history else 0.0
                    rows.append(
                        dict(
                            method="ovrad",
                            beta=beta,
                            solver=rule,
                            direct=direct,
                            patches=len(atlas),
                            samples="",
                            seconds=round(total, 3),
                            error=round(err, 5),
                            read_s=round(read_s, 3),
                            generate_s=round(gen_s, 3),
                            prepare_s=round(prep_s, 3),
                            solve_s=round(solve_s, 3),
                            reconstruct_s=round(rec_s, 3),
                            rays=state.rays,
                            unshot=f"{unshot:.2e}",
                            gather=gather,
                            min_rays=base.min_rays,
                            all=round(err_all, 5),
                            quality=quality,
                        )
                    )
                    print(
                        f"speed_vs_error: ovrad {quality} {len(atlas):6d} {beta:6s} {rule:5s} direct at "
                        f"{direct:7s} gather {gather:4d} {total:7.2f} s  err {err:.4f} all {err_all:.4f}",
                        flush=True,
                    )


def run_cycles(objects, ref, samples_list, rows) -> None:
    n = sum(len(o.data.vertices) for o in objects)
    mask = ref["scored"][:n]
    for samples in samples_list:
        values, seconds = scenes.cycles_vertex_bake(objects, samples, seed=0)
        err = scenes.relative_rms(values, ref["radiance"][:n], mask)
        rows.append(
            dict(method="cycles", beta="", solver="", direct="", patches="", samples=samples)
            | dict(seconds=round(seconds, 3), error=round(err, 5))
        )
        print(f"speed_vs_error: cycles {samples:5d} samples {seconds:7.2f} s  err {err:.4f}")


def read_scene(scene, receivers, n_vertices: int):
    """The scene as ovrad reads it (every rendered mesh receives, the baked ones first; lamps), timed;
    the points and triangles of the first n_vertices vertices."""
    pkg = ovrad_package()
    scene_io = pkg.operators.scene_io
    t = time.perf_counter()
    meshes = receivers + [
        o for o in scene.objects if o.type == "MESH" and not o.hide_render and o not in receivers
    ]
    depsgraph = bpy.context.evaluated_depsgraph_get()
    read = scene_io.read_scene(depsgraph, meshes)
    lamps = scene_io.read_lamps(depsgraph) if hasattr(scene_io, "read_lamps") else ()
    read_s = time.perf_counter() - t
    s = read.surfaces
    return s, lamps, read_s, s.vertices[:n_vertices], vertex_triangles(s, n_vertices), meshes


def plot(rows, path: Path, title: str, noise: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    cyc = [r for r in rows if r["method"] == "cycles"]
    ax.plot([r["seconds"] for r in cyc], [r["error"] for r in cyc], "k-o", label="Cycles DIFFUSE bake")
    for r in cyc:
        ax.annotate(
            f"{r['samples']} spp",
            (r["seconds"], r["error"]),
            fontsize=7,
            xytext=(4, 2),
            textcoords="offset points",
        )
    styles = {
        ("smooth", "exact", "points"): ("C0-s", "smooth beta, exact solver, direct at vertices"),
        ("box", "exact", "points"): ("C1-^", "box beta, exact solver, direct at vertices"),
        ("box", "paper", "points"): ("C2-.v", "box beta, paper's rule, direct at vertices"),
        ("smooth", "exact", "patches"): ("C0--x", "smooth beta, exact solver, all from patches"),
        ("box", "exact", "patches"): ("C1--x", "box beta, exact solver, all from patches"),
    }
    for key, (style, label) in styles.items():
        pts = sorted(
            (r["seconds"], r["error"])
            for r in rows
            if r["method"] == "ovrad" and (r["beta"], r["solver"], r["direct"]) == key
        )
        if pts:
            ax.plot([p[0] for p in pts], [p[1] for p in pts], style, label=f"ovrad {label}")
    if cyc:
        ax.plot(
            [r["seconds"] for r in cyc],
            [r["error"] / 3 for r in cyc],
            color="grey",
            ls="--",
            lw=0.8,
            label="goal: 1/3 of Cycles' error",
        )
    if np.isfinite(noise):
        ax.axhline(noise, color="grey", lw=0.8, ls=":", label=f"reference noise ({noise:.3f})")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time of the whole bake (s)")
    ax.set_ylabel("relative RMS error vs 4096-spp reference")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def run_quality(read, ref, levels, scene: str, rows) -> int:
    """The quality levels of the panel and the batch (smooth beta, exact solver, direct at vertices)."""
    quality = ovrad_package().operators.properties.QUALITY
    for level in levels or list(quality):
        q = quality[level.upper()]
        run_ovrad(
            read,
            ref,
            [q["patch_count"]],
            ["smooth"],
            ["exact"],
            rows,
            [q["gather_rays"]],
            q["min_rays"],
            level.upper(),
        )
    out = RESULTS / ("quality.csv" if scene == "cornell" else f"quality_{scene}.csv")
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, FIELDS)
        w.writeheader()
        w.writerows(rows)
    print(f"speed_vs_error: wrote {out}")
    return 0


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="speed_vs_error.py", description=__doc__.split("\n")[0])
    p.add_argument("--scene", choices=("cornell", "lamps"), default="cornell")
    p.add_argument("--counts", type=int, nargs="+", default=[500, 1500, 4000, 10000])
    p.add_argument("--betas", nargs="+", default=["box", "smooth"])
    p.add_argument("--solvers", nargs="+", default=["exact", "paper"])
    p.add_argument("--samples", type=int, nargs="*", default=[16, 64, 256, 1024])
    p.add_argument("--gather", type=int, nargs="+", default=[256], help="final-gather rays (0: off)")
    p.add_argument("--min-rays", type=int, help="transport rays at least (default: SolveSettings')")
    p.add_argument("--quality", nargs="*", help="run these quality levels only (none listed: all)")
    p.add_argument("--name", help="results file name without .csv (default: speed_vs_error[_<scene>])")
    p.add_argument("--reference", help="npz (default benchmarks/reference/<scene>_4096.npz)")
    a = p.parse_args(argv)
    ref = make_reference.load(
        Path(a.reference) if a.reference else HERE / "reference" / f"{a.scene}_4096.npz"
    )
    scene = scenes.open_cornell(ref["meta"]["spacing_m"], lamps=a.scene == "lamps")
    receivers = scenes.receivers(scene)
    table = scenes.vertex_table(receivers)
    n = len(table["positions"])
    # Cycles bakes the receivers (not the emitter); ovrad reads every mesh, receivers first in the same order.
    *read, _ = read_scene(scene, receivers, len(ref["positions"]))
    gap = np.abs(read[3] - ref["positions"]).max()
    if gap > 1e-5 or np.abs(table["positions"] - ref["positions"][:n]).max() > 1e-5:
        raise SystemExit(f"speed_vs_error: vertices do not match the reference (off by {gap:.2e})")
    rows: list[dict] = []
    RESULTS.mkdir(exist_ok=True)
    if a.quality is not None:
        return run_quality(read, ref, a.quality, a.scene, rows)
    run_cycles(receivers, ref, a.samples, rows)
    run_ovrad(read, ref, a.counts, a.betas, a.solvers, rows, a.gather, a.min_rays)
    out = RESULTS / ("speed_vs_error.csv" if a.scene == "cornell" else f"speed_vs_error_{a.scene}.csv")
    if a.name:
        out = RESULTS / f"{a.name}.csv"
    with open(out, "w", newline="") as fh:
        w = csv.DictWriter(fh, FIELDS)
        w.writeheader()
        w.writerows(rows)
    meta = ref["meta"]
    title = f"{a.scene}: {int(ref['scored'].sum())} vertices, reference {meta['samples']} spp"
    plot(rows, out.with_suffix(".png"), title, meta.get("relative_rms_noise", float("nan")))
    print(f"speed_vs_error: wrote {out} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []))
