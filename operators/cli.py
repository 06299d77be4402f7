"""`blender -c ovrad [options]`: the batch bake of scripts/ovrad_batch.py as a Blender command."""

# Usage: blender -c ovrad --input scene.blend --output out.blend [options]   (see `-c ovrad --help`)
# The add-on's register() calls register_cli(); unregister() calls unregister_cli().

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import bpy

COMMAND = "ovrad"
BATCH = Path(__file__).resolve().parent.parent / "scripts" / "ovrad_batch.py"
_MODULE = "_ovrad_batch_cli"
_handle = None


def batch_module():
    """scripts/ovrad_batch.py of this extension, loaded once (it is a script, not a package module)."""
    mod = sys.modules.get(_MODULE)
    if mod is None:
        spec = importlib.util.spec_from_file_location(_MODULE, BATCH)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[_MODULE] = mod
        try:
            spec.loader.exec_module(mod)
        except BaseException:
            del sys.modules[_MODULE]
            raise
    return mod


def _command(argv) -> int:
    """Blender calls this with the arguments after `-c ovrad`; the result is the exit status."""
    return int(batch_module().main(list(argv)))


def register_cli() -> None:
    """Register the `ovrad` command (Blender 4.2+; older versions have no -c, so nothing is done)."""
    global _handle
    if _handle is None and hasattr(bpy.utils, "register_cli_command"):
        _handle = bpy.utils.register_cli_command(COMMAND, _command)


def unregister_cli() -> None:
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
    sys.modules.pop(_MODULE, None)
