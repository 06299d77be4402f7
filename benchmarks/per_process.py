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


def write_csv(rows: list[dict], path, fields=None, append: bool = False, tag: str = "") -> None:
    """Write rows (dicts) to the CSV file path, its columns `fields` (default: every row's keys,
    in the order they first appear); append: after the rows already in the file. Prints where."""
    path = Path(path)
    if append and path.exists():
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh)) + list(rows)
    fields = list(fields) if fields is not None else list(dict.fromkeys(k for r in rows for k in r))
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    print(f"{tag + ': ' if tag else ''}wrote {path}", flush=True)
