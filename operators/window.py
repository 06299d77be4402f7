"""What the window shows of a running operator: the progress cursor, and 3D views redrawn."""

from __future__ import annotations

from contextlib import contextmanager

import bpy


@contextmanager
def progress_bar(context):
    """A progress callback for the engine: the window's progress cursor when there is a UI, else nothing."""
    wm = context.window_manager
    shown = context.window is not None and not bpy.app.background
    if shown:
        wm.progress_begin(0, 1000)

    def update(fraction: float, message: str) -> bool:
        if shown:
            wm.progress_update(int(1000 * min(max(fraction, 0.0), 1.0)))
        return True

    try:
        yield update
    finally:
        if shown:
            wm.progress_end()


def tag_redraw(context) -> None:
    """Redraw every 3D view (the patches' display changed)."""
    wm = context.window_manager
    for window in wm.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()
