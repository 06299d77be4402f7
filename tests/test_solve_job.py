"""The solve job without Blender: status text, cancel, error capture, live publishing and printed
progress, on a stand-in engine (operators/solve_job.py imports no bpy)."""

from __future__ import annotations

import importlib
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
# The repository as a package whose __init__ (which imports bpy) is not run.
PACKAGE = "ovrad_glue_without_bpy"


def job_module():
    if PACKAGE not in sys.modules:
        pkg = types.ModuleType(PACKAGE)
        pkg.__path__ = [str(ROOT)]
        sys.modules[PACKAGE] = pkg
    return importlib.import_module(f"{PACKAGE}.operators.solve_job")


@pytest.fixture
def sj():
    return job_module()


def test_the_job_module_imports_no_blender_module():
    code = (
        f"import sys; sys.path.insert(0, {str(ROOT / 'tests')!r});"
        "import test_solve_job as t; t.job_module();"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('bpy', 'mathutils', 'bmesh')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def solved(rays=0):
    """A stand-in for a prepared problem."""
    return types.SimpleNamespace(
        rays=rays, kept=0, seconds={}, memory={}, transport=types.SimpleNamespace(escaped=0)
    )


class Inputs:
    surfaces = atlas = object()
    lamps = ()
    kept = ("a kept block of C",)

    def __init__(self, rule="exact"):
        self.settings = types.SimpleNamespace(rule=rule)


def fake_engine(sj, monkeypatch, reports, final=None, error=None):
    """solve() sends `reports` (fraction, unshot) with a state whose radiosity is the fraction,
    stops when the callback says so; prepare() returns a stand-in problem."""
    calls = {"prepare": 0, "solve": 0}

    def prepare(surfaces, atlas, settings, progress=None, kept=()):
        calls["prepare"] += 1
        assert kept == Inputs.kept, "the job hands the engine the overlaps the atlases keep"
        assert progress(0.5, "casting transport rays") in (True, False)
        seconds = {"index": 0.1, "overlap": 0.0, "transport": 2.0}
        memory = {"index": 500.0, "overlap": 510.0, "transport": 900.0}
        transport = types.SimpleNamespace(escaped=17)
        return types.SimpleNamespace(rays=123, kept=40, seconds=seconds, memory=memory, transport=transport)

    def solve(problem, lamps, settings, progress=None, sky=None):
        calls["solve"] += 1
        if error is not None:
            raise error
        state = sj.SolveState(radiosity=np.zeros((2, 3)), unshot=np.zeros((2, 3)), rays=7)
        for fraction, unshot in reports:
            state.radiosity = np.full((2, 3), fraction)
            state.shots += 1
            state.history.append((state.shots, unshot))
            if progress(sj.SolveProgress(fraction, unshot, 0.1, state.rays, state)) is False:
                return state
        state.converged = final is None
        if final is not None:
            state.radiosity = final
        return state

    monkeypatch.setattr(sj, "prepare", prepare)
    monkeypatch.setattr(sj, "solve", solve)
    return calls


def test_status_text_names_stage_percent_unshot_time_and_what_is_left(sj):
    status = sj.JobStatus("solving", 0.25, 3e-3, 2.0, 10, cancelling=False)
    assert status.remaining == pytest.approx(6.0)
    assert status.text() == "solving 25%, unshot 3.00e-03, 2.0 s, ~6 s left"
    early = sj.JobStatus("form factors (indexing surfaces)", 0.01, None, 0.5, 0, cancelling=True)
    assert early.remaining is None
    assert early.text() == "cancelling: form factors (indexing surfaces) 1%, 0.5 s"


def test_a_job_prepares_solves_once_and_reports_converged(sj, monkeypatch):
    calls = fake_engine(sj, monkeypatch, [(0.5, 1e-2), (0.9, 1e-3)])
    job = sj.SolveJob(Inputs(), live=False)
    job.run()
    assert calls == {"prepare": 1, "solve": 1}
    assert job.error is None and job.done.is_set() and job.state.converged
    status = job.status()
    assert (status.stage, status.fraction, status.unshot) == ("converged", 1.0, 1e-3)
    assert job.stats() == {
        "rays": 7,
        "transport_rays": 123,
        "transport_escaped": 17,
        "form_factors_reused": False,
        "overlaps_kept": 40,
        "prepare_seconds": {"index": 0.1, "overlap": 0.0, "transport": 2.0},
        "prepare_peak_mb": {"index": 500.0, "overlap": 510.0, "transport": 900.0},
        "shots": 2,
        "unshot_fraction": 1e-3,
        "converged": True,
    }


def test_a_given_problem_is_reused_and_takes_the_whole_progress_bar(sj, monkeypatch):
    calls = fake_engine(sj, monkeypatch, [(0.5, 1e-2)])
    seen = []
    job = sj.SolveJob(Inputs(), live=False, problem=solved(5), listener=lambda j: seen.append(j.status()))
    job.run()
    assert calls == {"prepare": 0, "solve": 1} and job.reused
    assert seen[0].stage == "solving" and seen[0].fraction == pytest.approx(0.5)


def test_cancel_stops_the_solve_at_its_next_report(sj, monkeypatch):
    fake_engine(sj, monkeypatch, [(0.1, 0.5), (0.2, 0.4), (0.3, 0.3)])
    job = sj.SolveJob(Inputs(), live=False, problem=solved(), listener=lambda j: j.cancel())
    job.run()
    assert job.cancelled and job.status().cancelling
    assert job.state.shots == 1 and not job.state.converged and job.error is None


def test_user_errors_are_kept_and_bugs_keep_their_traceback(sj, monkeypatch):
    fake_engine(sj, monkeypatch, [], error=sj.OvradError("no light: add a lamp"))
    job = sj.SolveJob(Inputs(), live=False, problem=solved())
    job.run()
    assert str(job.error) == "no light: add a lamp" and job.details == "" and job.done.is_set()
    fake_engine(sj, monkeypatch, [], error=ZeroDivisionError("oops"))
    job = sj.SolveJob(Inputs(), live=False, problem=solved())
    job.run()
    assert isinstance(job.error, ZeroDivisionError) and "ZeroDivisionError: oops" in job.details
    assert job.stats() == {}


def test_a_diverging_solve_is_stopped_and_named(sj, monkeypatch):
    fake_engine(sj, monkeypatch, [(0.1, float("nan")), (0.2, 0.1)])
    job = sj.SolveJob(Inputs("paper"), live=False, problem=solved())
    job.run()
    assert "diverged" in str(job.error) and "'paper' solver" in str(job.error)
    assert job.details == ""


def test_a_live_job_publishes_copies_of_the_radiosity_and_its_final_answer(sj, monkeypatch):
    monkeypatch.setattr(sj, "LIVE_INTERVAL", 0.0)
    fake_engine(sj, monkeypatch, [(0.25, 0.5), (0.5, 0.2)], final=np.full((2, 3), 9.0))
    assert sj.SolveJob(Inputs(), live=True).latest() == (0, None)
    versions = []
    job = sj.SolveJob(Inputs(), live=True, problem=solved(), listener=lambda j: versions.append(j.latest()))
    job.run()
    assert [float(r[0, 0]) for _, r in versions] == [0.25, 0.5]
    version, radiosity = job.latest()
    assert version == 3 and np.all(radiosity == 9.0)
    assert radiosity is not job.state.radiosity  # a copy: the worker may go on changing its own


def test_a_job_that_is_not_live_publishes_nothing(sj, monkeypatch):
    fake_engine(sj, monkeypatch, [(0.5, 0.2)])
    job = sj.SolveJob(Inputs(), live=False, problem=solved())
    job.run()
    assert job.latest() == (0, None)


def test_printed_progress_is_at_most_one_line_a_second_and_the_last(sj, monkeypatch):
    lines = []
    printer = sj.ProgressPrinter(write=lambda text, flush: lines.append(text))
    fake_engine(sj, monkeypatch, [(0.1, 0.5), (0.2, 0.4), (0.3, 0.3)])
    job = sj.SolveJob(Inputs(), live=False, problem=solved(), listener=printer)
    job.run()
    assert len(lines) == 2
    assert lines[0].startswith("ovrad: solving 10%, unshot 5.00e-01")
    assert lines[1].startswith("ovrad: converged 100%")
