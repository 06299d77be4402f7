"""Solve through the installed extension: generate -> solve -> bake on a furnace box, cancel, form-factor
reuse, live progress, and every input that must be refused without changing anything."""

from __future__ import annotations

import threading
import time

import blender_scenes
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

RHO, LE = 0.5, 1.0  # furnace: L = LE / (1 - RHO) = 2 everywhere inside


material = blender_scenes.principled
closed_box = blender_scenes.closed_box


select = blender_scenes.select


colors = blender_scenes.color_values


def atlas_of(name):
    return next(o for o in bpy.data.objects if o.get("ovrad_source") == name)


def state():
    """What a refused or cancelled solve must leave exactly as it was."""
    out = {"quantity": bpy.context.scene.ovrad.display_quantity}
    for o in bpy.data.objects:
        if o.type == "MESH":
            out[o.name] = {
                a.name: (a.data_type, a.domain, colors(o.data, a.name).tobytes())
                for a in o.data.attributes
                if a.data_type == "FLOAT_COLOR"
            }
            out[o.name]["__attributes"] = sorted(a.name for a in o.data.attributes)
    return out


def slow_engine(ovrad, monkeypatch, seconds=0.01):
    """Each solver step takes a little longer, so a solve lasts long enough to be watched."""
    job_module = ovrad.operators.solve_job
    real = job_module.solve

    def slow(*args, progress=None, **kwargs):
        def step(*report):
            time.sleep(seconds)
            return progress(*report)

        return real(*args, progress=None if progress is None else step, **kwargs)

    monkeypatch.setattr(job_module, "solve", slow)
    monkeypatch.setattr(job_module, "LIVE_INTERVAL", 0.0)  # write every published state


@pytest.fixture
def furnace(ovrad, fresh_scene):
    """A closed box, uniform emission LE and reflectance RHO, with its atlas (about 300 patches)."""
    fresh_scene.ovrad.patch_count = 300
    fresh_scene.ovrad.solve_tolerance = 1e-4
    box = closed_box(mat=material("furnace", base=(RHO,) * 3, emission=LE))
    select(box)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    return box


@pytest.mark.versions
def test_furnace_box_bakes_le_over_one_minus_rho_at_every_vertex(furnace, ovrad):
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    atlas = atlas_of("Box")
    attr = atlas.data.attributes["ovrad_radiosity"]
    assert (attr.data_type, attr.domain) == ("FLOAT_COLOR", "POINT")
    # Stored as radiance B / pi: the patch values of a furnace are the uniform answer.
    patches = colors(atlas.data, "ovrad_radiosity")
    np.testing.assert_allclose(patches[:, :3], LE / (1 - RHO), rtol=0.02)
    assert np.all(patches[:, 3] == 1.0)
    assert bpy.context.scene.ovrad.display_quantity == "RADIOSITY"
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    baked = colors(furnace.data, "ovrad_radiance")
    assert len(baked) == len(furnace.data.vertices)  # POINT domain by default
    # Every vertex, corners of the box included (three charts meet there).
    np.testing.assert_allclose(baked[:, :3], LE / (1 - RHO), rtol=0.02)


@pytest.mark.versions
def test_cancelling_a_synchronous_solve_leaves_the_scene_as_it_was(furnace, ovrad, monkeypatch):
    solve = ovrad.operators.solve
    assert bpy.ops.ovrad.solve() == {"FINISHED"}  # a first solution, which must survive
    furnace.data.materials[0].node_tree.nodes["Principled BSDF"].inputs[
        "Emission Strength"
    ].default_value = 3.0
    bpy.context.scene.ovrad.display_quantity = "OVERLAP"
    before = state()
    calls = []

    def cancel_at_first_line(job):
        calls.append(job.status().stage)
        assert bpy.ops.ovrad.cancel_solve() == {"FINISHED"}  # what the panel's Cancel button runs

    monkeypatch.setattr(ovrad.operators.solve_job, "ProgressPrinter", lambda: cancel_at_first_line)
    assert bpy.ops.ovrad.solve() == {"CANCELLED"}
    assert calls and state() == before and solve.running() is None
    # Cancelled while computing form factors, with another ray count (no cached problem to reuse).
    bpy.context.scene.ovrad.rays_per_point = 16
    calls.clear()
    assert bpy.ops.ovrad.solve() == {"CANCELLED"}
    assert calls[0].startswith("form factors") and state() == before


