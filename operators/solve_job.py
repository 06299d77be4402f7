"""The solve job: prepare + solve on plain arrays, in a worker thread or synchronously, with a
progress snapshot, cancel, error capture and the latest radiosity published for live display.
Imports no bpy (the worker thread must never touch Blender data), so it is tested without Blender.
"""

from __future__ import annotations

import threading
import time
import traceback
from dataclasses import dataclass

import numpy as np

from ..ovrad_addon import OvradError, Problem, SolveProgress, SolveState, prepare, solve

LIVE_INTERVAL = 0.5  # seconds between live writes of the intermediate radiosity
PREPARE_WEIGHT = 0.8  # share of the progress bar the form factors take when they are computed


@dataclass(frozen=True)
class JobStatus:
    """A snapshot of a running solve, for the panel, the status bar and printed lines."""

    stage: str
    fraction: float  # 0..1 over the whole job
    unshot: float | None  # unshot power / emitted, once shooting
    elapsed: float
    rays: int
    cancelling: bool

    @property
    def remaining(self) -> float | None:
        if self.fraction < 0.02:
            return None
        return self.elapsed * (1.0 - self.fraction) / self.fraction

    def text(self) -> str:
        parts = [f"{self.stage} {100 * self.fraction:.0f}%"]
        if self.unshot is not None:
            parts.append(f"unshot {self.unshot:.2e}")
        parts.append(f"{self.elapsed:.1f} s")
        if self.remaining is not None:
            parts.append(f"~{self.remaining:.0f} s left")
        return ("cancelling: " if self.cancelling else "") + ", ".join(parts)


class SolveJob:
    """prepare (unless a problem is given) + solve of inputs (anything with surfaces, atlas, lamps
    and settings, e.g. solve_inputs.SolveInputs). run() works on plain arrays only, so it may run
    in a worker thread; the main thread reads status() and latest() under the lock."""

    def __init__(self, inputs, live: bool, problem: Problem | None = None, listener=None):
        self.inputs = inputs
        self.live = live  # publish the intermediate radiosity for live display
        self.listener = listener  # called with the job after each progress update, in run()'s thread
        self._lock = threading.Lock()
        self._cancel = threading.Event()
        self.done = threading.Event()
        self.problem = problem
        self.reused = problem is not None
        self.state: SolveState | None = None
        self.error: Exception | None = None
        self.details = ""  # the traceback of an unexpected error (a bug)
        self._stage, self._fraction, self._unshot, self._rays = "starting", 0.0, None, 0
        self._latest, self._version, self._published = None, 0, 0.0
        self._start = time.perf_counter()

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def status(self) -> JobStatus:
        with self._lock:
            return JobStatus(
                self._stage,
                self._fraction,
                self._unshot,
                time.perf_counter() - self._start,
                self._rays,
                self.cancelled,
            )

    def latest(self) -> tuple[int, np.ndarray | None]:
        """(version, radiosity (n, 3)) most recently published."""
        with self._lock:
            return self._version, self._latest

    def stats(self) -> dict:
        """What a finished solve did (empty before it has a state): rays, transport_rays,
        transport_escaped (of those, the rays that left the scene: 0 leaves a sky out),
        form_factors_reused, overlaps_kept (patches whose C was kept with the atlas, not integrated),
        prepare_seconds (per stage of prepare(): index, overlap, transport; empty when the form
        factors were reused), prepare_peak_mb (peak resident MiB per stage of prepare(), the same
        way), shots, unshot_fraction, converged."""
        st = self.state
        if st is None:
            return {}
        return {
            "rays": int(st.rays),
            "transport_rays": int(self.problem.rays),
            "transport_escaped": int(self.problem.transport.escaped),
            "form_factors_reused": bool(self.reused),
            "overlaps_kept": int(self.problem.kept),
            "prepare_seconds": {} if self.reused else dict(self.problem.seconds),
            "prepare_peak_mb": {} if self.reused else dict(self.problem.memory),
            "shots": int(st.shots),
            "unshot_fraction": unshot_fraction(st),
            "converged": bool(st.converged),
        }

    def _update(self, stage, fraction, unshot=None, rays=None) -> bool:
        with self._lock:
            self._stage, self._fraction = stage, float(fraction)
            if unshot is not None:
                self._unshot = float(unshot)
            if rays is not None:
                self._rays = int(rays)
        if self.listener is not None:
            self.listener(self)
        return not self.cancelled

    def _publish(self, radiosity: np.ndarray, force: bool = False) -> None:
        now = time.perf_counter()
        if not force and now - self._published < 0.5 * LIVE_INTERVAL:
            return
        copy = np.array(radiosity, np.float64, copy=True)
        with self._lock:
            self._latest, self._version = copy, self._version + 1
        self._published = now

    def run(self) -> None:
        """The whole job; errors are kept in self.error (and a bug's traceback in self.details)."""
        try:
            weight = 0.0
            if self.problem is None:
                weight = PREPARE_WEIGHT

                def on_prepare(f, message):
                    return self._update(f"form factors ({message})", weight * f)

                self.problem = prepare(
                    self.inputs.surfaces,
                    self.inputs.atlas,
                    self.inputs.settings,
                    progress=on_prepare,
                    kept=getattr(self.inputs, "kept", ()),
                )
            self.state = st = self._solve(self.problem, weight)
            if st.converged:
                self._update("converged", 1.0, unshot_fraction(st), st.rays)
        except OvradError as e:
            self.error = e
        except Exception as e:  # a bug: keep the traceback for the report, never kill Blender
            self.error = e
            self.details = traceback.format_exc()
        finally:
            self.done.set()

    def _solve(self, problem: Problem, weight: float) -> SolveState:
        inp = self.inputs
        diverged = []

        def on_solve(p: SolveProgress) -> bool:
            if not np.isfinite(p.unshot):
                diverged.append(p.unshot)  # stop: a NaN never falls below the tolerance
                return False
            if self.live:
                self._publish(p.state.radiosity)
            return self._update("solving", weight + (1 - weight) * p.fraction, p.unshot, p.rays)

        state = solve(problem, inp.lamps, inp.settings, progress=on_solve, sky=getattr(inp, "sky", None))
        if diverged or not np.all(np.isfinite(state.radiosity)):
            raise OvradError(
                f"the solve diverged (invalid values) with the '{inp.settings.rule}' solver: "
                "use the exact solver, or generate the atlas again with other settings"
            )
        if self.live:
            self._publish(state.radiosity, force=True)
        return state


def unshot_fraction(state: SolveState) -> float:
    """The last unshot fraction a solve state recorded (0 before any shot)."""
    return float(state.history[-1][1]) if state.history else 0.0


class ProgressPrinter:
    """A job listener printing progress lines of a synchronous solve (`blender -b`): at most one
    per `interval` seconds, and the last."""

    def __init__(self, interval: float = 1.0, write=print):
        self.interval = interval
        self.write = write
        self._printed = -np.inf

    def __call__(self, job: SolveJob) -> None:
        now = time.perf_counter()
        status = job.status()
        if now - self._printed >= self.interval or status.fraction >= 1.0:
            self._printed = now
            self.write(f"ovrad: {status.text()}", flush=True)
