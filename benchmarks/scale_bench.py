"""Scale: the batch bake at growing patch counts, timed, its memory measured and scored at every vertex.

Run (about 10 minutes for the defaults on 2 cores):
    scripts/blender -b --python-exit-code 1 -P benchmarks/scale_bench.py -- \
        [--scene cornell lamps_doorway production] [--counts 2000 25000 100000] [--name scale] \
        [--batch-args "--cluster-angle 0"]

Each bake runs in a Blender process of its own (so its memory is its own, not what earlier bakes
left behind) through the batch command's own code (scripts/ovrad_batch.py, `--input scene.blend
--output out.blend --patch-count N`, the file's other settings: medium quality), so the figures
are what a user's `blender -b -P ovrad_batch.py` gets. Per bake: seconds of generate,
solve (with its C, transport and shooting) and vertex bake; the peak resident memory of each stage
(the batch report's peak_memory_mb: the process's peak within the stage, Blender included); the
relative RMS error at EVERY vertex against the scene's converged Cycles reference (cornell,
lamps_doorway; speed_vs_error.py scores them the same way). `production` is the ~100 k-triangle
production-like room of scripts/make_production_scene.py, scored at every vertex against
reference/real/production.npz (make_production_reference.py) when it is there. Writes
benchmarks/results/<name>.csv and <name>.png (log-log: time and peak memory against patches).
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import bpy
import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
import speed_vs_error  # noqa: E402  (benchmarks/ is not a package)

import real_scenes  # noqa: E402

RESULTS = HERE / "results"
FIELDS = [
    "scene",
    "target_patches",
    "patches",
    "seconds",
    "generate_s",
    "solve_s",
    "bake_s",
    "overlap_s",
    "transport_s",
    "peak_mb",
    "generate_mb",
    "solve_mb",
    "bake_mb",
    "transport_mb",
    "rays",
    "error",
    "scored",
    "skipped",
]


def build_production(folder: Path) -> Path:
    """The production room built into folder by its script. A run builds it once for all its
    counts: the evaluated mesh of its boolean object (Carved) triangulates differently from build
    to build, which moved the error by up to 0.07 point between runs of identical code."""
    blend = folder / "production.blend"
    cmd = [str(ROOT / "scripts" / "blender"), "-b", "--python-exit-code", "1", "-P"]
    cmd += [str(ROOT / "scripts" / "make_production_scene.py"), "--", "--output", str(blend)]
    subprocess.run(cmd, check=True, capture_output=True)
    return blend


class Production:
    """The production-like room, built once by its own script; scored at every vertex against
    reference/real/production.npz (make_production_reference.py) when it is there."""

    name = "production"
    REFERENCE = HERE / "reference" / "real" / "production.npz"

    def __init__(self, folder: Path, blend: Path | None = None):
        self.blend = blend or build_production(folder)
        self.ref = None
        if self.REFERENCE.exists():
            with np.load(self.REFERENCE) as z:
                self.ref = {k: z[k] for k in z.files}
            bpy.ops.wm.open_mainfile(filepath=str(self.blend))
            names = [str(n) for n in self.ref["object_names"]]
            positions, _ = real_scenes.vertex_positions([bpy.context.scene.objects[n] for n in names])
            want = self.ref["positions"]
            if positions.shape != want.shape or np.abs(positions - want).max() > 1e-4:
                raise SystemExit("scale_bench: the production room no longer matches its reference")

    def score(self, attribute: str):
        """Relative RMS error over every vertex of every baked object (real_scenes.score); the
        objects the batch skipped (with a warning) are listed."""
        if self.ref is None:
            return float("nan"), float("nan")
        names = [str(n) for n in self.ref["object_names"]]
        values, self.skipped = real_scenes.baked_values(bpy.context.scene, names, attribute)
        s = real_scenes.score(self.ref | {"radiance": self.ref["radiance"].astype(np.float64)}, values)
        self.scored = s["scored"]
        return s["rel_rms"], s["rel_rms"]


def bake(sc, count: int, folder: Path, extra: str = "") -> dict:
    batch = speed_vs_error.batch_module()
    out, report = folder / f"{sc.name}_{count}.blend", folder / f"{sc.name}_{count}.json"
    args = ["--input", str(sc.blend), "--output", str(out), "--report", str(report)]
    rep = batch.run(batch.parse([*args, "--patch-count", str(count), *shlex.split(extra)]))
    s, mb, inner = rep["seconds"], rep["peak_memory_mb"], rep["solve_peak_memory_mb"]
    seconds = s["generate"] + s["solve"] + s["bake"]
    err, _ = sc.score(rep["attribute"])
    scored = dict(scored=getattr(sc, "scored", ""), skipped=";".join(getattr(sc, "skipped", [])))
    return (
        dict(scene=sc.name, target_patches=count, patches=rep["patches"], seconds=round(seconds, 2))
        | dict(generate_s=s["generate"], solve_s=s["solve"], bake_s=s["bake"])
        | dict(overlap_s=rep["solve_seconds"].get("overlap"))
        | dict(transport_s=rep["solve_seconds"].get("transport"))
        | dict(peak_mb=max(mb[k] for k in ("generate", "solve", "bake")), generate_mb=mb["generate"])
        | dict(solve_mb=mb["solve"], bake_mb=mb["bake"], transport_mb=inner.get("transport"))
        | dict(rays=rep["rays"], error=round(err, 5))
        | scored
    )


def one(scene: str, count: int, extra: str = "", blend: str = "") -> None:
    """One bake in this process (of the production room built into `blend`, if given); its row
    as one JSON line."""
    folder = Path(tempfile.mkdtemp(prefix="ovrad-scale-"))
    if scene == "production":
        sc = Production(folder, Path(blend) if blend else None)
    else:
        sc = speed_vs_error.Scene(scene, folder)
    print("scale_bench row " + json.dumps(bake(sc, count, folder, extra)), flush=True)


def run_one(scene: str, count: int, extra: str = "", blend: Path | None = None) -> dict:
    cmd = [str(ROOT / "scripts" / "blender"), "-b", "--python-exit-code", "1", "-P", __file__, "--"]
    cmd += ["--one", scene, str(count), "--batch-args", extra]
    if blend is not None:
        cmd += ["--production-blend", str(blend)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    rows = [ln for ln in proc.stdout.splitlines() if ln.startswith("scale_bench row ")]
    if proc.returncode != 0 or not rows:
        raise SystemExit(
            f"scale_bench: {scene} {count}: failed\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
        )
    r = json.loads(rows[-1].removeprefix("scale_bench row "))
    print(
        f"scale_bench: {scene:14s} {r['patches']:8d} patches {r['seconds']:8.1f} s "
        f"(generate {r['generate_s']:.1f}, solve {r['solve_s']:.1f}, bake {r['bake_s']:.1f}) "
        f"peak {r['peak_mb']:.0f} MiB, error {r['error']:.4f}",
        flush=True,
    )
    return r


def plot(rows: list, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for name in dict.fromkeys(r["scene"] for r in rows):
        mine = [r for r in rows if r["scene"] == name]
        n = [r["patches"] for r in mine]
        axes[0].loglog(n, [r["seconds"] for r in mine], "o-", label=name)
        axes[1].loglog(n, [r["peak_mb"] for r in mine], "o-", label=name)
    axes[0].axhline(120, color="grey", ls=":", label="2 minutes")
    axes[1].axhline(4096, color="grey", ls=":", label="4 GiB")
    axes[0].set(xlabel="patches", ylabel="generate + solve + bake (s)", title="time")
    axes[1].set(xlabel="patches", ylabel="peak resident memory (MiB)", title="memory (Blender included)")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="scale_bench.py", description=__doc__.split("\n")[0])
    scenes = ("cornell", "lamps_doorway", "production")
    p.add_argument("--scene", nargs="+", choices=scenes, default=["cornell"])
    p.add_argument("--counts", type=int, nargs="+", default=[2000, 25000, 100000])
    p.add_argument("--name", default="scale", help="results file name without .csv")
    p.add_argument("--batch-args", default="", help="extra batch options, one string")
    p.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    p.add_argument(
        "--production-blend",
        default="",
        help="bake this production room .blend (make_production_scene.py) instead of building one: "
        "runs from one file are comparable to the last digit",
    )
    a = p.parse_args(argv)
    if a.one:
        one(a.one[0], int(a.one[1]), a.batch_args, a.production_blend)
        return 0
    blend = Path(a.production_blend) if a.production_blend else None
    if "production" in a.scene and blend is None:
        blend = build_production(Path(tempfile.mkdtemp(prefix="ovrad-scale-")))
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / f"{a.name}.csv"
    rows: list[dict] = []
    for name in a.scene:
        for count in a.counts:
            rows.append(run_one(name, count, a.batch_args, blend if name == "production" else None))
            with open(out, "w", newline="") as fh:  # after every bake: a partial run keeps its rows
                w = csv.DictWriter(fh, FIELDS)
                w.writeheader()
                w.writerows(rows)
    plot(rows, out.with_suffix(".png"))
    print(f"scale_bench: wrote {out} and {out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []))
