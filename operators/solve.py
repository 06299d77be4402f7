"""Solve: atlas objects + their source meshes + occluders + lamps -> engine -> ovrad_radiosity on the atlases.

In the UI the engine runs in a worker thread (SolveJob.run never touches bpy); a window-manager
timer drives the operator's modal(), which shows progress and writes the intermediate radiosity
every LIVE_INTERVAL seconds. Without a window (`blender -b`) the same job runs synchronously and
prints progress lines. Prepared problems (form factors) are cached by a fingerprint of the geometry,
reflectances and atlases, so a re-solve after changing only lamps or emission strengths skips them.
"""

from __future__ import annotations

import hashlib
import threading
import time
import traceback
from dataclasses import dataclass, field, replace

import bpy
import numpy as np

from ..ovrad_addon import names
from ..ovrad_addon.atlas import Atlas, index_surfaces
from ..ovrad_addon.direct import DirectLight
from ..ovrad_addon.errors import OvradError
from ..ovrad_addon.lights import Lamp
from ..ovrad_addon.pipeline import Problem, SolveSettings, attach_sheets, direct_light, prepare, solve
from ..ovrad_addon.settings import AtlasSettings, ObjectSettings
from ..ovrad_addon.surfaces import Surfaces
from . import attributes, display, properties, scene_io

LIVE_INTERVAL = 0.5  # seconds between live writes of the intermediate radiosity
TIMER_STEP = 0.1  # seconds between modal() ticks
PREPARE_WEIGHT = 0.8  # share of the progress bar the form factors take when they are computed

# The last prepared problem: {"key", "rays", "problem"}. One entry only, as a problem holds C and R;
# kept across file loads (the key is the content, so a stale entry is never used).
_CACHE: dict = {}
# The solve running now (UI or synchronous), so the panel and ovrad.cancel_solve can find it.
_RUNNING: SolveJob | None = None


# --------------------------------------------------------------------------- reading the scene


@dataclass
class SolveInputs:
    """Everything the worker needs, read from bpy before it starts.

    atlas: all patches, atlas object after atlas object (atlas_names, counts); the first
    len(atlas_names) objects of surfaces are their source meshes, in the same order.
    """

    surfaces: Surfaces
    atlas: Atlas
    lamps: tuple[Lamp, ...]
    settings: SolveSettings
    atlas_names: list[str]
    counts: list[int]
    sources: list
    key: str
    warnings: list[str] = field(default_factory=list)

    def first_triangle(self, i: int) -> int:
        """Index in surfaces.triangles of receiver i's first triangle."""
        return int(np.flatnonzero(self.surfaces.object_index == i)[0])


def scene_atlases(scene) -> list[tuple]:
    """(atlas object, source mesh object) of every non-empty atlas in the scene, by atlas name."""
    found = sorted((o for o in scene.objects if attributes.is_atlas(o)), key=lambda o: o.name)
    if not found:
        raise OvradError("no atlas in the scene: select the meshes to light and press Generate Atlas first")
    pairs, seen = [], {}
    for obj in found:
        src_name = obj[names.PROP_SOURCE]
        src = bpy.data.objects.get(src_name)
        if src is None or src.type != "MESH":
            raise OvradError(
                f"the source mesh '{src_name}' of atlas '{obj.name}' is gone: generate the atlas again "
                f"or delete '{obj.name}'"
            )
        if src_name in seen:
            raise OvradError(f"'{seen[src_name]}' and '{obj.name}' are atlases of the same mesh: delete one")
        if src.name not in scene.objects:
            raise OvradError(f"the source mesh '{src_name}' of atlas '{obj.name}' is not in this scene")
        seen[src_name] = obj.name
        if attributes.patch_count(obj):
            pairs.append((obj, src))
    if not pairs:
        raise OvradError("every atlas in the scene is empty: generate the atlas again")
    return pairs


