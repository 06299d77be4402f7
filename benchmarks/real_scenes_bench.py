"""The real-scenes set baked as a user would, scored at every vertex against its Cycles reference.

    scripts/blender -b --python-exit-code 1 -P benchmarks/real_scenes_bench.py -- [--scene NAME ...]

For each scene: build it (benchmarks/real_scenes.py) into a .blend, run the documented batch
command on it with no options (`blender -b scene.blend -P scripts/ovrad_batch.py -- --output
out.blend --report r.json`), open the result and score `ovrad_radiance` at every vertex of every
baked mesh against benchmarks/reference/real/<scene>.npz. Writes benchmarks/results/real_scenes.csv.
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

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from per_process import write_csv  # noqa: E402

import real_scenes  # noqa: E402  (benchmarks/ is not a package)
from make_real_reference import load  # noqa: E402

RESULTS = HERE / "results" / "real_scenes.csv"


def bake(blend: Path, out: Path, report: Path, extra: list[str]) -> tuple[subprocess.CompletedProcess, float]:
    """The documented batch command on `blend`; returns the process and its wall time."""
    cmd = [
        str(ROOT / "scripts" / "blender"),
        "-b",
        str(blend),
        "-P",
        str(ROOT / "scripts" / "ovrad_batch.py"),
    ]
    cmd += ["--", "--output", str(out), "--report", str(report), *extra]
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=str(ROOT), capture_output=True, text=True, timeout=1800)
    return proc, time.perf_counter() - start


def run_scene(name: str, folder: Path, extra: list[str]) -> dict:
    blend, out, report = folder / f"{name}.blend", folder / f"{name}_baked.blend", folder / f"{name}.json"
    real_scenes.build(name, blend)
    proc, seconds = bake(blend, out, report, extra)
    row = {"scene": name, "exit": proc.returncode, "seconds": round(seconds, 2)}
    lines = proc.stdout.splitlines() + proc.stderr.splitlines()
    warnings = [ln for ln in lines if "warning" in ln.lower()]
    row["warnings"] = len(warnings)
    if proc.returncode != 0:
        row["error"] = (proc.stderr.strip().splitlines() or ["?"])[-1]
        return row
    ref = load(name)
    bpy.ops.wm.open_mainfile(filepath=str(out))
    values, missing = real_scenes.baked_values(bpy.context.scene, ref["object_names"])
    s = real_scenes.score(ref, values)
    rep = json.loads(report.read_text()) if report.exists() else {}
    row.update(
        rel_rms=round(s["rel_rms"], 4),
        scored=s["scored"],
        vertices=s["vertices"],
        skipped=";".join(missing),
        reference_noise=ref["meta"]["relative_rms_noise"],
        patches=rep.get("patches", ""),
    )
    # vertices where walls meet (two faces of the room's box) and in its corners (three): the
    # error there and the baked light's mean over the reference's
    for place, got in s["places"].items():
        row.update({f"{place}_rel_rms": round(got["rel_rms"], 4), f"{place}_ratio": round(got["ratio"], 4)})
        row[f"{place}_vertices"] = got["count"]
    return row


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(prog="real_scenes_bench.py", description=__doc__.split("\n")[0])
    p.add_argument("--scene", nargs="*", choices=tuple(real_scenes.SCENES), help="default: all")
    p.add_argument("--batch-args", default="", help="extra batch options, one string")
    p.add_argument("--output", default=str(RESULTS))
    a = p.parse_args(argv)
    folder = Path(tempfile.mkdtemp(prefix="ovrad-real-bench-"))
    rows = []
    for name in a.scene or list(real_scenes.SCENES):
        row = run_scene(name, folder, a.batch_args.split())
        rows.append(row)
        print("real_scenes_bench:", json.dumps(row), flush=True)
    keys = sorted({k for r in rows for k in r}, key=lambda k: (k != "scene", k))
    write_csv(rows, a.output, keys, tag="real_scenes_bench")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []))
