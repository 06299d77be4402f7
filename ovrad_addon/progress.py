"""Progress of the engine's long stages (building an atlas, preparing a solve), which can cancel."""

from __future__ import annotations

from collections.abc import Callable

from .errors import OvradError

StageCallback = Callable[[float, str], bool]
"""progress(fraction done in [0, 1], what is being done) -> False to cancel."""


def report_stage(progress: StageCallback | None, fraction: float, message: str) -> None:
    """Tell progress (if any) where the work stands; raise OvradError("cancelled") if it returns False."""
    if progress is not None and progress(fraction, message) is False:
        raise OvradError("cancelled")
