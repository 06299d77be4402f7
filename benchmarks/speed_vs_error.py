"""Speed against error: ovrad's quality levels and Cycles DIFFUSE vertex bakes on two scenes, one run.

Run (about 40 minutes on 2 cores):
    scripts/blender -b --python-exit-code 1 -P benchmarks/speed_vs_error.py -- \
        [--scene cornell lamps_doorway] [--quality draft medium high] [--samples 16 64 256 1024] [--sweep]

Scenes, each with its converged Cycles reference:
- cornell: scenes/cornell.blend with every receiver subdivided into 1.75 cm cells (benchmarks/scenes.py),
  lit by its emissive ceiling quad; benchmarks/reference/cornell_4096.npz (make_reference.py).
- lamps: the same box lit by a point and a spot lamp instead; benchmarks/reference/lamps_4096.npz.
- every scene of the real-scenes set (benchmarks/real_scenes.py), e.g. lamps_doorway: two rooms
  joined by a doorway, lit by a point, a spot, an area lamp and a sun through a window;
  benchmarks/reference/real/<scene>.npz (make_real_reference.py). `--scene real` runs them all.
- production: the production room (scripts/make_production_scene.py, 100 k triangles, 16
  receivers); benchmarks/reference/real/production.npz (make_production_reference.py).

Each scene is saved once to a temporary .blend that every bake opens afresh. ovrad bakes through
the batch command's own code (scripts/ovrad_batch.py, run in this process: `--input scene.blend
--output out.blend --quality LEVEL`, vertex colours, direct light at the vertices), timed over its
generate, solve and bake stages (reading the scene, the atlas, transport and solve, the vertex
values; not opening or saving the file). Cycles is timed over its bake call (seed 0; the
references use seeds 1 and up). Both are scored by relative RMS error at EVERY vertex of the baked
meshes but the emitters' ("error"); "error_seen" leaves out the vertices nothing sees (the Cornell
box's block bottoms and the floor under the blocks, whose reference is ~0; on lamps_doorway it
equals "error").

Then, in the same run, the engine's stages (transport, alpha at hits, the gather's lattice read)
in rays or hits per second against raw embree rays (benchmarks/hot_path_bench.py, --stages;
<name>_stages.csv).

--sweep adds ovrad bakes over --counts x --betas x --solvers (batch options --patch-count, --beta,
--solver; the file's other settings). Writes benchmarks/results/<name>.csv (one row per bake, a
`scene` column) and <name>.png (log-log, one panel per scene); <name> is speed_vs_error by default.
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import make_reference  # noqa: E402  (benchmarks/ is not a package)

import make_real_reference  # noqa: E402
import real_scenes  # noqa: E402
import scenes  # noqa: E402

RESULTS = HERE / "results"
SCENES = ("cornell", "lamps", *real_scenes.SCENES, "production")
FIELDS = [
    "scene",
    "method",
    "quality",
    "samples",
    "seconds",
    "error",
    "error_seen",
    "patches",
    "beta",
    "solver",
    "gather_rays",
    "min_rays",
    "rays",
    "generate_s",
    "solve_s",
    "bake_s",
]
LEVELS = ("draft", "medium", "high")


# --------------------------------------------------------------------------- helpers other benchmarks use


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


def read_scene(scene, receivers, n_vertices: int):
    """The scene as ovrad's engine reads it (every rendered mesh receives, the given ones first;
    lamps), timed; the points and triangles of the first n_vertices vertices (gather_bench.py)."""
    pkg = ovrad_package()
    scene_io = pkg.operators.scene_io
    t = time.perf_counter()
    meshes = receivers + [
        o for o in scene.objects if o.type == "MESH" and not o.hide_render and o not in receivers
    ]
    depsgraph = bpy.context.evaluated_depsgraph_get()
    read = scene_io.read_scene(depsgraph, meshes)
    # the lamps: scene_model reads them (older checkouts: scene_io, or nothing)
    lamp_reader = next(
        (m for m in (getattr(pkg.operators, "scene_model", None), scene_io) if hasattr(m, "read_lamps")), None
    )
    lamps = lamp_reader.read_lamps(depsgraph) if lamp_reader is not None else ()
    read_s = time.perf_counter() - t
    s = read.surfaces
    return s, lamps, read_s, s.vertices[:n_vertices], vertex_triangles(s, n_vertices), meshes


# --------------------------------------------------------------------------- scenes and scoring


class Scene:
    """A benchmark scene saved to a .blend, its reference and the masks it is scored over."""

    def __init__(self, name: str, folder: Path):
        self.name = name
        self.blend = folder / f"{name}.blend"
        if name == "production":
            import make_production_reference  # builds the room in a Blender process of its own

            self.ref = make_real_reference.load(name)
            self.blend = make_production_reference.build(folder)
            self.keep_world = False  # as its reference was made
        elif name in real_scenes.SCENES:
            self.ref = make_real_reference.load(name)
            real_scenes.build(name, self.blend)
            self.keep_world = True  # the reference keeps the (black) world as the scene has it
        else:
            self.ref = make_reference.load(HERE / "reference" / f"{name}_4096.npz")
            scenes.open_cornell(self.ref["meta"]["spacing_m"], lamps=name == "lamps")
            bpy.ops.wm.save_as_mainfile(filepath=str(self.blend), check_existing=False)
            self.keep_world = False
        n = len(self.ref["radiance"])
        emitter = self.ref.get("emitter", np.zeros(n, bool)).astype(bool)
        self.every = ~emitter
        self.seen = self.ref.get("scored", self.every).astype(bool) & self.every
        self.names = [str(s) for s in self.ref["object_names"]]
        # Cycles bakes the objects with a vertex to score (not the emitting quad).
        self.baked = [nm for k, nm in enumerate(self.names) if self.every[self.ref["object"] == k].any()]
        self.open()
        positions, _ = real_scenes.vertex_positions([bpy.context.scene.objects[nm] for nm in self.names])
        gap = np.abs(positions - self.ref["positions"]).max() if len(positions) == n else np.inf
        if gap > 1e-5:
            raise SystemExit(f"speed_vs_error: {name}: the vertices do not match the reference ({gap:.2e})")

    def open(self):
        bpy.ops.wm.open_mainfile(filepath=str(self.blend))
        return bpy.context.scene

    def score(self, attribute: str) -> tuple[float, float]:
        """Relative RMS error (every vertex, seen vertices) of a POINT colour attribute of the open file."""
        values, missing = real_scenes.baked_values(bpy.context.scene, self.names, attribute)
        # objects a bake skips with a warning (linked duplicates lit differently) are left out, as
        # real_scenes_bench.py leaves them out; any other vertex without a value is an error
        on = np.isin(self.ref["object"], [k for k, nm in enumerate(self.names) if nm not in missing])
        if not np.all(np.isfinite(values[self.every & on])):
            raise SystemExit(f"speed_vs_error: {self.name}: '{attribute}' is missing on scored vertices")
        unscored = [nm for nm in missing if self.every[self.ref["object"] == self.names.index(nm)].any()]
        if unscored:
            print(f"speed_vs_error: {self.name}: {attribute} not on {', '.join(unscored)}: left out")
        ref = self.ref["radiance"]
        every, seen = self.every & on, self.seen & on
        return scenes.relative_rms(values, ref, every), scenes.relative_rms(values, ref, seen)

    def noise(self) -> float:
        return float(self.ref["meta"].get("relative_rms_noise", float("nan")))


def run_cycles(sc: Scene, samples_list, rows) -> None:
    for samples in samples_list:
        scene = sc.open()
        objects = [scene.objects[nm] for nm in sc.baked]
        _, seconds = scenes.cycles_vertex_bake(objects, samples, seed=0, keep_world=sc.keep_world)
        err, seen = sc.score(scenes.BAKE_ATTRIBUTE)
        rows.append(
            dict(scene=sc.name, method="cycles", samples=samples, seconds=round(seconds, 3))
            | dict(error=round(err, 5), error_seen=round(seen, 5))
        )
        print(
            f"speed_vs_error: {sc.name} cycles {samples:5d} spp {seconds:8.2f} s  error {err:.4f}", flush=True
        )


def batch_module():
    """scripts/ovrad_batch.py as a module (its run() is the batch command without the process)."""
    if "ovrad_batch" not in sys.modules:
        spec = importlib.util.spec_from_file_location("ovrad_batch", ROOT / "scripts" / "ovrad_batch.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        sys.modules["ovrad_batch"] = module
    return sys.modules["ovrad_batch"]


def run_ovrad(sc: Scene, options: list[str], label: str, folder: Path, rows) -> None:
    """One batch bake of the scene's file with these batch options, timed and scored."""
    batch = batch_module()
    out, report = folder / f"{sc.name}_ovrad.blend", folder / f"{sc.name}_ovrad.json"
    args = ["--input", str(sc.blend), "--output", str(out), "--report", str(report), *options]
    try:
        rep = batch.run(batch.parse(args))
    except batch.BatchError as e:
        raise SystemExit(f"speed_vs_error: {sc.name}: ovrad {' '.join(options)}: {e}") from None
    s = rep["seconds"]
    seconds = s["generate"] + s["solve"] + s["bake"]
    err, seen = sc.score(rep["attribute"])
    rows.append(
        dict(scene=sc.name, method="ovrad", quality=label, seconds=round(seconds, 3))
        | dict(error=round(err, 5), error_seen=round(seen, 5), patches=rep["patches"])
        | dict(beta=rep["beta"], solver=rep["solver"], gather_rays=rep["gather_rays"])
        | dict(min_rays=rep["min_rays"], rays=rep["rays"], generate_s=s["generate"])
        | dict(solve_s=s["solve"], bake_s=s["bake"])
    )
    print(
        f"speed_vs_error: {sc.name} ovrad {label:24s} {rep['patches']:6d} patches {seconds:8.2f} s  "
        f"error {err:.4f}",
        flush=True,
    )


