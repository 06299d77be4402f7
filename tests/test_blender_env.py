"""The test helpers themselves, on a throwaway extension: private user folder, install, reset, -c."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import blender_env

pytestmark = pytest.mark.blender


@pytest.fixture(scope="module")
def throwaway(tmp_path_factory, blender_commands):
    """The throwaway extension installed for this module's tests, removed afterwards."""
    zip_path = blender_env.make_throwaway_extension(tmp_path_factory.mktemp("throwaway"))
    module = blender_env.install_extension(zip_path, "throwaway")
    yield module
    blender_env.uninstall_extension("throwaway")


def test_user_folder_is_private():
    import bpy

    user = Path(bpy.utils.resource_path("USER"))
    assert user == Path(os.environ["BLENDER_USER_RESOURCES"])
    assert user.name.startswith("ovrad-test-blender-user-")
    assert Path(bpy.utils.user_resource("CONFIG")).is_relative_to(user)
    assert Path(bpy.utils.user_resource("EXTENSIONS")).is_relative_to(user)
    assert Path(bpy.utils.user_resource("SCRIPTS")).is_relative_to(user)


def test_install_enables_the_extension(throwaway):
    import addon_utils
    import bpy

    assert throwaway.__name__ == "bl_ext.user_default.throwaway"
    assert addon_utils.check("bl_ext.user_default.throwaway") == (True, True)
    assert bpy.ops.throwaway.ping() == {"FINISHED"}
    installed = Path(bpy.utils.user_resource("EXTENSIONS")) / "user_default" / "throwaway"
    assert (installed / "__init__.py").is_file()


def test_install_of_a_missing_zip_fails(tmp_path):
    with pytest.raises(FileNotFoundError):
        blender_env.install_extension(tmp_path / "nothing.zip", "nothing")


def test_fresh_scene_is_empty_and_keeps_the_extension(throwaway, fresh_scene):
    import addon_utils
    import bpy

    assert len(bpy.data.objects) == 0 and len(bpy.data.meshes) == 0
    assert fresh_scene == bpy.context.scene
    assert addon_utils.check("bl_ext.user_default.throwaway") == (True, True)
    bpy.ops.mesh.primitive_cube_add()
    assert bpy.ops.throwaway.ping() == {"FINISHED"}
    assert fresh_scene["throwaway_ping"] == 1


def test_fresh_scene_again_discards_the_previous_tests_data(throwaway, fresh_scene):
    import bpy

    assert len(bpy.data.objects) == 0
    assert "throwaway_ping" not in fresh_scene


def test_reset_re_enables_after_a_factory_reset(throwaway):
    import addon_utils
    import bpy

    # A test that calls read_factory_settings loses every extension: reset_scene restores them
    # when given the set of add-ons to keep, which is what it records before resetting.
    before = blender_env.enabled_addons()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert addon_utils.check("bl_ext.user_default.throwaway")[1] is False
    for name in sorted(before - blender_env.enabled_addons()):
        addon_utils.enable(name, default_set=True, persistent=True)
    assert addon_utils.check("bl_ext.user_default.throwaway") == (True, True)
    assert bpy.ops.throwaway.ping() == {"FINISHED"}


def test_cli_command_is_recorded_and_runs(throwaway, blender_commands, capsys):
    assert blender_commands.run("throwaway", ["7"]) == 7
    assert "throwaway command ['7']" in capsys.readouterr().out


def test_blender_subprocess_sees_the_installed_extension(throwaway, run_blender):
    # The saved preferences enable the extension in scripts/blender, so -c finds its command.
    proc = run_blender(["-b", "-c", "throwaway", "9"])
    assert proc.returncode == 9, proc.stdout + proc.stderr
    assert "throwaway command ['9']" in proc.stdout
    # --factory-startup ignores the preferences, as in Blender.
    proc = run_blender(["-b", "--factory-startup", "-c", "throwaway", "9"])
    assert proc.returncode == 1 and "Unrecognized command" in proc.stderr


def test_blender_subprocess_addons_option_enables_an_extension(throwaway, run_blender):
    args = ["-b", "--factory-startup", "--addons", "bl_ext.user_default.throwaway", "-c", "throwaway", "6"]
    proc = run_blender(args)
    assert proc.returncode == 6, proc.stdout + proc.stderr
