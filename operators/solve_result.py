"""Writing a solve's result into the file: radiosity and direct light on the atlas objects, or the
scene put back as it was (save_state / restore_state) after a cancelled or failed solve."""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ..ovrad_addon import bake_sky, direct_light, names
from . import attributes, compat, display, environment
from .solution import remember
from .solve_inputs import SolveInputs, light_key
from .solve_job import SolveJob, unshot_fraction


@dataclass
class SavedState:
    """What a solve changes, as it was before: per atlas object its solve attributes (each, or
    None), its display quantity and its solve properties, and the scene's display setting."""

    quantity: str
    objects: dict


def save_state(scene, atlas_names: list[str]) -> SavedState:
    """What a solve of these atlas objects may change, as it is now."""
    saved = {}
    for name in atlas_names:
        obj = bpy.data.objects.get(name)
        if obj is None or not attributes.is_atlas(obj):
            continue  # an environment atlas the solve will make: nothing to restore
        mesh = obj.data
        old = {
            attr: attributes.read_point_attribute(mesh, attr) if attr in mesh.attributes else None
            for attr in _WRITTEN
        }
        mod = obj.modifiers.get(names.DISPLAY_MODIFIER)
        q = None
        if mod is not None and mod.node_group is not None:
            q = compat.modifier_input(mod, display.input_identifier(mod.node_group, "Quantity"))
        saved[name] = (old, None if q is None else int(q), {p: obj.get(p) for p in _PROPS})
    return SavedState(scene.ovrad.display_quantity, saved)


# the point attributes (and their types) and the object properties a finished solve writes
_WRITTEN = {names.RADIOSITY: "FLOAT_COLOR", names.DIRECT: "FLOAT_COLOR", names.SKY: "INT"}
_PROPS = (names.PROP_LIGHT_KEY, names.PROP_ESCAPED)


def restore_state(scene, saved: SavedState) -> None:
    """Put back what save_state() saw (a cancelled or failed solve leaves the scene as before)."""
    if scene.ovrad.display_quantity != saved.quantity:
        scene.ovrad.display_quantity = saved.quantity
    for name, (old, quantity, props) in saved.objects.items():
        obj = bpy.data.objects.get(name)
        if obj is None or not attributes.is_atlas(obj):
            continue
        mesh = obj.data
        for attr_name, values in old.items():
            if values is None:
                attributes.remove_attribute(mesh, attr_name)
            elif len(values) == len(mesh.vertices):
                attributes.write_point_attribute(mesh, attr_name, values, _WRITTEN[attr_name])
        for prop, value in props.items():
            if value is None:
                obj.pop(prop, None)
            elif obj.get(prop) != value:
                obj[prop] = value
        if quantity is not None:
            display.set_input(obj, "Quantity", quantity)
        mesh.update()


def write_radiosity(
    scene,
    inputs: SolveInputs,
    radiosity: np.ndarray,
    first_shot: np.ndarray | None = None,
    sky: np.ndarray | None = None,
    escaped: int | None = None,
) -> list[str]:
    """Radiance B/pi (FLOAT_COLOR, alpha 1) on each atlas object, shown by the display, and the
    first shot's share of it (direct light, for bakes) with the key of the light it came from
    (first_shot None: an intermediate write, which removes both), where the bakes cast sky rays
    (sky (n,) bool, radiosity.emission.bake_sky; None: everywhere) and how many transport rays escaped;
    returns the names of atlas objects that changed under the solve (skipped)."""
    skipped = []
    radiance = np.asarray(radiosity, np.float64) / np.pi
    direct = radiance if first_shot is None else np.asarray(first_shot, np.float64) / np.pi
    key = light_key(inputs.surfaces, inputs.lamps, inputs.sky)
    env = inputs.environment
    pending = env is not None and env.new  # written by finish() only, so a cancel leaves the old one
    start = 0
    for i, (name, count) in enumerate(zip(inputs.atlas_names, inputs.counts, strict=True)):
        sl = slice(start, start + count)
        part, part_direct = radiance[sl], direct[sl]
        start += count
        if pending and i == len(inputs.sources):
            continue
        obj = bpy.data.objects.get(name)
        if obj is None or not attributes.is_atlas(obj) or attributes.patch_count(obj) != count:
            skipped.append(name)
            continue
        attributes.write_point_attribute(obj.data, names.RADIOSITY, part, "FLOAT_COLOR")
        if first_shot is None:
            # a live, intermediate write: no split to bake from until the solve has finished
            # (a bake would otherwise add direct light to a radiosity that holds it already)
            for attr in (names.DIRECT, names.SKY):
                attributes.remove_attribute(obj.data, attr)
            for prop in _PROPS:
                obj.pop(prop, None)
        else:
            attributes.write_point_attribute(obj.data, names.DIRECT, part_direct, "FLOAT_COLOR")
            obj[names.PROP_LIGHT_KEY] = key
            if sky is None:
                attributes.remove_attribute(obj.data, names.SKY)
            else:
                part_sky = np.asarray(sky[sl], np.int32)
                attributes.write_point_attribute(obj.data, names.SKY, part_sky, "INT")
            if escaped is None or escaped < 0:
                obj.pop(names.PROP_ESCAPED, None)
            else:
                obj[names.PROP_ESCAPED] = int(escaped)
        obj.data.update()
        display.set_quantity(obj, "RADIOSITY")
    if scene.ovrad.display_quantity != "RADIOSITY":
        scene.ovrad.display_quantity = "RADIOSITY"
    return skipped


def summary(job: SolveJob) -> str:
    """The one-line report of a finished solve."""
    st, inp = job.state, job.inputs
    reuse = "form factors reused" if job.reused else f"{job.problem.rays:,} transport rays"
    unshot = unshot_fraction(st)
    return (
        f"ovrad: solved {len(inp.atlas):,} patches, {len(inp.lamps)} lamp(s), {reuse}, "
        f"{st.shots:,} shots, unshot {unshot:.1e}, {job.status().elapsed:.2f} s"
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
    env = job.inputs.environment
    if env is not None:
        stored = environment.store(scene, env)
        if env.atlas is not None:
            job.inputs.atlas_names[len(job.inputs.sources)] = stored
    inputs, problem = job.inputs, job.problem
    light = direct_light(problem, inputs.lamps, inputs.settings, sky=inputs.sky)
    # from the radiosity as the bakes read it back (float32 radiance): the choice a bake would make
    stored = np.pi * (np.asarray(job.state.radiosity) / np.pi).astype(np.float32).astype(np.float64)
    sky = bake_sky(problem, light, stored)
    escaped = None if problem.transport is None else problem.transport.escaped
    skipped = write_radiosity(scene, inputs, job.state.radiosity, job.state.first_shot, sky, escaped)
    message = summary(job)
    if skipped:
        message += f" (changed during the solve, not written: {', '.join(skipped)})"
    if not job.state.converged:
        message += " (not converged)"
    return "FINISHED", message
