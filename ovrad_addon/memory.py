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


def reset_peak() -> bool:
    """Start a new peak at the current resident size; False where the system cannot (then
    peak_mb() keeps counting from the process start)."""
    try:
        with open(_CLEAR, "w", encoding="ascii") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


class StagePeaks:
    """Peak memory per named stage: `with peaks.stage("solve"): ...` records that stage's peak
    (MiB, rounded); `.mb` maps stage names to peaks."""

    def __init__(self):
        self.mb: dict[str, float] = {}

    def stage(self, name: str):
        return _Stage(self, name)


class _Stage:
    def __init__(self, owner: StagePeaks, name: str):
        self.owner, self.name = owner, name

    def __enter__(self):
        reset_peak()
        return self

    def __exit__(self, *exc):
        peak = peak_mb()
        if peak is not None:
            self.owner.mb[self.name] = round(peak, 1)
        return False
