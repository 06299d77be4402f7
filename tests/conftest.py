"""Test session set-up: a private Blender user folder, and fixtures for the built and installed extension."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_env  # noqa: E402  (tests/ is not a package)

# Before any test module can import bpy: Blender reads its user folders once, at import.
blender_env.private_user_resources()

# Fixtures that load bpy: tests using them are Blender tests even without the marker.
BLENDER_FIXTURES = {"built_extension", "ovrad", "fresh_scene", "blender_commands"}


def pytest_collection_modifyitems(config, items):
    for item in items:
        if BLENDER_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.blender)


@pytest.fixture(scope="session")
def built_extension() -> Path:
    """The linux-x64 extension zip in dist/ (rebuilt only when a source is newer than it)."""
    return blender_env.build_extension_zip(blender_env.PLATFORM)


@pytest.fixture(scope="session")
def ovrad(built_extension):
    """The ovrad extension installed from its zip and enabled: the module bl_ext.user_default.ovrad."""
    return blender_env.install_extension(built_extension, blender_env.EXTENSION_ID)


@pytest.fixture(scope="session")
def blender_commands():
    """What `blender -c ID ARGS` would run: `blender_commands.run(ID, ARGS)` returns the exit code.

    Request it together with (or before) the extension fixture whose commands a test calls.
    """
    return blender_env.cli_commands()


@pytest.fixture
def fresh_scene():
    """An empty factory scene; installed extensions stay enabled (see blender_env.reset_scene)."""
    return blender_env.reset_scene()


@pytest.fixture
def run_blender():
    """blender_env.run_blender: scripts/blender in a subprocess sharing the private user folder."""
    return blender_env.run_blender
