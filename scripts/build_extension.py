"""Build the ovrad extension zip(s) with Blender's own builder (shipped in the bpy module)."""

from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tomllib
import zipfile
from functools import cache
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent
DIST = ROOT / "dist"
MANIFEST = ROOT / "blender_manifest.toml"

sys.path.insert(0, str(ROOT / "scripts"))
import fetch_wheels  # noqa: E402  (sibling script, not a package)

# Names that must never be packed: numpy comes with Blender; tests and dev tools are not runtime.
FORBIDDEN_PARTS = ("tests/", "benchmarks/", "scenes/", ".venv/", ".ci/", "__pycache__/")
# The only script the extension needs at run time (the batch runner).
RUNTIME_SCRIPTS = ("scripts/ovrad_batch.py",)


@cache
def builder_path() -> Path:
    """blender_ext.py inside the installed bpy module, found without importing bpy (slow)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.origin:
        raise SystemExit("error: the bpy module is not installed in this Python (run `make venv`)")
    bpy_dir = Path(spec.origin).parent
    found = sorted(bpy_dir.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise SystemExit(f"error: Blender's extension builder is not in {bpy_dir}")
    return found[-1]


@cache
def builder() -> ModuleType:
    """Blender's builder as a module: its path filter tells which files a build packs."""
    spec = importlib.util.spec_from_file_location("blender_ext", builder_path())
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def manifest(root: Path = ROOT) -> dict:
    with (root / "blender_manifest.toml").open("rb") as fh:
        return tomllib.load(fh)


def zip_names(root: Path = ROOT, out_dir: Path = DIST, split_platforms: bool = False) -> dict[str, Path]:
    """The zip(s) a build writes, by platform ("" when not split), named as the builder does."""
    m = manifest(root)
    base = f"{m['id']}-{m['version']}"
    if not split_platforms:
        return {"": out_dir / f"{base}.zip"}
    return {p: out_dir / f"{base}-{p.replace('-', '_')}.zip" for p in m["platforms"]}


def source_files(root: Path = ROOT) -> dict[str, Path]:
    """Files (relative name -> path) the builder packs, wheels excepted, using its own filter."""
    ext = builder()
    patterns = manifest(root).get("build", {}).get("paths_exclude_pattern")
    match = ext.PathPatternMatch(patterns) if patterns else None

    def keep(rel: str, is_dir: bool) -> bool:
        rel = rel.replace(os.sep, "/")
        if match is None:
            return not os.path.basename(rel).startswith(".")
        return not match.test_path(rel + "/" if is_dir else rel)

    files = {rel.replace(os.sep, "/"): Path(p) for p, rel in ext.scandir_recursive(str(root), filter_fn=keep)}
    files["blender_manifest.toml"] = root / "blender_manifest.toml"
    return files


def is_up_to_date(zip_path: Path, root: Path = ROOT) -> bool:
    """True when the zip exists, is newer than every source and wheel, and packs the same files."""
    if not zip_path.is_file():
        return False
    files = source_files(root)
    wheels = [w.path for w in fetch_wheels.manifest_wheels(root / "blender_manifest.toml")]
    stamp = zip_path.stat().st_mtime
    if any(p.stat().st_mtime > stamp for p in [*files.values(), *wheels, Path(__file__)]):
        return False
    try:
        with zipfile.ZipFile(zip_path) as zf:
            packed = {n for n in zf.namelist() if not n.startswith("wheels/")}
    except zipfile.BadZipFile:
        return False
    return packed == set(files)  # a file added or removed since the build means rebuild


def verify_zip(zip_path: Path) -> list[str]:
    """Problems with a built zip (empty when fine): numpy, tests, dev scripts, missing entry points."""
    with zipfile.ZipFile(zip_path) as zf:
        names = zf.namelist()
    problems = []
    for n in names:
        low = n.lower()
        if "numpy" in low:
            problems.append(f"{n}: numpy is bundled with Blender and must not be shipped")
        if any(low.startswith(part) or f"/{part}" in low for part in FORBIDDEN_PARTS):
            problems.append(f"{n}: development file in the extension")
        if low.startswith("scripts/") and n not in RUNTIME_SCRIPTS:
            problems.append(f"{n}: development script in the extension")
    for required in ("blender_manifest.toml", "__init__.py"):
        if required not in names:
            problems.append(f"{required} is missing")
    return problems


def build(
    root: Path = ROOT,
    out_dir: Path = DIST,
    split_platforms: bool = False,
    force: bool = False,
    fetch: bool = True,
    quiet: bool = False,
) -> dict[str, Path]:
    """Fetch wheels, build (unless every zip is up to date), verify; returns zips by platform."""
    if fetch:
        fetch_wheels.fetch(fetch_wheels.manifest_wheels(root / "blender_manifest.toml"), quiet=quiet)
    if not (root / "__init__.py").is_file():
        raise SystemExit(f"error: {root / '__init__.py'} is missing: an add-on extension needs it")
    zips = zip_names(root, out_dir, split_platforms)
    if force or not all(is_up_to_date(z, root) for z in zips.values()):
        out_dir.mkdir(parents=True, exist_ok=True)  # the builder does not create it
        cmd = [sys.executable, str(builder_path()), "build", "--source-dir", str(root)]
        cmd += ["--output-dir", str(out_dir)]
        if split_platforms:
            cmd.append("--split-platforms")
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if not quiet or proc.returncode != 0:
            sys.stderr.write(proc.stdout + proc.stderr)
        if proc.returncode != 0:
            raise SystemExit(f"error: Blender's extension builder failed ({proc.returncode})")
    problems = [f"{z.name}: {p}" for z in zips.values() for p in verify_zip(z)]
    if problems:
        raise SystemExit("error: bad extension zip:\n  " + "\n  ".join(problems))
    return zips


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--output-dir", type=Path, default=DIST, help="where zips go (default dist/)")
    parser.add_argument("--split-platforms", action="store_true", help="one zip per platform")
    parser.add_argument("--platform", help="print only this platform's zip, e.g. linux-x64")
    parser.add_argument("--force", action="store_true", help="rebuild even when up to date")
    parser.add_argument("--no-fetch", action="store_true", help="do not download missing wheels")
    parser.add_argument("-q", "--quiet", action="store_true", help="print only the zip path(s)")
    args = parser.parse_args(argv)

    zips = build(
        out_dir=args.output_dir.resolve(),
        split_platforms=args.split_platforms or bool(args.platform),
        force=args.force,
        fetch=not args.no_fetch,
        quiet=args.quiet,
    )
    if args.platform:
        if args.platform not in zips:
            raise SystemExit(f"error: {args.platform} is not one of the manifest's platforms {list(zips)}")
        zips = {args.platform: zips[args.platform]}
    for z in zips.values():
        print(z)
    return 0


if __name__ == "__main__":
    sys.exit(main())