def test_cancelled_live_solve_restores_what_its_live_updates_wrote(furnace, ovrad, monkeypatch):
    """The modal operator's path, driven as its timer would: worker thread, live writes, cancel."""
    solve, result = ovrad.operators.solve, ovrad.operators.solve_result
    slow_engine(ovrad, monkeypatch)
    scene = bpy.context.scene
    scene.ovrad.display_quantity = "BETA"
    before = state()
    inputs = ovrad.operators.solve_inputs.read_inputs(bpy.context)
    job = solve.make_job(inputs, live=True)
    saved = result.save_state(scene, inputs.atlas_names)
    worker = threading.Thread(target=job.run)
    worker.start()
    written = 0
    deadline = time.time() + 60
    while written == 0 and time.time() < deadline:
        version, radiosity = job.latest()
        if version:
            result.write_radiosity(scene, inputs, radiosity)  # a live update, as modal() makes it
            written = version
        time.sleep(0.01)
    job.cancel()
    worker.join()
    assert written > 0, "no intermediate radiosity was published"
    assert not job.state.converged  # stopped half way
    assert (
        "ovrad_radiosity" in atlas_of("Box").data.attributes and scene.ovrad.display_quantity == "RADIOSITY"
    )
    status, message = result.finish(scene, job, saved)
    assert status == "CANCELLED" and "as it was" in message
    assert state() == before


def test_live_solve_to_the_end_writes_the_same_answer(furnace, ovrad):
    solve, result = ovrad.operators.solve, ovrad.operators.solve_result
    inputs = ovrad.operators.solve_inputs.read_inputs(bpy.context)
    job = solve.make_job(inputs, live=True)
    worker = threading.Thread(target=job.run)
    worker.start()
    worker.join()
    status, _ = result.finish(
        bpy.context.scene, job, result.save_state(bpy.context.scene, inputs.atlas_names)
    )
    assert status == "FINISHED" and job.state.converged
    np.testing.assert_allclose(colors(atlas_of("Box").data, "ovrad_radiosity")[:, :3], 2.0, rtol=0.02)
    p = job.status()
    assert p.fraction == pytest.approx(1.0) and p.unshot < 1e-4 and "unshot" in p.text()


@pytest.mark.versions
def test_changing_lamps_or_emission_only_reuses_the_form_factors(furnace, ovrad, capsys):
    ovrad.operators.solution.clear_cache()
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert "reusing the form factors" not in capsys.readouterr().out
    first = colors(atlas_of("Box").data, "ovrad_radiosity")[:, :3].copy()
    strength = furnace.data.materials[0].node_tree.nodes["Principled BSDF"].inputs["Emission Strength"]
    strength.default_value = 2.5 * LE
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert "reusing the form factors" in capsys.readouterr().out
    # Light is linear in the emission: the same solve, scaled.
    np.testing.assert_allclose(colors(atlas_of("Box").data, "ovrad_radiosity")[:, :3], 2.5 * first, rtol=1e-3)
    # A lamp added inside is only light too.
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", "POINT"))
    bpy.context.scene.collection.objects.link(lamp)
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert "reusing the form factors" in capsys.readouterr().out
    # Another reflectance changes the form factors' weights: computed again.
    furnace.data.materials[0].node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (
        0.3,
        0.3,
        0.3,
        1,
    )
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert "reusing the form factors" not in capsys.readouterr().out


def test_no_light_is_refused_and_changes_nothing(ovrad, fresh_scene):
    fresh_scene.ovrad.patch_count = 100
    box = closed_box(mat=material("dark", emission=0.0))
    select(box)
    bpy.ops.ovrad.generate_atlas()
    before = state()
    with pytest.raises(RuntimeError, match="no light"):
        bpy.ops.ovrad.solve()
    assert state() == before


def test_no_atlas_is_refused_with_what_to_do(ovrad, fresh_scene):
    closed_box(mat=material("lit", emission=1.0))
    with pytest.raises(RuntimeError, match="no atlas in the scene: select the meshes .* Generate Atlas"):
        bpy.ops.ovrad.solve()
    with pytest.raises(RuntimeError, match="Generate Atlas"):
        bpy.ops.ovrad.bake_vertex()


def test_missing_or_moved_source_mesh_is_refused(furnace, ovrad):
    before = state()
    furnace.location = (0.5, 0.0, 0.0)
    with pytest.raises(RuntimeError, match="generate the atlas again"):
        bpy.ops.ovrad.solve()
    assert state() == before
    bpy.data.objects.remove(furnace)
    with pytest.raises(RuntimeError, match="source mesh 'Box' of atlas 'Box_ovrad_atlas' is gone"):
        bpy.ops.ovrad.solve()


