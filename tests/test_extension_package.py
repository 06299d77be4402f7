"""The extension package: manifest wheels, the built linux zip's contents, and installing it."""

from __future__ import annotations

import re
import tomllib
import zipfile

import blender_env
from blender_env import ROOT

MANIFEST = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
PLATFORMS = {"linux-x64", "windows-x64", "macos-arm64"}


def wheel_parts(entry: str) -> tuple[str, str, str, str]:
    """(name, version, python tag, platform tag) of a manifest wheel entry."""
    parts = entry.rsplit("/", 1)[-1].removesuffix(".whl").split("-")
    return parts[0], parts[1], parts[-3], parts[-1]


def test_manifest_fields():
    assert MANIFEST["id"] == "ovrad" and MANIFEST["type"] == "add-on"
    assert MANIFEST["blender_version_min"] == "4.2.0"
    assert MANIFEST["license"] == ["SPDX:GPL-3.0-or-later"]
    assert set(MANIFEST["platforms"]) == PLATFORMS


def test_manifest_wheels_cover_every_platform_and_never_numpy():
    builder = blender_env.build_script().builder()
    covered: dict[str, set[str]] = {}
    for entry in MANIFEST["wheels"]:
        name, _, python_tag, platform_tag = wheel_parts(entry)
        assert name.lower() != "numpy", "Blender bundles numpy"
        assert python_tag == "cp311", "Blender 4.2-5.0 bundle Python 3.11"
        for tag in platform_tag.split("."):
            for platform in builder.blender_platforms_from_wheel_platform(tag):
                covered.setdefault(name, set()).add(platform)
    assert covered.keys() == {"embreex", "scipy"}
    for name, platforms in covered.items():
        assert platforms >= PLATFORMS, f"{name} lacks wheels for {PLATFORMS - platforms}"


def test_shipped_scipy_is_the_one_tests_use():
    shipped = {wheel_parts(w)[1] for w in MANIFEST["wheels"] if wheel_parts(w)[0] == "scipy"}
    pinned = re.search(r"^scipy==(\S+)", (ROOT / "requirements-dev.txt").read_text(), re.M)
    assert pinned and shipped == {pinned.group(1)}


def test_linux_zip_contents(built_extension):
    assert built_extension.name == f"ovrad-{MANIFEST['version']}-linux_x64.zip"
    assert blender_env.build_script().verify_zip(built_extension) == []
    with zipfile.ZipFile(built_extension) as zf:
        names = set(zf.namelist())
        packed_manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
    wheels = {n for n in names if n.startswith("wheels/")}
    assert wheels and all(("linux" in w) for w in wheels), wheels
    assert packed_manifest["build"]["generated"]["platforms"] == ["linux-x64"]
    assert not any(n.startswith(("tests/", "benchmarks/", "scenes/", ".")) for n in names)
    assert ("scripts/ovrad_batch.py" in names) == (ROOT / "scripts" / "ovrad_batch.py").is_file()
    assert not any(n.startswith("scripts/") and n != "scripts/ovrad_batch.py" for n in names)
    assert "__init__.py" in names and any(n.startswith("ovrad_addon/") for n in names)


def test_zip_is_reused_while_up_to_date(built_extension):
    # Built again first: a source edited since the session's build makes it (rightly) stale.
    assert blender_env.build_extension_zip() == built_extension
    assert blender_env.build_script().is_up_to_date(built_extension)
    mtime = built_extension.stat().st_mtime_ns
    assert blender_env.build_extension_zip() == built_extension
    assert built_extension.stat().st_mtime_ns == mtime


def test_installed_extension_is_enabled(ovrad):
    import addon_utils

    assert ovrad.__name__ == "bl_ext.user_default.ovrad"
    assert addon_utils.check("bl_ext.user_default.ovrad") == (True, True)
