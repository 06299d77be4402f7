"""Run a benchmark once per size, each in its own process (so max RSS is that size's alone), and
write the rows as CSV. The benchmark script answers `--one SIZE [extra]` with one JSON line."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path


def run_sizes(script: str, sizes, extra: list[str], show: Callable[[dict], str]) -> list[dict]:
    """One row (dict) per size, printed with `show` as it arrives."""
    rows = []
    for size in sizes:
        proc = subprocess.run(
            [sys.executable, script, "--one", str(size), *extra], capture_output=True, text=True, check=True
        )
        rows.append(json.loads(proc.stdout.strip().splitlines()[-1]))
        print(show(rows[-1]), flush=True)
    return rows


def write_csv(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {path}")