@pytest.mark.versions
def test_occluders_cast_shadows_and_world_light_counts(ovrad, fresh_scene, capfd):
    """A sun and a dim constant world over a floor, half of it under a card that has no atlas:
    the card still shadows; the world adds pi L to the open floor."""
    fresh_scene.ovrad.patch_count = 200
    bpy.ops.mesh.primitive_plane_add(size=4.0)
    floor = bpy.context.active_object
    floor.data.materials.append(material("floor", base=(0.5, 0.5, 0.5)))
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(1.0, 0.0, 1.0))
    card = bpy.context.active_object
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 2.0
    bpy.context.scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("World")
    if world.node_tree is None:
        world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.05, 0.05, 0.05, 1.0)
    fresh_scene.world = world
    select(floor)
    bpy.ops.ovrad.generate_atlas()
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    radiance = colors(atlas_of(floor.name).data, "ovrad_radiosity")[:, 0]
    centers = np.array([v.co for v in atlas_of(floor.name).data.vertices])
    shadowed = (centers[:, 0] > 0.3) & (np.abs(centers[:, 1]) < 0.7)
    lit = centers[:, 0] < -0.7
    # Lit: rho E / pi, E = 2 W/m^2 from the sun + pi 0.05 from the world (less the bit of sky
    # the card hides, plus a little light bounced off its underside: both under 1 %).
    assert np.median(radiance[lit]) == pytest.approx(0.5 * (2.0 + np.pi * 0.05) / np.pi, rel=0.03)
    assert np.all(radiance[shadowed] < 0.2 * np.median(radiance[lit]))
    assert card.name not in [o.get("ovrad_source") for o in bpy.data.objects]
    assert "world" not in capfd.readouterr().out


class Layout:
    """A UILayout stand-in: records what draw() shows (operator() returns settable properties)."""

    def __init__(self, shown):
        self.shown = shown

    def column(self, **_):
        return self

    box = row = column

    def prop(self, data, name, **_):
        assert name in data.bl_rna.properties, name
        self.shown.append(("prop", name))

    def operator(self, idname, **_):
        module, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, module), name), idname
        self.shown.append(("operator", idname))
        return type("Props", (), {})()

    def label(self, text="", **_):
        self.shown.append(("label", text))

    def separator(self, **_):
        pass


def draw(ovrad):
    """What the main panel and all its sub-panels show."""
    shown = []
    for cls in ovrad.ui.panel.classes:
        panel = type("P", (), {"layout": Layout(shown)})()
        cls.draw(panel, bpy.context)
    return shown


def test_panel_shows_solve_bake_and_while_solving_progress_and_cancel(furnace, ovrad, monkeypatch):
    shown = draw(ovrad)
    for name in ("solve_tolerance", "solve_rule", "rays_per_point", "bake_target", "bake_attribute"):
        assert ("prop", name) in shown
    for op in ("ovrad.solve", "ovrad.bake_vertex", "ovrad.preview"):
        assert ("operator", op) in shown
    assert ("operator", "ovrad.cancel_solve") not in shown
    bpy.context.scene.ovrad.bake_target = "IMAGE"
    assert ("operator", "ovrad.bake_image") in draw(ovrad)
    solve = ovrad.operators.solve
    job = solve.make_job(ovrad.operators.solve_inputs.read_inputs(bpy.context), live=True)
    job._update("solving", 0.5, 3e-3, 1000)
    monkeypatch.setattr(solve, "_RUNNING", job)
    shown = draw(ovrad)
    labels = [t for kind, t in shown if kind == "label"]
    assert ("operator", "ovrad.cancel_solve") in shown and ("operator", "ovrad.solve") not in shown
    assert "Solving: 50%" in labels and "Unshot energy: 3.00e-03" in labels
    assert any(t.startswith("Elapsed") and "remaining" in t for t in labels)
    with pytest.raises(RuntimeError, match="already running"):
        bpy.ops.ovrad.solve()


class Event:
    def __init__(self, type, value="NOTHING"):
        self.type, self.value = type, value


class FakeWindowManager:
    """What the modal solve asks of the window manager, recorded."""

    windows = ()

    def __init__(self):
        self.calls = []

    def event_timer_add(self, step, window=None):
        self.calls.append(("timer", step))
        return "timer"

    def event_timer_remove(self, timer):
        self.calls.append(("timer removed",))

    def modal_handler_add(self, op):
        self.calls.append(("modal",))

    def progress_begin(self, lo, hi):
        self.calls.append(("progress", lo, hi))

    def progress_update(self, value):
        self.calls.append(("update", value))

    def progress_end(self):
        self.calls.append(("progress end",))


