"""Operator: Refine Atlas, smaller patches where the solved light varies (ovrad_addon/refine.py).

After a solve, each patch whose radiosity differs much from an overlapping neighbour's (a shadow
edge, the fall-off under a lamp, a corner) is replaced by five smaller ones covering it (four for
box-beta squares); evenly lit patches stay as they are. The atlas objects are written again as
Generate writes them (with their block of C), so Solve then solves the refined atlas. Refining again
goes one level deeper, down to a quarter of the generated radius.
"""

from __future__ import annotations

import time

import bpy
import numpy as np

from ..ovrad_addon import REFINE_MIN_SCALE as MIN_SCALE
from ..ovrad_addon import (
    OvradError,
    attach_sheets,
    both_sides_index,
    integrate,
    keep,
    names,
    object_keys,
    overlaps,
    refine,
)
from . import attributes, display, engine_settings, polls, solve_inputs
from .window import progress_bar

BASE_RADIUS = "ovrad_base_radius"  # object property: the median radius the atlas was generated with


def refine_scene(context) -> tuple[int, int, int]:
    """Refine every receiver atlas of the scene from its stored solution; (patches replaced, patches
    before, patches after). Raises OvradError (nothing changed) when there is nothing to refine from."""
    scene = context.scene
    for obj, _ in solve_inputs.scene_atlases(scene, []):
        if names.RADIOSITY not in obj.data.attributes:
            raise OvradError(f"atlas '{obj.name}' has no solution to refine from: press Solve first")
    inputs = solve_inputs.read_inputs(context, need_light=False)
    n_atlases = len(inputs.sources)
    objects = [bpy.data.objects[name] for name in inputs.atlas_names[:n_atlases]]
    count = sum(inputs.counts[:n_atlases])
    atlas = inputs.atlas.select(np.arange(count))
    radiance, smallest, bases = [], [], []
    for obj in objects:
        mesh = obj.data
        radiance.append(attributes.read_point_attribute(mesh, names.RADIOSITY)[:, :3])
        radii = attributes.read_point_attribute(mesh, names.RADIUS)
        bases.append(float(obj.get(BASE_RADIUS, np.median(radii))))
        smallest.append(np.full(len(radii), MIN_SCALE * np.sqrt(2.0) * bases[-1]))
    index = both_sides_index(inputs.surfaces, "auto", atlas)
    atlas = attach_sheets(atlas, index)
    B = np.pi * np.concatenate(radiance).astype(np.float64)
    settings = engine_settings.atlas_settings(scene.ovrad, inputs.sources)
    crease = settings.crease_angle
    receivers = [k for k in inputs.kept if k.start < count]  # the environment's block is not needed
    # the stored atlas's C as a solve reads it (the kept blocks' own quadrature)
    C = overlaps(inputs.surfaces, atlas, index, kept=receivers)[0]
    finer, replaced = refine(atlas, index, B, smallest=np.concatenate(smallest), C=C)
    if replaced == 0:
        return 0, count, count
    finer = finer.as_stored()
    quadrature = settings.rule_order(len(finer))  # as Generate would choose for the finer atlas
    with progress_bar(context) as progress:
        finer, C, flags = integrate(finer, index, quadrature, progress)
    world = object_keys(inputs.surfaces)
    for i, (base, src) in enumerate(zip(bases, inputs.sources, strict=True)):
        sel = np.flatnonzero(finer.source_object == i)
        part = finer.select(sel)
        kept = None
        if len(sel):
            kept = keep(world, part, C[sel][:, sel], quadrature, crease, contacts=flags[sel])
        new = attributes.write_atlas(scene, src.name, part, kept)
        new[BASE_RADIUS] = base
        display.ensure_modifier(new, part.beta)
        display.set_quantity(new, scene.ovrad.display_quantity)
    return replaced, count, len(finer)


class OVRAD_OT_refine_atlas(bpy.types.Operator):
    bl_idname = "ovrad.refine_atlas"
    bl_label = "Refine Atlas"
    bl_description = (
        "Replace the patches where the solved light varies (a patch and an overlapping neighbour disagree) "
        "by four or five smaller ones each, then solve again"
    )
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        has_atlas = any(attributes.is_atlas(o) for o in context.scene.objects)
        checks = (
            polls.object_mode(context, "refine the atlas"),
            (has_atlas, "Generate an atlas and solve it first"),
        )
        return polls.passes(cls, checks)

    def execute(self, context):
        attributes.keep_atlases_out_of_renders()  # atlases of older files rendered: mend them
        start = time.perf_counter()
        try:
            replaced, before, after = refine_scene(context)
        except OvradError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        if replaced == 0:
            self.report({"INFO"}, "ovrad: nothing to refine (every patch agrees with its neighbours)")
            return {"FINISHED"}
        seconds = time.perf_counter() - start
        self.report(
            {"INFO"},
            f"ovrad: {replaced:,} patches refined, {before:,} -> {after:,} patches in {seconds:.2f} s; "
            "solve again",
        )
        return {"FINISHED"}


classes = (OVRAD_OT_refine_atlas,)