def fingerprint(surfaces: Surfaces, atlas: Atlas) -> str:
    """What the form factors depend on: world geometry, reflectances, receivers and the patches
    (not emission, which the engine reads at each solve, nor lamps)."""
    h = hashlib.blake2b(digest_size=20)
    arrays = (
        surfaces.vertices,
        surfaces.triangles,
        surfaces.object_index,
        surfaces.reflectance,
        surfaces.receiver,
        atlas.centers,
        atlas.normals,
        atlas.tangents,
        atlas.radii,
        atlas.shapes,
        atlas.thickness,
        atlas.min_cos,
        atlas.source_object,
    )
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    h.update(atlas.beta.encode())
    return h.hexdigest()


def light_key(surfaces: Surfaces, lamps) -> str:
    """What direct light depends on besides geometry: the lamps and every triangle's emission."""
    h = hashlib.blake2b(digest_size=20)
    h.update(repr(tuple(lamps)).encode())
    h.update(np.ascontiguousarray(surfaces.emission).tobytes())
    return h.hexdigest()


def _light_warnings(surfaces: Surfaces, lamps, scene, n_receivers: int) -> list[str]:
    """Light the engine will not see (world, emitters without atlas); raises when nothing emits."""
    out = []
    world = scene_io.read_world(scene)
    if world is None:
        out.append("the world is not a constant colour (nodes drive it): its light is ignored")
    elif world.max() > 0:
        rgb = ", ".join(f"{v:.3g}" for v in world)
        out.append(
            f"world light ({rgb}) is ignored: ovrad lights with lamps and emissive materials only "
            "(set the world's strength to 0 to compare with Cycles)"
        )
    receiver = surfaces.object_index < n_receivers
    emits = surfaces.emission.max(axis=1) > 0
    for i in np.unique(surfaces.object_index[emits & ~receiver]):
        out.append(
            f"'{surfaces.object_names[i]}' emits light but has no atlas: its light is ignored "
            "(generate an atlas on it too)"
        )
    lamp_power = sum(lamp.power * max(lamp.color) for lamp in lamps)
    if lamp_power <= 0 and not np.any(emits & receiver):
        raise OvradError(
            "no light: no lamp and no emissive material on a mesh with an atlas "
            "(add a lamp or an emissive material)"
        )
    return out


def read_inputs(context, settings: SolveSettings | None = None, need_light: bool = True) -> SolveInputs:
    """Read atlases, their source meshes (receivers), the other visible meshes (occluders) and lamps.

    Raises OvradError for anything that stops a solve; changes nothing.
    """
    scene = context.scene
    pairs = scene_atlases(scene)
    sources = [src for _, src in pairs]
    depsgraph = context.evaluated_depsgraph_get()
    meshes = scene_io.read_scene(depsgraph, sources, scene_io.default_occluders(context, sources))
    if meshes.objects[: meshes.n_receivers] != sources:
        kept = set(meshes.objects)
        lost = [s.name for s in sources if s not in kept]
        raise OvradError(f"{', '.join(map(repr, lost))} no longer has faces: generate its atlas again")
    parts = []
    for i, (obj, _) in enumerate(pairs):
        a = attributes.read_atlas(obj)
        parts.append(replace(a, source_object=np.full(len(a), i, np.int64)))
    atlas = Atlas.concatenate(parts)
    warnings = list(meshes.warnings)
    lamps = scene_io.read_lamps(depsgraph, warnings)
    if need_light:
        warnings += _light_warnings(meshes.surfaces, lamps, scene, len(sources))
    return SolveInputs(
        surfaces=meshes.surfaces,
        atlas=atlas,
        lamps=lamps,
        settings=settings or properties.solve_settings(scene.ovrad),
        atlas_names=[o.name for o, _ in pairs],
        counts=[len(p) for p in parts],
        sources=sources,
        key=fingerprint(meshes.surfaces, atlas),
        warnings=list(dict.fromkeys(warnings)),
    )


# --------------------------------------------------------------------------- the problem cache


