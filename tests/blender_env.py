"""Shared helpers for Blender (bpy) tests: private user folders, extension build and install, CLI runs."""

from __future__ import annotations

import atexit
import importlib
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
from functools import cache
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "scripts"
BLENDER = SCRIPTS / "blender"
EXTENSION_ID = "ovrad"
REPO = "user_default"
PLATFORM = "linux-x64"  # the zip the tests install (the machines are linux x86_64)
# `make test-versions` runs the tests in other Blenders' venvs on the zip `make build` wrote (with
# the development venv's builder): this names it, and no build happens in those venvs.
ZIP_VARIABLE = "OVRAD_EXTENSION_ZIP"

# Blender's per-user folders; each may be redirected on its own, so all are set.
USER_DIRS = {
    "BLENDER_USER_CONFIG": "config",
    "BLENDER_USER_SCRIPTS": "scripts",
    "BLENDER_USER_EXTENSIONS": "extensions",
    "BLENDER_USER_DATAFILES": "datafiles",
}
_MARK = "OVRAD_TEST_USER_RESOURCES"  # set once per test session; subprocesses inherit it


def private_user_resources() -> Path:
    """Point Blender's user folders at a private temporary folder (before `import bpy`).

    Tests must never read or write the real user's preferences or extensions, whatever the
    environment says; scripts/blender subprocesses inherit the same folder, so an extension
    installed and saved in the preferences by the test process is enabled there too.
    """
    if "bpy" in sys.modules and _MARK not in os.environ:
        raise RuntimeError("bpy was imported before the test user folder was set up")
    existing = os.environ.get(_MARK)
    if existing and Path(existing).is_dir():
        folder = Path(existing)
    else:
        folder = Path(tempfile.mkdtemp(prefix="ovrad-test-blender-user-"))
        os.environ[_MARK] = str(folder)
        # Registered before bpy is imported: runs after bpy's own exit handler.
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
    os.environ["BLENDER_USER_RESOURCES"] = str(folder)
    for var, sub in USER_DIRS.items():
        os.environ[var] = str(folder / sub)
    return folder


def _load_script(name: str) -> ModuleType:
    """Import scripts/NAME.py as a module (scripts/ is not a package)."""
    if name in sys.modules:
        return sys.modules[name]
    if str(SCRIPTS) not in sys.path:
        sys.path.insert(0, str(SCRIPTS))
    return importlib.import_module(name)


def build_script() -> ModuleType:
    """scripts/build_extension.py, the same code `make build` runs."""
    return _load_script("build_extension")


def build_extension_zip(platform: str = PLATFORM) -> Path:
    """The platform's extension zip in dist/, rebuilt only when a source is newer (or files changed).

    With OVRAD_EXTENSION_ZIP set (make test-versions), that zip as it is.
    """
    if given := os.environ.get(ZIP_VARIABLE):
        return Path(given).resolve()
    zips = build_script().build(split_platforms=True, quiet=True)
    return zips[platform]


def build_zip(source_dir: Path, output_dir: Path) -> Path:
    """Build any extension folder with Blender's builder (for throwaway test extensions)."""
    output_dir.mkdir(parents=True, exist_ok=True)
    builder = build_script().builder_path()
    cmd = [sys.executable, str(builder), "build", "--source-dir", str(source_dir)]
    proc = subprocess.run([*cmd, "--output-dir", str(output_dir)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"extension build failed:\n{proc.stdout}{proc.stderr}")
    (zip_path,) = output_dir.glob("*.zip")
    return zip_path


@cache
def cli_commands():
    """Record add-ons' bpy.utils.register_cli_command calls (the module cannot run `-c`).

    Call before installing an extension; `cli_commands().run(id, args)` then does what
    `blender -c id args` does and returns its exit code.
    """
    import bpy

    return _load_script("blender_cli").Commands(bpy)


@cache
def cornell_blend() -> Path:
    """The bundled Cornell box for this Blender: scenes/cornell.blend, or the same scene rebuilt.

    scenes/cornell.blend is saved by Blender 5.0, whose file header Blender 4.5 reads and 4.2
    does not; under a Blender older than 4.5 the scene is built again by its own deterministic
    script (scripts/make_cornell.py) into the session's private folder.
    """
    import bpy

    bundled = ROOT / "scenes" / "cornell.blend"
    if bpy.app.version >= (4, 5, 0):
        return bundled
    out = private_user_resources() / "scenes" / "cornell.blend"
    if not out.is_file():
        script = SCRIPTS / "make_cornell.py"
        proc = run_blender(["-b", "--python-exit-code", "1", "--python", script, "--", "--output", out])
        if proc.returncode != 0 or not out.is_file():
            raise RuntimeError(f"could not build the Cornell box:\n{proc.stdout}{proc.stderr}")
    return out


def module_name(ext_id: str = EXTENSION_ID, repo: str = REPO) -> str:
    return f"bl_ext.{repo}.{ext_id}"


def install_extension(zip_path: Path, ext_id: str = EXTENSION_ID, repo: str = REPO) -> ModuleType:
    """Install and enable an extension zip in the private user folder; returns its module.

    The preferences are saved afterwards so scripts/blender subprocesses enable it too.
    """
    import addon_utils
    import bpy

    cli_commands()  # wrap register_cli_command before the add-on registers its commands
    if not Path(zip_path).is_file():  # the operator reports FINISHED even for a missing file
        raise FileNotFoundError(zip_path)
    bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo=repo, enable_on_install=True)
    name = module_name(ext_id, repo)
    state = addon_utils.check(name)
    assert state == (True, True), f"{name} not enabled after install: check() = {state}"
    bpy.ops.wm.save_userpref()
    return importlib.import_module(name)


