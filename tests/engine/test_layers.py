"""The engine is plain Python + numpy: it must not import Blender."""

import ast
import subprocess
import sys
from pathlib import Path

ENGINE = Path(__file__).resolve().parents[2] / "ovrad_addon"


def test_engine_sources_import_no_blender_module():
    offenders = []
    for path in ENGINE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            mods = []
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                mods = [node.module]
            offenders += [
                f"{path.name}: {m}" for m in mods if m.split(".")[0] in ("bpy", "mathutils", "bmesh")
            ]
    assert offenders == []


def test_importing_the_engine_loads_no_blender_module():
    code = (
        "import sys, ovrad_addon, ovrad_addon.atlas, ovrad_addon.overlap, ovrad_addon.rays;"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('bpy', 'mathutils', 'bmesh')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ENGINE.parent, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"