class FakeWorkspace:
    def __init__(self):
        self.status = []

    def status_text_set(self, text):
        self.status.append(text)


def modal_driver(ovrad):
    """The operator's own invoke/modal code, run on a stand-in for the operator and a window context
    (background Blender runs no modal operators and has no window)."""
    cls = ovrad.operators.solve.OVRAD_OT_solve
    reports = []

    class Driver:
        _read, _start, _cleanup, _end, modal = cls._read, cls._start, cls._cleanup, cls._end, cls.modal

        def report(self, kind, message):
            reports.append((set(kind), message))

    context = type(
        "Context",
        (),
        {
            "scene": bpy.context.scene,
            "window": "window",
            "window_manager": FakeWindowManager(),
            "workspace": FakeWorkspace(),
            "view_layer": bpy.context.view_layer,
            "evaluated_depsgraph_get": staticmethod(bpy.context.evaluated_depsgraph_get),
        },
    )()
    return Driver(), context, reports


def run_modal(op, context, esc_after_writes=None):
    """Tick the timer until the operator ends; press Esc after that many live writes."""
    writes = []
    deadline = time.time() + 120
    while time.time() < deadline:
        result = op.modal(context, Event("TIMER"))
        if result != {"PASS_THROUGH"}:
            return result, writes
        if op._written and op._written not in writes:
            writes.append(op._written)
            if esc_after_writes is not None and len(writes) >= esc_after_writes:
                assert op.modal(context, Event("ESC", "PRESS")) == {"RUNNING_MODAL"}
        time.sleep(0.02)
    raise AssertionError("the modal solve did not end")


def test_modal_solve_updates_live_and_finishes_with_the_answer(furnace, ovrad, monkeypatch):
    solve = ovrad.operators.solve
    slow_engine(ovrad, monkeypatch)
    op, context, reports = modal_driver(ovrad)
    assert op._start(context) == {"RUNNING_MODAL"} and solve.running() is op._job
    result, writes = run_modal(op, context)
    assert result == {"FINISHED"} and solve.running() is None
    assert writes, "no live update was written while solving"
    np.testing.assert_allclose(colors(atlas_of("Box").data, "ovrad_radiosity")[:, :3], 2.0, rtol=0.02)
    status = context.workspace.status
    assert any(s and "%" in s and "Esc to cancel" in s for s in status) and status[-1] is None
    calls = [c[0] for c in context.window_manager.calls]
    assert calls[:3] == ["timer", "modal", "progress"] and calls[-2:] == ["timer removed", "progress end"]
    assert any("solved" in m for kind, m in reports if kind == {"INFO"})


def test_modal_solve_cancelled_with_esc_restores_the_scene(furnace, ovrad, monkeypatch):
    solve = ovrad.operators.solve
    slow_engine(ovrad, monkeypatch)
    before = state()
    op, context, reports = modal_driver(ovrad)
    op._start(context)
    result, writes = run_modal(op, context, esc_after_writes=1)
    assert writes and result == {"CANCELLED"} and solve.running() is None
    assert not op._job.state.converged  # stopped half way
    assert state() == before
    assert any("cancelled" in m for _, m in reports)


def test_a_diverging_solve_stops_with_an_error_and_changes_nothing(furnace, ovrad, monkeypatch):
    """A solver that produces NaN (seen with the paper's rule on atlases with empty supports) must
    not loop forever: the progress callback stops it and the operator reports it."""
    solve, job_module = ovrad.operators.solve, ovrad.operators.solve_job
    real = job_module.solve
    report = ovrad.ovrad_addon.SolveProgress

    def nan_solve(problem, lamps, settings, progress=None, state=None, sky=None):
        st = real(problem, lamps, settings, progress=lambda *a: False, state=state, sky=sky)
        st.radiosity = np.full_like(st.radiosity, np.nan)
        if progress is not None:
            assert progress(report(0.5, float("nan"), 0.1, 10, st)) is False  # the guard asks to stop
        return st

    monkeypatch.setattr(job_module, "solve", nan_solve)
    before = state()
    with pytest.raises(RuntimeError, match="the solve diverged .* use the exact solver"):
        bpy.ops.ovrad.solve()
    assert state() == before and solve.running() is None