def transport_key(settings) -> tuple[int, int]:
    """The solve settings the transport depends on: a cached problem is reused only if they match."""
    return settings.rays_per_point, settings.min_rays


def cached_problem(inputs: SolveInputs, transport: tuple[int, int] | None = None) -> Problem | None:
    """The cached problem of these inputs (any ray counts if transport is None), with the
    current surfaces: their emission may differ, the engine reads it at each solve."""
    if _CACHE.get("key") != inputs.key:
        return None
    if transport is not None and _CACHE["transport"] != transport:
        return None
    return replace(_CACHE["problem"], surfaces=inputs.surfaces)


def remember(inputs: SolveInputs, problem: Problem) -> None:
    _CACHE.clear()
    _CACHE.update(key=inputs.key, transport=transport_key(inputs.settings), problem=problem)


def clear_cache() -> None:
    """Forget the prepared problem (frees its memory)."""
    _CACHE.clear()


def locate(surfaces: Surfaces, atlas: Atlas) -> Problem:
    """A problem for reconstruction only (no C, no transport): the surfaces indexed as prepare()
    indexes them and the patches re-attached to their sheets. Much cheaper than prepare()."""
    sides = AtlasSettings(objects=tuple(ObjectSettings(sides="BOTH") for _ in surfaces.object_names))
    index = index_surfaces(surfaces, sides)
    return Problem(surfaces, attach_sheets(atlas, index), index, None, None, 0, {})


@dataclass
class Solution:
    """A solved scene, ready for reconstruction at surface points (bakes).

    problem: surfaces, index and atlas with sheets (C and transport may be None); radiosity
    (n, 3) B per patch, read back from the atlas objects; receivers: the source mesh objects,
    receiver i's triangles start at first_triangle[i] in problem.surfaces.triangles, in the
    order of its evaluated mesh's loop_triangles. first_shot (n, 3) and light: the solve's direct
    light, which bakes compute at their own points (None: everything from the patches).
    """

    problem: Problem
    radiosity: np.ndarray
    receivers: list
    first_triangle: list[int]
    first_shot: np.ndarray | None = None
    light: DirectLight | None = None


def load_solution(context) -> Solution:
    """The stored solve of the scene's atlases; raises OvradError if there is none (press Solve)."""
    inputs = read_inputs(context, need_light=False)
    parts = []
    for name, count in zip(inputs.atlas_names, inputs.counts, strict=True):
        mesh = bpy.data.objects[name].data
        if names.RADIOSITY not in mesh.attributes:
            raise OvradError(f"'{name}' has no solved light: press Solve first")
        parts.append(attributes.read_point_attribute(mesh, names.RADIOSITY)[:count, :3])
    radiosity = np.pi * np.concatenate(parts).astype(np.float64)
    problem = cached_problem(inputs) or locate(inputs.surfaces, inputs.atlas)
    firsts = [inputs.first_triangle(i) for i in range(len(inputs.sources))]
    first_shot, light = None, None
    if context.scene.ovrad.bake_direct:
        first_shot, light = _stored_direct(inputs, problem)
    return Solution(problem, radiosity, inputs.sources, firsts, first_shot, light)


def _stored_direct(inputs: SolveInputs, problem: Problem) -> tuple[np.ndarray | None, DirectLight | None]:
    """The first shot stored by the last solve and the direct light to compute at bake points;
    raises OvradError when the lamps or emission changed since (the split would not match)."""
    parts, key = [], light_key(inputs.surfaces, inputs.lamps)
    for name, count in zip(inputs.atlas_names, inputs.counts, strict=True):
        obj = bpy.data.objects[name]
        if names.DIRECT not in obj.data.attributes:
            return None, None  # solved by an older version: reconstruct everything from the patches
        if obj.get(names.PROP_LIGHT_KEY) != key:
            raise OvradError(
                "the lamps or emissive materials changed since the last solve: press Solve again "
                "before baking"
            )
        parts.append(attributes.read_point_attribute(obj.data, names.DIRECT)[:count, :3])
    first_shot = np.pi * np.concatenate(parts).astype(np.float64)
    return first_shot, direct_light(problem, inputs.lamps, inputs.settings)


