"""scripts/blender emulates Blender's command line: file, -P, --python-expr, exit codes, -c."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from blender_env import BLENDER, ROOT, run_blender

pytestmark = pytest.mark.blender

CORNELL = ROOT / "scenes" / "cornell.blend"

REPORT = """\
import json, sys, bpy
out = sys.argv[sys.argv.index("--") + 1:][0]
with open(out, "w") as fh:
    json.dump({"argv": sys.argv, "name": __name__, "file": __file__,
               "blend": bpy.data.filepath, "objects": len(bpy.data.objects),
               "user": bpy.utils.resource_path("USER")}, fh)
"""


def script(tmp_path: Path, text: str, name: str = "script.py") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_file_then_script_with_arguments_after_double_dash(tmp_path):
    s = script(tmp_path, REPORT)
    out = tmp_path / "report.json"
    proc = run_blender(["-b", CORNELL, "-P", s, "--", out, "extra"], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(out.read_text())
    # Blender's sys.argv: the executable, then every argument as given.
    assert report["argv"] == [str(BLENDER), "-b", str(CORNELL), "-P", str(s), "--", str(out), "extra"]
    assert report["name"] == "__main__"
    assert report["file"] == str(s)
    assert Path(report["blend"]) == CORNELL
    assert report["objects"] == 9


def test_relative_script_and_file_resolve_against_the_working_directory(tmp_path):
    script(tmp_path, REPORT, "rel.py")
    proc = run_blender(["--background", "--python", "rel.py", "--", "out.json"], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    report = json.loads((tmp_path / "out.json").read_text())
    assert report["file"] == str(tmp_path / "rel.py")  # made absolute, as Blender does
    assert report["blend"] == ""  # no file given: Blender's startup scene
    assert report["objects"] == 3  # camera, cube, light


def test_python_expr_runs_in_order_with_scripts(tmp_path):
    s = script(tmp_path, "print('from script')\n")
    proc = run_blender(["-b", "--python-expr", "print('first')", "-P", s, "--python-expr", "print('last')"])
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stdout.splitlines() if ln in ("first", "from script", "last")]
    assert lines == ["first", "from script", "last"]


def test_sys_exit_sets_the_exit_code_and_stops(tmp_path):
    s = script(tmp_path, "import sys\nsys.exit(3)\n")
    proc = run_blender(["-b", "-P", s, "--python-expr", "print('not reached')"])
    assert proc.returncode == 3
    assert "not reached" not in proc.stdout


def test_exception_without_exit_code_continues_and_exits_zero(tmp_path):
    # Blender's default (--python-exit-code 0): print the traceback, go on, exit 0.
    s = script(tmp_path, "raise ValueError('boom')\n")
    proc = run_blender(["-b", "-P", s, "--python-expr", "print('still running')"])
    assert proc.returncode == 0
    assert "ValueError: boom" in proc.stderr
    assert "still running" in proc.stdout
    assert "blender_cli.py" not in proc.stderr  # only the script's frames, as Blender shows


def test_exception_with_python_exit_code(tmp_path):
    s = script(tmp_path, "raise ValueError('boom')\n")
    proc = run_blender(["-b", "--python-exit-code", "2", "-P", s, "--python-expr", "print('not reached')"])
    assert proc.returncode == 2
    assert "ValueError: boom" in proc.stderr
    assert "not reached" not in proc.stdout


def test_command_registered_by_a_script_runs_with_the_remaining_arguments():
    register = (
        "import bpy\n"
        "def hello(argv):\n"
        "    print('hello', argv)\n"
        "    return int(argv[0])\n"
        "bpy.utils.register_cli_command('hello', hello)\n"
    )
    proc = run_blender(["-b", "--python-expr", register, "-c", "hello", "5", "--", "-P", "x"])
    assert proc.returncode == 5, proc.stderr
    assert "hello ['5', '--', '-P', 'x']" in proc.stdout  # the command takes every argument after it

    proc = run_blender(["--python-expr", register, "-c", "help"])
    assert proc.returncode == 0 and "hello" in proc.stdout


@pytest.mark.parametrize(
    "body, code, message",
    [
        ("return 'no'", 1, "Expected an int return value"),
        ("raise RuntimeError('bad')", 1, "RuntimeError: bad"),
        ("import sys; sys.exit(4)", 4, ""),
    ],
)
def test_command_results(body, code, message):
    register = f"import bpy\ndef cmd(argv):\n    {body}\nbpy.utils.register_cli_command('cmd', cmd)\n"
    proc = run_blender(["--python-expr", register, "-c", "cmd"])
    assert proc.returncode == code
    assert message in proc.stderr


def test_unknown_command_and_option_fail():
    proc = run_blender(["-b", "-c", "no_such_command"])
    assert proc.returncode == 1 and "Unrecognized command" in proc.stderr
    proc = run_blender(["-b", "--no-such-option"])
    assert proc.returncode == 1 and "unsupported argument" in proc.stderr


def test_missing_blend_file_stops_with_failure(tmp_path):
    proc = run_blender(["-b", tmp_path / "missing.blend", "--python-expr", "print('not reached')"])
    assert proc.returncode == 1
    assert "not reached" not in proc.stdout


def test_private_user_folder_when_the_environment_sets_none(tmp_path):
    s = script(tmp_path, REPORT)
    out = tmp_path / "report.json"
    env = {k: v for k, v in os.environ.items() if not k.startswith("BLENDER_USER_")}
    env["HOME"] = str(tmp_path / "home")  # would catch a write to ~/.config/blender
    proc = subprocess.run([str(BLENDER), "-b", "-P", str(s), "--", str(out)], env=env, capture_output=True)
    assert proc.returncode == 0, proc.stderr
    user = Path(json.loads(out.read_text())["user"])
    assert user.name.startswith("ovrad-blender-user-")
    assert not user.exists()  # removed at exit
    # Blender makes empty thumbnail caches in ~/.cache, but nothing of the user's configuration.
    assert not (tmp_path / "home" / ".config").exists()


def test_help_documents_the_exit_code_rule():
    proc = run_blender(["--help"])
    assert proc.returncode == 0
    assert "--python-exit-code" in proc.stdout and "exits 0" in proc.stdout
