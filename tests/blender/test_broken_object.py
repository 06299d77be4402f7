"""One object that cannot be baked is skipped with a warning; it never stops the bake of the others."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import blender_env

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[2]
BATCH = ROOT / "scripts" / "ovrad_batch.py"
OTHERS = ["Floor", "Ceiling", "BackWall", "LeftWall", "RightWall", "ShortBlock", "Light"]

BREAK = """
import bpy
bpy.data.objects['TallBlock'].data.vertices[0].co = (float('nan'), 0.0, 0.0)
bpy.ops.wm.save_as_mainfile(filepath={path!r})
"""

BAKED = """
import bpy
print('BAKED', sorted(o.name for o in bpy.data.objects if o.type == 'MESH'
                      and 'ovrad_radiance' in o.data.color_attributes))
"""


def test_a_mesh_with_a_nan_vertex_is_skipped_and_the_rest_baked(ovrad, run_blender, tmp_path):
    broken = tmp_path / "broken.blend"
    cornell = blender_env.cornell_blend()
    proc = run_blender(
        ["-b", str(cornell), "--python-exit-code", "1", "--python-expr", BREAK.format(path=str(broken))]
    )
    assert proc.returncode == 0, proc.stderr
    out, report = tmp_path / "out.blend", tmp_path / "report.json"
    args = ["--patch-count", "200", "--output", str(out), "--report", str(report)]
    proc = run_blender(["-b", str(broken), "-P", str(BATCH), "--", *args], timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "'TallBlock' has NaN or infinite vertex coordinates" in proc.stdout + proc.stderr
    r = json.loads(report.read_text())
    assert r["receivers"] == OTHERS
    assert [s["object"] for s in r["skipped"]] == ["TallBlock"] and "NaN" in r["skipped"][0]["why"]
    proc = run_blender(["-b", str(out), "--python-exit-code", "1", "--python-expr", BAKED])
    assert proc.returncode == 0, proc.stderr
    line = next(ln for ln in proc.stdout.splitlines() if ln.startswith("BAKED "))
    assert eval(line[6:]) == sorted(OTHERS)  # noqa: S307  (our own repr of a list of names)
