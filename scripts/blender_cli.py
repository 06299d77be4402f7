"""Blender's command line (-b, FILE, -P, --python-expr, -c, ...) emulated on the bpy module."""

from __future__ import annotations

import atexit
import builtins
import os
import shutil
import sys
import tempfile
import traceback
import types

HELP = """\
usage: scripts/blender [options] [file.blend] [-P script.py] ... [-- script args]

Blender's command line for the bpy module (no Blender binary needed). Arguments are
processed in order, as Blender does:

  -b, --background        accepted; the bpy module always runs in the background
  FILE.blend              open the file (bpy.ops.wm.open_mainfile); a file that cannot be
                          opened stops processing and exits 1, as Blender does in -b mode
  -P, --python SCRIPT     run SCRIPT as __main__ with sys.argv = [blender, *all arguments]
                          (a script reads its own arguments after "--")
  --python-expr EXPR      run EXPR the same way
  --python-exit-code N    exit code used when a later script raises (0..255). Blender's
                          default is 0: an uncaught exception prints its traceback, Blender
                          carries on with the next argument and finally exits 0. Give
                          --python-exit-code 1 *before* -P to make failures visible.
  -c, --command ID ARGS   run the command an add-on registered with
                          bpy.utils.register_cli_command; it takes all remaining arguments
                          and its return value is the exit code ("-c help" lists them),
                          e.g. -c extension install-file -r user_default -e ovrad.zip
  --addons A,B            enable these add-ons (module names, e.g. bl_ext.user_default.ovrad)
  --factory-startup       do not load the user's preferences (enabled extensions)
  -E, --engine ENGINE     set the scene's render engine
  -noaudio, -y, -Y, --enable-autoexec, --disable-autoexec, --python-use-system-env:
                          accepted and ignored
  --                      end of Blender's options: the rest is left for scripts
  -v, --version / -h, --help

sys.exit(N) in a script (or in a command) ends Blender at once with exit code N.
Unlike Blender, an unknown option is an error (exit 1), not silently ignored.

User configuration: BLENDER_USER_RESOURCES (config, extensions, scripts) is a private
temporary folder, deleted at exit, unless the environment sets it: set it to share installed
and enabled extensions between runs. Without --factory-startup the preferences saved there
(config/userpref.blend) are loaded first, which enables the extensions they list.
"""

# Options that take no value and change nothing for the module.
IGNORED = {"-noaudio", "-y", "-Y", "--enable-autoexec", "--disable-autoexec", "--python-use-system-env"}


class CliError(Exception):
    """A command-line mistake: reported in one line, exit code 1."""


def parse(args: list[str]) -> tuple[list[tuple[str, object]], bool]:
    """Turn arguments into ordered actions; also return whether --factory-startup was given.

    Blender applies --factory-startup before everything else (it is read in an earlier pass),
    so it is pulled out here; every other action keeps its place.
    """
    actions: list[tuple[str, object]] = []
    factory = False
    i = 0

    def value(opt: str) -> str:
        if i + 1 >= len(args):
            raise CliError(f"{opt} requires an argument")
        return args[i + 1]

    while i < len(args):
        a = args[i]
        if a == "--":
            break  # everything after belongs to the scripts (they read sys.argv)
        if a in ("-b", "--background") or a in IGNORED:
            pass
        elif a == "--factory-startup":
            factory = True
        elif a in ("-h", "--help"):
            actions.append(("help", None))
        elif a in ("-v", "--version"):
            actions.append(("version", None))
        elif a in ("-P", "--python"):
            actions.append(("python", value(a)))
            i += 1
        elif a == "--python-expr":
            actions.append(("expr", value(a)))
            i += 1
        elif a == "--python-exit-code":
            code = value(a)
            if not code.isdigit() or not 0 <= int(code) <= 255:
                raise CliError(f"{a} '{code}', expected number in [0..255]")
            actions.append(("exit_code", int(code)))
            i += 1
        elif a == "--addons":
            actions.append(("addons", value(a)))
            i += 1
        elif a in ("-E", "--engine"):
            actions.append(("engine", value(a)))
            i += 1
        elif a in ("-c", "--command"):
            if i + 1 >= len(args):
                raise CliError(f"{a} requires at least one argument")
            # The command consumes every remaining argument, "--" included.
            actions.append(("command", args[i + 1 :]))
            break
        elif a.startswith("-"):
            raise CliError(f"unsupported argument {a!r} (see scripts/blender --help)")
        else:
            actions.append(("file", a))
        i += 1
    return actions, factory


