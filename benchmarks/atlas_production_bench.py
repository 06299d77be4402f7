"""Benchmark: Generate Atlas on the production-like scene (scripts/make_production_scene.py).

Run: .venv/bin/python benchmarks/atlas_production_bench.py [--npz surfaces.npz] [--count 2000] [--no-overlap]
Without --npz the scene is built once by Blender (scripts/blender) into a temporary folder.
Prints and writes benchmarks/results/atlas_production.csv: triangles, charts, patches, seconds
per stage (index: charts, sheets and rays; placement; C: overlap integration), peak memory
(max RSS), and how many receiving objects got no patches. Timings are never asserted.
--no-overlap stops after placement (both passes build_atlas makes). The scene's ~30 000 small
pieces are clutter (ovrad_addon/clutter.py): a few hundred ball patches cover them, where one patch
per piece made 24 000 patches and a minute of overlap integration.
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "atlas_production.csv"
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import per_process  # noqa: E402  (benchmarks/ is not a package)


def build_npz(folder: Path) -> Path:
    """Build the scene with Blender and export its surfaces (a few seconds)."""
    npz = folder / "production.npz"
    subprocess.run(
        [
            str(ROOT / "scripts" / "blender"),
            "-b",
            "--python-exit-code",
            "1",
            "-P",
            str(ROOT / "scripts" / "make_production_scene.py"),
            "--",
            "--npz",
            str(npz),
        ],
        check=True,
        capture_output=True,
    )
    return npz


def load_surfaces(npz: Path):
    import numpy as np

    from ovrad_addon import Surfaces

    d = np.load(npz)
    return Surfaces.from_arrays(
        d["vertices"],
        d["triangles"],
        d["object_index"],
        d["reflectance"],
        d["emission"],
        [str(x) for x in d["object_names"]],
    )


def run_placement(surfaces, count: int) -> dict:
    """Index and placement only, as build_atlas does them (spacing corrected once)."""
    import numpy as np

    from ovrad_addon import AtlasSettings
    from ovrad_addon import atlas as atlas_mod

    settings = AtlasSettings(patch_count=count)
    t0 = time.perf_counter()
    index = atlas_mod.index_surfaces(surfaces, settings)
    t_index = time.perf_counter() - t0
    t0 = time.perf_counter()
    spacing = atlas_mod.sheet_spacing(index, settings)
    placed, total = atlas_mod.place_all(index, settings, spacing)
    placed, total = atlas_mod.place_all(index, settings, spacing * np.sqrt(total / count))
    t_place = time.perf_counter() - t0
    return {
        "triangles": len(surfaces.triangles),
        "charts": index.charts.count,
        "sheets": len(index.sheet_chart),
        "patches": total,
        "index_s": round(t_index, 3),
        "placement_s": round(t_place, 3),
        "overlap_C_s": "",
        "generate_total_s": round(t_index + t_place, 3),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "objects_without_patches": "(not integrated)",
    }


def run(surfaces, count: int) -> dict:
    import numpy as np

    from ovrad_addon import AtlasSettings
    from ovrad_addon import atlas as atlas_mod

    settings = AtlasSettings(patch_count=count)
    marks = {}

    def progress(f, msg):
        marks.setdefault(msg.split(" ")[0], time.perf_counter())
        return True

    t0 = time.perf_counter()
    index = atlas_mod.index_surfaces(surfaces, settings)
    t_index = time.perf_counter() - t0
    t0 = time.perf_counter()
    atlas = atlas_mod.build_atlas(surfaces, settings, progress=progress)
    t1 = time.perf_counter()
    t_place = marks["integrating"] - marks["placing"]
    got = np.bincount(atlas.source_object, minlength=len(surfaces.object_names)) > 0
    return {
        "triangles": len(surfaces.triangles),
        "charts": index.charts.count,
        "sheets": len(index.sheet_chart),
        "patches": len(atlas),
        "index_s": round(t_index, 3),
        "placement_s": round(t_place, 3),
        "overlap_C_s": round(t1 - marks["integrating"], 3),
        "generate_total_s": round(t1 - t0, 3),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "objects_without_patches": ";".join(
            n for n, g, r in zip(surfaces.object_names, got, surfaces.receiver, strict=True) if r and not g
        ),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--npz", type=Path, help="surfaces exported by make_production_scene.py --npz")
    ap.add_argument("--count", type=int, default=2000, help="target patch count")
    ap.add_argument("--no-overlap", action="store_true", help="stop after placement (no C)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        npz = a.npz or build_npz(Path(tmp))
        row = (run_placement if a.no_overlap else run)(load_surfaces(npz), a.count)
    print(
        f"{row['triangles']} triangles  {row['charts']} charts  {row['patches']} patches  "
        f"index {row['index_s']} s  placement {row['placement_s']} s  C {row['overlap_C_s']} s  "
        f"total {row['generate_total_s']} s  peak {row['peak_rss_mb']} MB  "
        f"no patches: {row['objects_without_patches'] or 'none'}"
    )
    per_process.write_csv([row], OUT)


if __name__ == "__main__":
    main()