# --------------------------------------------------------------------------- the job (no bpy)


@dataclass
class Progress:
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
    """prepare + solve on SolveInputs. run() works on plain arrays only, so it may run in a worker
    thread; the main thread reads progress() and latest() under the lock."""

    def __init__(self, inputs: SolveInputs, live: bool, listener=None):
        self.inputs = inputs
        self.live = live  # publish intermediate radiosity (costs a second solve call)
        self.listener = listener  # called with the job after each progress update, in run()'s thread
        self._lock = threading.Lock()
        self._cancel = threading.Event()
        self.done = threading.Event()
        self.problem = cached_problem(inputs, transport_key(inputs.settings))
        self.reused = self.problem is not None
        self.state = None
        self.error: Exception | None = None
        self.details = ""
        self._stage, self._fraction, self._unshot, self._rays = "starting", 0.0, None, 0
        self._latest, self._version, self._published = None, 0, 0.0
        self._start = time.perf_counter()

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def cancelled(self) -> bool:
        return self._cancel.is_set()

    def progress(self) -> Progress:
        with self._lock:
            return Progress(
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
        try:
            if self.problem is None:
                weight = PREPARE_WEIGHT

                def on_prepare(f, message):
                    return self._update(f"form factors ({message})", weight * f)

                self.problem = prepare(
                    self.inputs.surfaces, self.inputs.atlas, self.inputs.settings, progress=on_prepare
                )
            else:
                weight = 0.0
            self.state = st = self._solve(self.problem, weight)
            if st.converged:
                unshot = st.history[-1][1] if st.history else 0.0
                self._update("converged", 1.0, unshot, st.rays)
        except OvradError as e:
            self.error = e
        except Exception as e:  # a bug: keep the traceback for the report, never kill Blender
            self.error = e
            self.details = traceback.format_exc()
        finally:
            self.done.set()

    def _solve(self, problem: Problem, weight: float):
        inp = self.inputs

        diverged = []

        def on_solve(f, unshot, elapsed, rays):
            if not np.isfinite(unshot):
                diverged.append(unshot)  # stop: a NaN never falls below the tolerance
                return False
            if self.live and holder:
                self._publish(holder[0].radiosity)
            return self._update("solving", weight + (1 - weight) * f, unshot, rays)

        holder = []
        if not self.live:
            state = solve(problem, inp.lamps, inp.settings, progress=on_solve)
        else:
            # The progress callback does not see the state: stop after the first shot (one shooter,
            # so the tolerance's reference power stays that of the direct light), then continue
            # the same state, which solve() updates in place and the callback can read.
            state = solve(problem, inp.lamps, replace(inp.settings, batch=1), progress=lambda *a: False)
            if not (state.converged or self.cancelled) and np.all(np.isfinite(state.radiosity)):
                holder.append(state)
                state = solve(problem, inp.lamps, inp.settings, progress=on_solve, state=state)
        if diverged or not np.all(np.isfinite(state.radiosity)):
            raise OvradError(
                f"the solve diverged (invalid values) with the '{inp.settings.rule}' solver: "
                "use the exact solver, or generate the atlas again with other settings"
            )
        if self.live:
            self._publish(state.radiosity, force=True)
        return state


def print_progress(job: SolveJob) -> None:
    """Progress lines of a synchronous solve (`blender -b`): at most one a second, and the last."""
    now = time.perf_counter()
    p = job.progress()
    if now - getattr(job, "_printed", 0.0) >= 1.0 or p.fraction >= 1.0:
        job._printed = now
        print(f"ovrad: {p.text()}", flush=True)


def running() -> SolveJob | None:
    """The solve running now, if any."""
    return _RUNNING


# --------------------------------------------------------------------------- writing the result


@dataclass
class SavedState:
    """What a solve changes, as it was before: per atlas object its radiosity attribute (or None)
    and its display quantity, and the scene's display setting."""

    quantity: str
    objects: dict


def save_state(scene, atlas_names: list[str]) -> SavedState:
    saved = {}
    for name in atlas_names:
        obj = bpy.data.objects[name]
        mesh = obj.data
        old = {
            attr: attributes.read_point_attribute(mesh, attr) if attr in mesh.attributes else None
            for attr in (names.RADIOSITY, names.DIRECT)
        }
        mod = obj.modifiers.get(names.DISPLAY_MODIFIER)
        q = None
        if mod is not None and mod.node_group is not None:
            q = mod.get(display.input_identifier(mod.node_group, "Quantity"))
        saved[name] = (old, None if q is None else int(q), obj.get(names.PROP_LIGHT_KEY))
    return SavedState(scene.ovrad.display_quantity, saved)


def restore_state(scene, saved: SavedState) -> None:
    """Put back what save_state() saw (a cancelled or failed solve leaves the scene as before)."""
    if scene.ovrad.display_quantity != saved.quantity:
        scene.ovrad.display_quantity = saved.quantity
    for name, (old, quantity, key) in saved.objects.items():
        obj = bpy.data.objects.get(name)
        if obj is None or not attributes.is_atlas(obj):
            continue
        mesh = obj.data
        for attr_name, values in old.items():
            if values is None:
                attr = mesh.attributes.get(attr_name)
                if attr is not None:
                    mesh.attributes.remove(attr)
            elif len(values) == len(mesh.vertices):
                attributes.write_point_attribute(mesh, attr_name, values, "FLOAT_COLOR")
        if key is None:
            obj.pop(names.PROP_LIGHT_KEY, None)
        elif obj.get(names.PROP_LIGHT_KEY) != key:
            obj[names.PROP_LIGHT_KEY] = key
        if quantity is not None:
            display.set_input(obj, "Quantity", quantity)
        mesh.update()


def write_radiosity(
    scene, inputs: SolveInputs, radiosity: np.ndarray, first_shot: np.ndarray | None = None
) -> list[str]:
    """Radiance B/pi (FLOAT_COLOR, alpha 1) on each atlas object, shown by the display, and the
    first shot's share of it (direct light, for bakes) with the key of the light it came from
    (first_shot None: an intermediate write, which removes both); returns the names of atlas
    objects that changed under the solve (skipped)."""
    skipped = []
    radiance = np.asarray(radiosity, np.float64) / np.pi
    direct = radiance if first_shot is None else np.asarray(first_shot, np.float64) / np.pi
    key = light_key(inputs.surfaces, inputs.lamps)
    start = 0
    for name, count in zip(inputs.atlas_names, inputs.counts, strict=True):
        part = radiance[start : start + count]
        part_direct = direct[start : start + count]
        start += count
        obj = bpy.data.objects.get(name)
        if obj is None or not attributes.is_atlas(obj) or attributes.patch_count(obj) != count:
            skipped.append(name)
            continue
        attributes.write_point_attribute(obj.data, names.RADIOSITY, part, "FLOAT_COLOR")
        if first_shot is None:
            # a live, intermediate write: no split to bake from until the solve has finished
            # (a bake would otherwise add direct light to a radiosity that holds it already)
            old = obj.data.attributes.get(names.DIRECT)
            if old is not None:
                obj.data.attributes.remove(old)
            obj.pop(names.PROP_LIGHT_KEY, None)
        else:
            attributes.write_point_attribute(obj.data, names.DIRECT, part_direct, "FLOAT_COLOR")
            obj[names.PROP_LIGHT_KEY] = key
        obj.data.update()
        display.set_quantity(obj, "RADIOSITY")
    if scene.ovrad.display_quantity != "RADIOSITY":
        scene.ovrad.display_quantity = "RADIOSITY"
    return skipped


def summary(job: SolveJob) -> str:
    st, inp = job.state, job.inputs
    reuse = "form factors reused" if job.reused else f"{job.problem.rays:,} transport rays"
    unshot = st.history[-1][1] if st.history else 0.0
    return (
        f"ovrad: solved {len(inp.atlas):,} patches, {len(inp.lamps)} lamp(s), {reuse}, "
        f"{st.shots:,} shots, unshot {unshot:.1e}, {job.progress().elapsed:.2f} s"
    )


def finish(scene, job: SolveJob, saved: SavedState | None) -> tuple[str, str]:
    """Write the result of a finished job, or restore the scene; returns (status, message), status
    one of FINISHED, CANCELLED, ERROR."""
    if job.problem is not None:  # also after a cancelled solve: the next one starts from it
        remember(job.inputs, job.problem)
    if job.error is not None and not (job.cancelled and str(job.error) == "cancelled"):
        if saved is not None:
            restore_state(scene, saved)
        if job.details:
            print(job.details)
            return "ERROR", f"ovrad: internal error ({job.error!r}); see the console"
        return "ERROR", str(job.error)
    if job.cancelled or job.state is None:
        if saved is not None:
            restore_state(scene, saved)
        return "CANCELLED", "ovrad: solve cancelled; the scene is as it was"
    skipped = write_radiosity(scene, job.inputs, job.state.radiosity, job.state.first_shot)
    message = summary(job)
    if skipped:
        message += f" (changed during the solve, not written: {', '.join(skipped)})"
    if not job.state.converged:
        message += " (not converged)"
    return "FINISHED", message


# --------------------------------------------------------------------------- operators


def _tag_redraw(context) -> None:
    wm = context.window_manager
    for window in wm.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


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
        if _RUNNING is not None:
            cls.poll_message_set("A solve is already running")
            return False
        return True

    def _read(self, context) -> SolveInputs | None:
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
        job = SolveJob(inputs, live=False, listener=lambda j: print_progress(j))
        if job.reused:
            print("ovrad: reusing the form factors of the last solve (only lamps or emission changed)")
        _RUNNING = job
        try:
            job.run()
        finally:
            _RUNNING = None
        return self._end(context, job, None)

    def _end(self, context, job, saved):
        status, message = finish(context.scene, job, saved)
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
        self._job = SolveJob(inputs, live=True)
        self._saved = save_state(context.scene, inputs.atlas_names)
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
        _tag_redraw(context)

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
            if version != self._written and now - self._last_write >= LIVE_INTERVAL and not job.cancelled:
                write_radiosity(context.scene, job.inputs, radiosity)
                self._written, self._last_write = version, now
            p = job.progress()
            context.window_manager.progress_update(int(100 * p.fraction))
            if context.workspace is not None:
                context.workspace.status_text_set(f"ovrad: {p.text()} (Esc to cancel)")
            _tag_redraw(context)
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
            restore_state(context.scene, self._saved)
        except (ReferenceError, RuntimeError, AttributeError):
            pass  # the data is being freed (a file is loading): nothing left to restore


class OVRAD_OT_cancel_solve(bpy.types.Operator):
    bl_idname = "ovrad.cancel_solve"
    bl_label = "Cancel Solve"
    bl_description = "Stop the running solve; the scene is left as it was before it started"

    @classmethod
    def poll(cls, context):
        if _RUNNING is None or _RUNNING.cancelled:
            cls.poll_message_set("No solve is running")
            return False
        return True

    def execute(self, context):
        _RUNNING.cancel()
        return {"FINISHED"}


def unregister() -> None:
    """Stop a running solve and free the cached problem (the add-on is being disabled)."""
    if _RUNNING is not None:
        _RUNNING.cancel()
    clear_cache()


classes = (OVRAD_OT_solve, OVRAD_OT_cancel_solve)