def private_user_resources() -> None:
    """Point Blender's user folders at a private temporary one unless the caller chose one.

    Must run before `import bpy`: Blender reads these variables once, at start-up.
    """
    if os.environ.get("BLENDER_USER_RESOURCES"):
        return
    tmp = tempfile.mkdtemp(prefix="ovrad-blender-user-")
    # Registered before bpy is imported, so it runs after bpy's own exit handler.
    atexit.register(shutil.rmtree, tmp, ignore_errors=True)
    os.environ["BLENDER_USER_RESOURCES"] = tmp


class Commands:
    """Records what add-ons pass to bpy.utils.register_cli_command.

    The module has no -c of its own and keeps its command table in C, so the registration
    function is wrapped before any add-on is enabled; the real one is still called.
    """

    def __init__(self, bpy: types.ModuleType) -> None:
        self.table: dict[str, list] = {}
        self._register = bpy.utils.register_cli_command
        self._unregister = bpy.utils.unregister_cli_command
        bpy.utils.register_cli_command = self.register
        bpy.utils.unregister_cli_command = self.unregister
        # Enabled while bpy was imported, so registered before the wrapper (bl_pkg's "extension").
        self._early = [a.module for a in bpy.context.preferences.addons]

    def discover(self) -> None:
        """Re-register the add-ons enabled before the wrapper so their commands are recorded too.

        Cheap (about 50 ms for Blender's default add-ons); only done when -c is used.
        """
        import addon_utils

        early, self._early = self._early, []
        for name in early:
            if addon_utils.check(name)[1]:
                addon_utils.disable(name)
                addon_utils.enable(name, default_set=True)

    def register(self, id, execute):  # noqa: A002  (Blender's own parameter name)
        handle = self._register(id, execute)
        self.table.setdefault(id, []).append((handle, execute))
        return handle

    def unregister(self, handle):
        self._unregister(handle)
        for entries in self.table.values():
            entries[:] = [e for e in entries if e[0] is not handle]

    def run(self, id: str, argv: list[str]) -> int:  # noqa: A002
        """Call the command as Blender does; its result (or SystemExit code) is the exit code."""
        if id == "help":
            print("Blender Command Listing:")
            for name in sorted(k for k, v in self.table.items() if len(v) == 1):
                print(f"\t{name}")
            return 0
        entries = self.table.get(id, [])
        if not entries:
            sys.stderr.write(f'Unrecognized command: "{id}"\n')
            return 1
        if len(entries) > 1:
            sys.stderr.write(f'Command: "{id}" was registered multiple times, must be resolved, aborting!\n')
            return 1
        try:
            result = entries[0][1](list(argv))
        except SystemExit as ex:
            result = ex.code
        except BaseException as ex:  # Blender prints the error and fails with 1
            print_exception(ex)
            return 1
        if not isinstance(result, int):
            sys.stderr.write(f"TypeError: Expected an int return value, not a {type(result).__name__}\n")
            return 1
        return int(result)


def print_exception(ex: BaseException) -> None:
    """Print a traceback without this file's frames (Blender shows only the script's)."""
    tb = ex.__traceback__
    while tb is not None and tb.tb_frame.f_code.co_filename == __file__:
        tb = tb.tb_next
    traceback.print_exception(type(ex), ex, tb)
    sys.stderr.flush()


def run_code(source: str, filename: str) -> None:
    """Execute code in a fresh __main__ module, as Blender runs -P and --python-expr.

    Not runpy.run_path: it rewrites sys.argv[0] while the script runs, and Blender does not.
    """
    code = compile(source, filename, "exec")
    module = types.ModuleType("__main__")
    module.__dict__.update(__builtins__=builtins, __file__=filename)
    if filename == "<string>":
        del module.__file__
    previous = sys.modules.get("__main__")
    sys.modules["__main__"] = module  # dataclasses, pickle and friends look here
    try:
        exec(code, module.__dict__)
    finally:
        sys.modules["__main__"] = previous


