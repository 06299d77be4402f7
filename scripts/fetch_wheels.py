"""Download the wheels that blender_manifest.toml lists into wheels/ (skips files already present)."""

from __future__ import annotations

import argparse
import concurrent.futures
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = ROOT / "blender_manifest.toml"

# Blender bundles numpy; a second copy in an extension breaks every other add-on using it.
FORBIDDEN = ("numpy",)


@dataclass(frozen=True)
class Wheel:
    """One wheel file named in the manifest, split into the parts pip needs to find it."""

    path: Path
    name: str
    version: str
    python_tag: str
    abi_tag: str
    platform_tags: tuple[str, ...]

    @classmethod
    def from_manifest_entry(cls, entry: str, root: Path = ROOT) -> Wheel:
        path = (root / entry).resolve()
        stem = path.name.removesuffix(".whl")
        parts = stem.split("-")
        if not path.name.endswith(".whl") or len(parts) not in (5, 6):
            raise ValueError(f"not a wheel file name: {entry}")
        # name-version(-build)?-python-abi-platform; a compressed tag set joins tags with dots.
        name, version, python_tag, abi_tag, platform = parts[0], parts[1], *parts[-3:]
        return cls(path, name, version, python_tag, abi_tag, tuple(platform.split(".")))

    @property
    def python_version(self) -> str:
        # "cp311" -> "3.11": the interpreter Blender bundles, not the one running this script.
        digits = self.python_tag.removeprefix("cp").removeprefix("py")
        return f"{digits[0]}.{digits[1:]}" if len(digits) > 1 else digits

    def is_present(self) -> bool:
        """True when the file exists and is a readable zip (a half-written download is not)."""
        if not self.path.is_file() or self.path.stat().st_size == 0:
            return False
        try:
            with zipfile.ZipFile(self.path) as zf:
                return any(n.endswith(".dist-info/RECORD") for n in zf.namelist())
        except zipfile.BadZipFile:
            return False

    def pip_command(self, dest: Path) -> list[str]:
        cmd = [
            sys.executable,
            "-m",
            "pip",
            "download",
            "--only-binary=:all:",
            "--no-deps",
            "--disable-pip-version-check",
            "--python-version",
            self.python_version,
            "--implementation",
            self.python_tag[:2],
            "--abi",
            self.abi_tag,
            "--dest",
            str(dest),
        ]
        for tag in self.platform_tags:
            cmd += ["--platform", tag]
        return [*cmd, f"{self.name}=={self.version}"]


def manifest_wheels(manifest: Path = MANIFEST) -> list[Wheel]:
    """The wheels the manifest lists, refusing any that Blender already provides."""
    with manifest.open("rb") as fh:
        data = tomllib.load(fh)
    wheels = [Wheel.from_manifest_entry(w, manifest.parent) for w in data.get("wheels", [])]
    for w in wheels:
        if w.name.lower().replace("-", "_") in FORBIDDEN:
            raise SystemExit(f"error: {w.path.name}: Blender bundles {w.name}, never ship it")
    return wheels


def fetch_one(wheel: Wheel, quiet: bool = False) -> str:
    """Download one wheel through a temporary folder so wheels/ never holds a partial file."""
    wheel.path.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ovrad-wheel-", dir=wheel.path.parent) as tmp:
        proc = subprocess.run(wheel.pip_command(Path(tmp)), capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"pip download failed for {wheel.path.name}:\n{proc.stdout}\n{proc.stderr}")
        got = sorted(p.name for p in Path(tmp).glob("*.whl"))
        if wheel.path.name not in got:
            # pip picked another build of that version: the manifest must name what pip serves.
            raise RuntimeError(f"expected {wheel.path.name}, pip downloaded {got}")
        os.replace(Path(tmp) / wheel.path.name, wheel.path)
    return f"downloaded {wheel.path.name}" if not quiet else ""


def fetch(wheels: list[Wheel], jobs: int = 3, quiet: bool = False) -> list[Path]:
    """Fetch the missing wheels (a few at a time, downloads are network bound)."""
    missing = [w for w in wheels if not w.is_present()]
    if missing and not quiet:
        print(f"downloading {len(missing)} of {len(wheels)} wheels into {missing[0].path.parent}", flush=True)
    errors = []
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = {pool.submit(fetch_one, w, quiet): w for w in missing}
        for fut in concurrent.futures.as_completed(futures):
            try:
                msg = fut.result()
                if msg:
                    print(msg, flush=True)
            except Exception as exc:  # report every failure, not just the first
                errors.append(str(exc))
    if errors:
        raise SystemExit("error: " + "\n".join(errors))
    return [w.path for w in wheels]


def prune(wheels: list[Wheel], folder: Path) -> None:
    """Remove wheel files the manifest no longer names (old versions would bloat nothing, but confuse)."""
    keep = {w.path.name for w in wheels}
    for p in folder.glob("*.whl"):
        if p.name not in keep:
            print(f"removing   {p.name}")
            p.unlink()
    for p in folder.glob("ovrad-wheel-*"):
        shutil.rmtree(p, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--manifest", type=Path, default=MANIFEST, help="extension manifest to read")
    parser.add_argument("--jobs", type=int, default=3, help="parallel downloads (default 3)")
    parser.add_argument("--prune", action="store_true", help="delete wheels the manifest does not list")
    parser.add_argument("--check", action="store_true", help="only check; exit 1 when any wheel is missing")
    parser.add_argument("-q", "--quiet", action="store_true")
    args = parser.parse_args(argv)

    wheels = manifest_wheels(args.manifest)
    if args.check:
        missing = [w.path.name for w in wheels if not w.is_present()]
        for name in missing:
            print(f"missing    {name}")
        return 1 if missing else 0
    fetch(wheels, jobs=args.jobs, quiet=args.quiet)
    if args.prune and wheels:
        prune(wheels, wheels[0].path.parent)
    return 0


if __name__ == "__main__":
    sys.exit(main())
