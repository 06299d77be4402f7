"""The real-scenes set (benchmarks/real_scenes.py): the documented batch command with no options
bakes each class of scene without an error, scored at EVERY vertex of every baked mesh against the
scene's converged Cycles reference (benchmarks/reference/real/, 1 024-4 096 samples)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
if str(BENCH) not in sys.path:
    sys.path.insert(0, str(BENCH))

import real_scenes_bench  # noqa: E402  (benchmarks/ is not a package)

import blender_env  # noqa: E402

# Relative RMS bound per scene: the measured error (benchmarks/results/real_scenes.csv) with room
# for the reference's own noise (1.5-3 % per vertex, in the csv) and the bake's seeded variation.
# doorway: the second room is lit only through the doorway, all of it indirect light; measured
# 5.8 %, above the 5 % this class should reach (open work, named in the README).
BOUNDS = {
    "doorway": 0.07,
    "contact": 0.04,
    "ceiling_opening": 0.035,
    "duplicates": 0.035,
    "instances": 0.035,
    "textured": 0.055,
    "sky_constant": 0.055,
    "sky_hdr": 0.08,
}
# Linked duplicates lit differently cannot share one set of vertex colours: skipped with a warning.
SKIPPED = {"duplicates": "BenchA;BenchB"}


@pytest.mark.parametrize("name", list(BOUNDS))
def test_batch_bakes_the_scene_within_its_bound(ovrad, tmp_path, name):
    import addon_utils

    before = blender_env.enabled_addons()
    try:
        row = real_scenes_bench.run_scene(name, tmp_path, [])
    finally:  # building a scene reads the factory startup file: keep the session's add-ons on
        for lost in sorted(before - blender_env.enabled_addons()):
            addon_utils.enable(lost, default_set=True, persistent=True)
    assert row["exit"] == 0, row.get("error")
    assert row["skipped"] == SKIPPED.get(name, ""), row
    assert row["rel_rms"] < BOUNDS[name], row