# --------------------------------------------------------------------------- plot


def plot(rows, scenes_run: list[Scene], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = min(4, len(scenes_run))
    rows_n = -(-len(scenes_run) // cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(6.5 * cols, 5 * rows_n), squeeze=False)
    for ax in axes.ravel()[len(scenes_run) :]:
        ax.set_visible(False)
    for ax, sc in zip(axes.ravel(), scenes_run, strict=False):
        mine = [r for r in rows if r["scene"] == sc.name]
        cyc = sorted((r for r in mine if r["method"] == "cycles"), key=lambda r: r["seconds"])
        if cyc:
            xs, ys = [r["seconds"] for r in cyc], [r["error"] for r in cyc]
            ax.plot(xs, ys, "k-o", label="Cycles DIFFUSE bake")
            ax.plot(xs, [y / 3 for y in ys], color="grey", ls="--", lw=0.8, label="1/3 of Cycles' error")
            for r in cyc:
                ax.annotate(
                    f"{r['samples']} spp",
                    (r["seconds"], r["error"]),
                    fontsize=7,
                    xytext=(4, 2),
                    textcoords="offset points",
                )
        levels = [r for r in mine if r["method"] == "ovrad" and r["quality"] in LEVELS]
        if levels:
            levels.sort(key=lambda r: LEVELS.index(r["quality"]))
            ax.plot(
                [r["seconds"] for r in levels],
                [r["error"] for r in levels],
                "C0-s",
                label="ovrad quality levels (batch --quality)",
            )
            for r in levels:
                ax.annotate(
                    r["quality"],
                    (r["seconds"], r["error"]),
                    fontsize=7,
                    xytext=(4, -9),
                    textcoords="offset points",
                    color="C0",
                )
        sweep = [r for r in mine if r["method"] == "ovrad" and r["quality"] not in LEVELS]
        for k, key in enumerate(sorted({(r["beta"], r["solver"]) for r in sweep})):
            pts = sorted(
                (r["patches"], r["seconds"], r["error"]) for r in sweep if (r["beta"], r["solver"]) == key
            )
            ax.plot(
                [p[1] for p in pts],
                [p[2] for p in pts],
                f"C{k + 1}-^",
                label=f"ovrad patch counts, {key[0]} beta, {key[1]} solver",
            )
        if np.isfinite(sc.noise()):
            ax.axhline(sc.noise(), color="grey", lw=0.8, ls=":", label=f"reference noise ({sc.noise():.3f})")
        meta = sc.ref["meta"]
        ax.set_title(
            f"{sc.name}: {int(sc.every.sum())} vertices, reference {meta['samples']} spp", fontsize=10
        )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time of the bake (s)")
        ax.set_ylabel("relative RMS error at every vertex")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


# --------------------------------------------------------------------------- main


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="speed_vs_error.py", description=__doc__.split("\n")[0])
    p.add_argument("--scene", nargs="+", choices=(*SCENES, "real"), default=["cornell", "lamps_doorway"])
    p.add_argument(
        "--quality", nargs="*", choices=LEVELS, default=list(LEVELS), help="none listed: no levels"
    )
    p.add_argument("--samples", type=int, nargs="*", default=[16, 64, 256, 1024], help="Cycles samples")
    p.add_argument("--sweep", action="store_true", help="also ovrad over --counts x --betas x --solvers")
    p.add_argument("--counts", type=int, nargs="+", default=[500, 1500, 4000, 10000])
    p.add_argument("--betas", nargs="+", choices=("box", "smooth"), default=["box", "smooth"])
    p.add_argument("--solvers", nargs="+", choices=("exact", "paper"), default=["exact", "paper"])
    p.add_argument("--name", default="speed_vs_error", help="results file name without .csv")
    p.add_argument(
        "--stages",
        nargs="*",
        choices=("cornell", "rooms"),
        default=["cornell", "rooms"],
        help="engine scenes whose per-stage rays per second against raw embree are measured in the "
        "same run (benchmarks/hot_path_bench.py; none listed: skipped)",
    )
    a = p.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="ovrad-speed-"))
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / f"{a.name}.csv"
    rows: list[dict] = []
    done: list[Scene] = []
    names = [n for name in a.scene for n in (real_scenes.SCENES if name == "real" else (name,))]
    for name in dict.fromkeys(names):
        sc = Scene(name, folder)
        run_cycles(sc, a.samples, rows)
        for level in a.quality:
            run_ovrad(sc, ["--quality", level], level, folder, rows)
        if a.sweep:
            for count in a.counts:
                for beta in a.betas:
                    for solver in a.solvers:
                        options = ["--patch-count", str(count), "--beta", beta, "--solver", solver]
                        run_ovrad(sc, options, f"{count} {beta} {solver}", folder, rows)
        done.append(sc)
        with open(out, "w", newline="") as fh:  # after every scene: a partial run keeps its rows
            w = csv.DictWriter(fh, FIELDS)
            w.writeheader()
            w.writerows(rows)
    plot(rows, done, out.with_suffix(".png"))
    if a.stages:  # the engine's stages against raw embree rays, in this same run (its own process:
        # tests/scenes.py, which it builds its scenes with, shares a name with benchmarks/scenes.py)
        cmd = [sys.executable, str(HERE / "hot_path_bench.py"), "--scene", *a.stages]
        subprocess.run([*cmd, "--repeat", "5", "--name", f"{a.name}_stages"], check=True)
        print(f"speed_vs_error: wrote {RESULTS / f'{a.name}_stages.csv'}")
    meta = {sc.name: dict(sc.ref["meta"]) for sc in done}
    print(f"speed_vs_error: references {json.dumps(meta)}")
    print(f"speed_vs_error: wrote {out} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []))