def uninstall_extension(ext_id: str, repo: str = REPO) -> None:
    """Disable and remove an extension (and save the preferences without it)."""
    import bpy

    repo_dir = bpy.utils.user_resource("EXTENSIONS", path=repo)
    bpy.ops.extensions.package_uninstall(repo_directory=repo_dir, pkg_id=ext_id)
    bpy.ops.wm.save_userpref()


def enabled_addons() -> set[str]:
    import bpy

    return {a.module for a in bpy.context.preferences.addons}


def reset_scene():
    """Back to Blender's factory startup file, empty, keeping preferences and enabled add-ons.

    wm.read_homefile(use_factory_startup=True) resets the data only; wm.read_factory_settings
    would also reset the preferences and so disable every installed extension. Anything still
    found disabled afterwards is enabled again. Returns the new scene.
    """
    import addon_utils
    import bpy

    before = enabled_addons()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    for name in sorted(before - enabled_addons()):
        addon_utils.enable(name, default_set=True, persistent=True)
    missing = before - enabled_addons()
    assert not missing, f"add-ons lost by the scene reset: {sorted(missing)}"
    return bpy.context.scene


def run_blender(
    args: list[str],
    cwd: Path | str | None = None,
    env: dict[str, str] | None = None,
    timeout: float = 600,
) -> subprocess.CompletedProcess:
    """Run scripts/blender ARGS (Blender's command line on the bpy module) and capture its output.

    It shares this session's private user folder and runs on this interpreter's bpy (the Blender
    under test) unless `env` says otherwise.
    """
    full_env = {**os.environ, "OVRAD_PYTHON": sys.executable, **(env or {})}
    return subprocess.run(
        [str(BLENDER), *map(str, args)],
        cwd=str(cwd or ROOT),
        env=full_env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


THROWAWAY_INIT = '''\
"""A throwaway extension for testing the install helpers: one operator, one CLI command."""
import bpy

_handle = None


def _command(argv):
    print("throwaway command", argv)
    return int(argv[0]) if argv else 0


class THROWAWAY_OT_ping(bpy.types.Operator):
    bl_idname = "throwaway.ping"
    bl_label = "Ping"

    def execute(self, context):
        context.scene["throwaway_ping"] = 1
        return {"FINISHED"}


def register():
    global _handle
    bpy.utils.register_class(THROWAWAY_OT_ping)
    _handle = bpy.utils.register_cli_command("throwaway", _command)


def unregister():
    bpy.utils.unregister_cli_command(_handle)
    bpy.utils.unregister_class(THROWAWAY_OT_ping)
'''

THROWAWAY_MANIFEST = """\
schema_version = "1.0.0"
id = "throwaway"
version = "0.0.1"
name = "Throwaway"
tagline = "Test extension for the ovrad test helpers"
maintainer = "ovrad tests"
type = "add-on"
blender_version_min = "4.2.0"
license = ["SPDX:GPL-3.0-or-later"]
"""


def make_throwaway_extension(folder: Path) -> Path:
    """Write and build the throwaway extension under `folder`; returns its zip."""
    src = folder / "throwaway"
    src.mkdir(parents=True, exist_ok=True)
    (src / "__init__.py").write_text(THROWAWAY_INIT)
    (src / "blender_manifest.toml").write_text(THROWAWAY_MANIFEST)
    return build_zip(src, folder / "dist")
