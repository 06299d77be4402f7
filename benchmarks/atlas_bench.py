"""Benchmark: atlas generation and overlap-matrix (C) time and peak memory at 1k, 10k and 100k patches.

Run: .venv/bin/python benchmarks/atlas_bench.py [--sizes 1000 10000 100000]
Each size runs in its own process so peak memory (max RSS) is that size's alone.
Writes benchmarks/results/atlas.csv and prints a table.
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
OUT = ROOT / "benchmarks" / "results" / "atlas.csv"


def one(count: int, beta: str) -> dict:
    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    import scenes
    from ovrad_addon import AtlasSettings, build_atlas, has_embree

    s = scenes.cornell()
    marks = {}

    def progress(f, msg):
        marks.setdefault(msg.split(" ")[0], time.perf_counter())
        return True

    t0 = time.perf_counter()
    atlas = build_atlas(s, AtlasSettings(patch_count=count, beta=beta), progress=progress)
    t1 = time.perf_counter()
    t_int = marks.get("integrating", t1)
    return {
        "target": count,
        "beta": beta,
        "patches": len(atlas),
        "generate_s": round(t_int - t0, 3),
        "overlap_C_s": round(t1 - t_int, 3),
        "total_s": round(t1 - t0, 3),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "mean_overlap": round(float(atlas.overlap_count.mean()), 2),
        "rays": "embree" if has_embree() else "numpy",
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    ap.add_argument("--beta", default="smooth")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one, a.beta)))
        return
    rows = per_process.run_sizes(
        __file__,
        a.sizes,
        ["--beta", a.beta],
        lambda r: (
            f"{r['patches']:>7} patches  generate {r['generate_s']:7.2f} s  C {r['overlap_C_s']:7.2f} s  "
            f"peak {r['peak_rss_mb']:7.1f} MB  mean overlap {r['mean_overlap']}"
        ),
    )
    per_process.write_csv(rows, OUT)


if __name__ == "__main__":
    main()
