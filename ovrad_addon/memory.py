"""Peak resident memory of this process, per stage where the system allows it.

On Linux the kernel keeps the peak (VmHWM in /proc/self/status) and lets a process reset it
(writing 5 to /proc/self/clear_refs), so each stage's own peak is measured. Elsewhere only the
peak since the process started is known (getrusage), and a stage reports that.
"""

from __future__ import annotations

import sys

_STATUS = "/proc/self/status"
_CLEAR = "/proc/self/clear_refs"


def _linux_field(name: str) -> float | None:
    try:
        with open(_STATUS, encoding="ascii") as fh:
            for line in fh:
                if line.startswith(name + ":"):
                    return int(line.split()[1]) / 1024.0  # kB -> MiB
    except OSError:
        return None
    return None


def peak_mb() -> float | None:
    """The peak resident memory (MiB) since the process started or the last reset_peak()."""
    hwm = _linux_field("VmHWM")
    if hwm is not None:
        return hwm
    try:
        import resource
    except ImportError:  # Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


def resident_mb() -> float | None:
    """The resident memory (MiB) now (Linux; None elsewhere)."""
    return _linux_field("VmRSS")


# Stages open now (nested ones too): resetting the kernel's peak for an inner stage first hands
# the peak so far to every open stage, so an outer stage's peak stays its own.
_open: list[_Stage] = []


def reset_peak() -> bool:
    """Start a new peak at the current resident size; False where the system cannot (then
    peak_mb() keeps counting from the process start). Open stages keep the peak reached so far."""
    before = peak_mb()
    for stage in _open:
        stage.fold(before)
    try:
        with open(_CLEAR, "w", encoding="ascii") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


class StagePeaks:
    """Peak memory per named stage: `with peaks.stage("solve"): ...` records that stage's peak
    (MiB, rounded; stages may nest); `.mb` maps stage names to peaks."""

    def __init__(self):
        self.mb: dict[str, float] = {}

    def stage(self, name: str):
        return _Stage(self, name)


class _Stage:
    def __init__(self, owner: StagePeaks, name: str):
        self.owner, self.name, self.peak = owner, name, None

    def fold(self, value: float | None) -> None:
        if value is not None:
            self.peak = value if self.peak is None else max(self.peak, value)

    def __enter__(self):
        reset_peak()
        self.peak = None
        _open.append(self)
        return self

    def __exit__(self, *exc):
        _open.remove(self)
        self.fold(peak_mb())
        if self.peak is not None:
            self.owner.mb[self.name] = round(self.peak, 1)
        return False
