"""The Solve and Cancel Solve operators: read the inputs, run a SolveJob, write or restore.

In the UI the engine runs in a worker thread (solve_job.SolveJob.run never touches bpy); a
window-manager timer drives the operator's modal(), which shows progress and writes the
intermediate radiosity every solve_job.LIVE_INTERVAL seconds. Without a window (`blender -b`) the
same job runs synchronously and prints progress lines. A prepared problem (form factors) is reused
from solution's cache when only lamps or emission changed. Code that runs a solve and needs its
result (the batch script) registers a listener with add_listener().
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import bpy

from ..ovrad_addon import OvradError
from . import attributes, polls, solution, solve_job, solve_result
from .solve_inputs import SolveInputs, read_inputs
from .solve_job import SolveJob
from .window import tag_redraw

TIMER_STEP = 0.1  # seconds between modal() ticks

# The solve running now (UI or synchronous), so the panel and ovrad.cancel_solve can find it.
_RUNNING: SolveJob | None = None
# Called with each finished job (converged, cancelled or failed) after its result is written.
_LISTENERS: list[Callable[[SolveJob], None]] = []


def running() -> SolveJob | None:
    """The solve running now, if any."""
    return _RUNNING


def add_listener(listener: Callable[[SolveJob], None]) -> Callable[[], None]:
    """Call listener(job) each time a solve operator ends; returns the function that removes it."""
    _LISTENERS.append(listener)
    return lambda: _LISTENERS.remove(listener)


def make_job(inputs: SolveInputs, live: bool, listener=None) -> SolveJob:
    """A job for these inputs, reusing the cached problem when it was prepared for them."""
    problem = solution.cached_problem(inputs, solution.transport_key(inputs.settings))
    return SolveJob(inputs, live, problem=problem, listener=listener)


class OVRAD_OT_solve(bpy.types.Operator):
    bl_idname = "ovrad.solve"
    bl_label = "Solve"
    bl_description = (
        "Compute the light on every mesh with an atlas (lamps, emissive materials, interreflections), "
        "stored as 'ovrad_radiosity' on the atlas objects; Esc cancels"
    )
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        # No atlas is not a poll failure: execute() says what to do about it.
        return polls.passes(cls, [(_RUNNING is None, "A solve is already running")])

    def _read(self, context) -> SolveInputs | None:
        attributes.keep_atlases_out_of_renders()  # atlases of older files rendered: mend them
        try:
            inputs = read_inputs(context)
        except OvradError as e:
            self.report({"ERROR"}, str(e))
            return None
        for w in inputs.warnings:
            self.report({"WARNING"}, w)
        return inputs

    def execute(self, context):
        """Synchronous: what `blender -b` scripts and tests run."""
        global _RUNNING
        inputs = self._read(context)
        if inputs is None:
            return {"CANCELLED"}
        job = make_job(inputs, live=False, listener=solve_job.ProgressPrinter())
        if job.reused:
            print("ovrad: reusing the form factors of the last solve (only lamps or emission changed)")
        _RUNNING = job
        try:
            job.run()
        finally:
            _RUNNING = None
        return self._end(context, job, None)

    def _end(self, context, job, saved):
        status, message = solve_result.finish(context.scene, job, saved)
        for listener in tuple(_LISTENERS):
            listener(job)
        if status == "FINISHED":
            self.report({"INFO"}, message)
            return {"FINISHED"}
        self.report({"ERROR"} if status == "ERROR" else {"INFO"}, message)
        return {"CANCELLED"}

    def invoke(self, context, event):
        if context.window is None or bpy.app.background:
            return self.execute(context)
        return self._start(context)

    def _start(self, context):
        """Read the scene, start the worker and the timer that drives modal()."""
        global _RUNNING
        inputs = self._read(context)
        if inputs is None:
            return {"CANCELLED"}
        self._job = make_job(inputs, live=True)
        self._saved = solve_result.save_state(context.scene, inputs.atlas_names)
        self._written = 0
        self._last_write = time.perf_counter()
        self._thread = threading.Thread(target=self._job.run, name="ovrad solve", daemon=True)
        _RUNNING = self._job
        self._thread.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(TIMER_STEP, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        return {"RUNNING_MODAL"}

    def _cleanup(self, context) -> None:
        global _RUNNING
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        _RUNNING = None
        tag_redraw(context)

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC" and event.value == "PRESS":
            job.cancel()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if not job.done.is_set():
            now = time.perf_counter()
            version, radiosity = job.latest()
            live = now - self._last_write >= solve_job.LIVE_INTERVAL
            if version != self._written and live and not job.cancelled:
                solve_result.write_radiosity(context.scene, job.inputs, radiosity)
                self._written, self._last_write = version, now
            p = job.status()
            context.window_manager.progress_update(int(100 * p.fraction))
            if context.workspace is not None:
                context.workspace.status_text_set(f"ovrad: {p.text()} (Esc to cancel)")
            tag_redraw(context)
            return {"PASS_THROUGH"}
        self._thread.join()
        self._cleanup(context)
        return self._end(context, job, self._saved)

    def cancel(self, context):
        # Blender ends the operator (file closed, window gone): stop the worker, leave the scene as it was.
        self._job.cancel()
        self._thread.join(timeout=30)
        self._cleanup(context)
        try:
            solve_result.restore_state(context.scene, self._saved)
        except (ReferenceError, RuntimeError, AttributeError):
            pass  # the data is being freed (a file is loading): nothing left to restore


class OVRAD_OT_cancel_solve(bpy.types.Operator):
    bl_idname = "ovrad.cancel_solve"
    bl_label = "Cancel Solve"
    bl_description = "Stop the running solve; the scene is left as it was before it started"

    @classmethod
    def poll(cls, context):
        return polls.passes(cls, [(_RUNNING is not None and not _RUNNING.cancelled, "No solve is running")])

    def execute(self, context):
        _RUNNING.cancel()
        return {"FINISHED"}


def unregister() -> None:
    """Stop a running solve and free the cached problem (the add-on is being disabled)."""
    if _RUNNING is not None:
        _RUNNING.cancel()
    solution.clear_cache()


classes = (OVRAD_OT_solve, OVRAD_OT_cancel_solve)
