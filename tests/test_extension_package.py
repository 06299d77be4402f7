"""The extension package: manifest wheels, the built linux zip's contents, and installing it."""

from __future__ import annotations

import re
import tomllib
import zipfile

import pytest

import blender_env
from blender_env import ROOT

MANIFEST = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
PLATFORMS = {"linux-x64", "windows-x64", "macos-arm64", "macos-x64"}
# The supported Blenders (make test-versions) and the Python each bundles. Blender 5.0 and later
# have no Intel-mac build: macos-x64 serves 4.2 to 4.5 only.
BLENDER_PYTHONS = {"4.2": (3, 11), "4.5": (3, 11), "5.0": (3, 11), "5.3": (3, 13)}
BLENDERS_ON = {p: set(BLENDER_PYTHONS) for p in PLATFORMS} | {"macos-x64": {"4.2", "4.5"}}
# scipy per Python (blender_manifest.toml says why): one wheel of each package per Blender.
SCIPY_FOR = {(3, 11): "1.15.3", (3, 13): "1.17.1"}


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
        assert python_tag in ("cp311", "cp313"), "Blender 4.2-5.0 bundle Python 3.11, 5.1+ 3.13"
        for tag in platform_tag.split("."):
            for platform in builder.blender_platforms_from_wheel_platform(tag):
                covered.setdefault(name, set()).add(platform)
    assert covered.keys() == {"embreex", "scipy"}
    for name, platforms in covered.items():
        assert platforms >= PLATFORMS, f"{name} lacks wheels for {PLATFORMS - platforms}"


def test_shipped_scipy_is_the_one_tests_use():
    shipped = {wheel_parts(w)[1] for w in MANIFEST["wheels"] if wheel_parts(w)[0] == "scipy" and "cp311" in w}
    pinned = re.search(r"^scipy==(\S+)", (ROOT / "requirements-dev.txt").read_text(), re.M)
    assert pinned and shipped == {pinned.group(1)}


def installer_picks(wheels: list[str], python: tuple[int, int], platform: str) -> dict[str, str]:
    """The wheels Blender's installer installs from a zip's list: those whose Python tag is this
    Python's and whose platform tag is this platform's (bl_pkg's wheel filter, the same rule in
    4.2 and 5.3), then one per package (the highest version); returns package -> file name."""
    builder = blender_env.build_script().builder()
    picked: dict[str, str] = {}
    for entry in wheels:
        name, version, python_tag, platform_tag = wheel_parts(entry)
        if builder.python_versions_from_wheel_python_tag(python_tag) != {python}:
            continue
        if not any(
            platform in builder.blender_platforms_from_wheel_platform(t) for t in platform_tag.split(".")
        ):
            continue
        if name not in picked or wheel_parts(picked[name])[1] < version:
            picked[name] = entry.rsplit("/", 1)[-1]
    return picked


@pytest.mark.parametrize("platform", sorted(PLATFORMS))
def test_each_zip_installs_the_right_wheels_on_every_supported_blender(platform):
    """Every platform zip holds, for each Blender of that platform, one embreex and one scipy
    wheel of its Python and platform (never numpy), and nothing another Blender cannot use."""
    zips = blender_env.build_script().build(split_platforms=True, quiet=True, fetch=False)
    with zipfile.ZipFile(zips[platform]) as zf:
        packed = [n for n in zf.namelist() if n.startswith("wheels/")]
        generated = tomllib.loads(zf.read("blender_manifest.toml").decode())["build"]["generated"]
    assert generated["platforms"] == [platform]
    assert sorted(w.removeprefix("./") for w in generated["wheels"]) == sorted(packed)
    used = set()
    for blender in sorted(BLENDERS_ON[platform]):
        python = BLENDER_PYTHONS[blender]
        picked = installer_picks(packed, python, platform)
        assert picked.keys() == {"embreex", "scipy"}, (blender, picked)
        assert wheel_parts(picked["scipy"])[1] == SCIPY_FOR[python], (blender, picked)
        assert wheel_parts(picked["embreex"])[1] == "4.4.0.post1"
        used |= {f"wheels/{w}" for w in picked.values()}
    assert used == set(packed), f"{platform}: wheels no supported Blender installs: {set(packed) - used}"


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


@pytest.mark.versions
def test_installed_extension_is_enabled(ovrad):
    import addon_utils

    assert ovrad.__name__ == "bl_ext.user_default.ovrad"
    assert addon_utils.check("bl_ext.user_default.ovrad") == (True, True)


@pytest.mark.versions
def test_the_installer_installed_this_pythons_wheels(ovrad):
    """Blender's installer unpacked the scipy and embreex of this Python from the zip (which holds
    two scipy versions) into the extensions' site-packages, and no numpy (Blender's own is used)."""
    import sys
    from pathlib import Path

    import bpy

    python = sys.version_info[:2]
    site = Path(bpy.utils.user_resource("EXTENSIONS"), ".local", "lib", "python{}.{}".format(*python))
    dists = sorted(p.name for p in site.glob("site-packages/*.dist-info"))
    assert dists == ["embreex-4.4.0.post1.dist-info", f"scipy-{SCIPY_FOR[python]}.dist-info"]
