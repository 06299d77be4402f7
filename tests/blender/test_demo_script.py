"""scripts/ovrad_demo.py run as documented, through scripts/blender: installed extension or checkout."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import blender_env

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[2]
CORNELL = ROOT / "scenes" / "cornell.blend"
SMALL = ["--patch-count", "300", "--samples", "1", "--resolution", "48"]


def demo(run_blender, out: Path, *extra: str, env=None):
    args = ["-b", str(CORNELL), "--python-exit-code", "1"]
    args += ["-P", str(ROOT / "scripts" / "ovrad_demo.py"), "--", "--output", str(out / "c.blend"), *extra]
    return run_blender(args, env=env)


def summary(stdout: str) -> tuple[int, int]:
    m = re.search(r"ovrad demo: (\d+) patches on (\d+) objects in [\d.]+ s", stdout)
    assert m, stdout
    return int(m.group(1)), int(m.group(2))


def test_demo_saves_the_atlas_and_renders_a_picture(ovrad, run_blender, tmp_path):
    before = CORNELL.stat().st_mtime_ns
    proc = demo(run_blender, tmp_path, *SMALL, "--picture", str(tmp_path / "c.png"))
    assert proc.returncode == 0, proc.stderr
    assert "ovrad_demo: using bl_ext.user_default.ovrad from " in proc.stdout
    patches, objects = summary(proc.stdout)
    assert objects == 8 and 250 <= patches <= 400  # every mesh of the Cornell box, about the asked count
    assert (tmp_path / "c.blend").is_file() and (tmp_path / "c.png").stat().st_size > 1000
    assert CORNELL.stat().st_mtime_ns == before
    # The installed extension did the work (its atlas objects and display are in the saved file).
    check = run_blender(
        [
            "-b",
            str(tmp_path / "c.blend"),
            "--python-exit-code",
            "1",
            "--python-expr",
            "import bpy; a = [o for o in bpy.data.objects if 'ovrad_source' in o]; "
            "print('ATLAS', len(a), sum(len(o.data.vertices) for o in a), "
            "all(o.modifiers.get('ovrad display') for o in a), [c.name for c in a[0].users_collection])",
        ]
    )
    assert f"ATLAS 8 {patches} True ['ovrad']" in check.stdout, check.stdout + check.stderr


def test_demo_runs_from_a_checkout_without_the_extension(run_blender, tmp_path):
    # An empty user folder: no extension installed, so the script registers the checkout itself.
    user = tmp_path / "user"
    env = {"BLENDER_USER_RESOURCES": str(user)}
    env |= {var: str(user / sub) for var, sub in blender_env.USER_DIRS.items()}
    proc = demo(run_blender, tmp_path, *SMALL, env=env)
    assert proc.returncode == 0, proc.stderr
    assert f"ovrad_demo: using ovrad from {ROOT}" in proc.stdout
    assert summary(proc.stdout)[1] == 8


def test_demo_never_overwrites_its_input(run_blender, tmp_path):
    copy = tmp_path / "scene.blend"
    copy.write_bytes(CORNELL.read_bytes())
    proc = run_blender(
        [
            "-b",
            "--factory-startup",
            str(copy),
            "-P",
            str(ROOT / "scripts" / "ovrad_demo.py"),
            "--",
            "--output",
            str(copy),
        ]
    )
    assert proc.returncode == 2 and "refusing to overwrite the input file" in proc.stderr
    assert copy.read_bytes() == CORNELL.read_bytes()