def exit_now(code) -> None:
    """End the process like Blender's sys.exit handling: int -> code, None -> 0, text -> 1."""
    sys.stdout.flush()
    sys.stderr.flush()
    raise SystemExit(code)


def load_preferences(bpy: types.ModuleType) -> None:
    """Load saved preferences, which enables the add-ons and extensions they list."""
    config = bpy.utils.user_resource("CONFIG")
    if os.path.isfile(os.path.join(config, "userpref.blend")):
        if bpy.app.version < (4, 5, 0):
            # The bpy 4.2 module crashes (segmentation fault) in wm.read_userpref whenever a
            # userpref.blend exists (Blender 4.2 itself reads it at start-up). Enable what an
            # install enables instead: every extension in the user's repositories.
            enable_addons(",".join(installed_extensions(bpy)))
        else:
            bpy.ops.wm.read_userpref()
    if os.path.isfile(os.path.join(config, "startup.blend")):
        bpy.ops.wm.read_homefile()


def installed_extensions(bpy: types.ModuleType) -> list[str]:
    """Module names (bl_ext.REPO.ID) of the extensions installed in the user's repositories."""
    found = []
    for repo in bpy.context.preferences.extensions.repos:
        folder = repo.directory
        if not (repo.enabled and folder and os.path.isdir(folder)):
            continue
        for pkg in sorted(os.listdir(folder)):
            if os.path.isfile(os.path.join(folder, pkg, "blender_manifest.toml")):
                found.append(f"bl_ext.{repo.module}.{pkg}")
    return found


def enable_addons(names: str) -> None:
    import addon_utils

    for name in filter(None, names.split(",")):
        if addon_utils.check(name)[1] is False:
            if addon_utils.enable(name, default_set=True, persistent=True) is None:
                sys.stderr.write(f"Error: add-on {name!r} could not be enabled\n")


def main(args: list[str]) -> int:
    try:
        actions, factory = parse(args)
    except CliError as ex:
        sys.stderr.write(f"Error: {ex}\n")
        return 1
    if any(kind == "help" for kind, _ in actions):
        print(HELP)
        return 0

    # Blender puts neither the script's folder nor this emulator's on sys.path.
    here = os.path.dirname(os.path.abspath(__file__))
    sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != here]
    private_user_resources()
    import bpy  # after the environment is set up

    commands = Commands(bpy)
    if not factory:
        load_preferences(bpy)
    # As Blender sets it: the executable, then every argument, the script's own after "--".
    sys.argv = [os.environ.get("BLENDER_CLI_ARGV0", "blender"), *args]

    python_exit_code = 0
    for kind, arg in actions:
        if kind == "version":
            print(f"Blender {bpy.app.version_string} (bpy module, command line emulated)")
            return 0
        if kind == "exit_code":
            python_exit_code = arg
        elif kind == "file":
            path = os.path.abspath(arg)
            try:
                if not os.path.isfile(path):
                    raise RuntimeError(f"cannot read file '{path}': No such file or directory")
                bpy.ops.wm.open_mainfile(filepath=path)
            except Exception as ex:  # Blender -b stops at a file it cannot load
                sys.stderr.write(f"Error: {ex}\n")
                return 1
        elif kind in ("python", "expr"):
            try:
                if kind == "python":
                    path = os.path.abspath(arg)  # Blender makes the script's path absolute too
                    with open(path, encoding="utf-8") as fh:
                        source = fh.read()
                    run_code(source, path)
                else:
                    run_code(arg, "<string>")
            except SystemExit as ex:
                exit_now(ex.code)
            except BaseException as ex:
                print_exception(ex)
                if python_exit_code:
                    return python_exit_code
        elif kind == "addons":
            enable_addons(arg)
        elif kind == "engine":
            bpy.context.scene.render.engine = arg
        elif kind == "command":
            commands.discover()
            return commands.run(arg[0], arg[1:])
    return 0


if __name__ == "__main__":
    code = main(sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    sys.exit(code)
