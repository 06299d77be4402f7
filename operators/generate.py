"""Operators: Generate Atlas on the selected meshes, and switch what atlas patches are coloured by."""

from __future__ import annotations

import time

import bpy
import numpy as np
from bpy.props import EnumProperty

from ..ovrad_addon import OvradError, build_atlas_and_overlaps, keep, object_keys
from . import attributes, display, engine_settings, polls, scene_io, scene_model
from .window import progress_bar


class OVRAD_OT_generate_atlas(bpy.types.Operator):
    bl_idname = "ovrad.generate_atlas"
    bl_label = "Generate Atlas"
    bl_description = (
        "Cover the selected meshes (modifiers applied) with overlapping patches: one atlas object per mesh "
        "in the 'ovrad' collection, replacing that mesh's previous atlas"
    )
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        meshes = (
            bool(polls.selected_meshes(context)),
            "Select at least one mesh object to generate an atlas",
        )
        return polls.passes(cls, (polls.object_mode(context, "generate an atlas"), meshes))

    def execute(self, context):
        attributes.keep_atlases_out_of_renders()  # atlases of older files rendered: mend them
        start = time.perf_counter()
        scene = context.scene
        # In the order a solve reads the atlases' meshes (by atlas name): the same triangle order, so
        # the same ray hits where faces coincide, and the C integrated here is the one a solve would
        selected = sorted(context.selected_objects, key=lambda o: o.name + attributes.ATLAS_SUFFIX)
        active = context.view_layer.objects.active
        # Everything that can fail runs before the first write, so an error leaves the file as it was.
        try:
            depsgraph = context.evaluated_depsgraph_get()
            model = scene_model.read_model(depsgraph, scene)
            meshes = scene_io.read_scene(depsgraph, selected, model.others(selected), model)
            settings = engine_settings.atlas_settings(scene.ovrad, meshes.objects)
            with progress_bar(context) as progress:
                built = build_atlas_and_overlaps(meshes.surfaces, settings, progress=progress)
            atlas, C, quadrature, flags = built
        except OvradError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        parts, world = [], object_keys(meshes.surfaces)
        for i, obj in enumerate(meshes.objects[: meshes.n_receivers]):
            sel = np.flatnonzero(atlas.source_object == i)
            part = atlas.select(sel)
            # its block of C, kept on the atlas object so a solve need not integrate it again
            kept = None
            if len(sel):
                kept = keep(world, part, C[sel][:, sel], quadrature, settings.crease_angle, 0, flags[sel])
            parts.append((obj.name, part, kept))
        for w in meshes.warnings:
            self.report({"WARNING"}, w)
        for name, part, kept in parts:
            if len(part) == 0:
                self.report({"WARNING"}, f"'{name}' got no patches (no face of it can be covered)")
            obj = attributes.write_atlas(scene, name, part, kept)
            display.ensure_modifier(obj, part.beta)
            display.set_quantity(obj, scene.ovrad.display_quantity)
        # New objects are not selected, but keep the user's selection exactly as it was regardless.
        chosen = set(selected)
        for obj in context.view_layer.objects:
            if obj.select_get() != (obj in chosen):
                obj.select_set(obj in chosen)
        if context.view_layer.objects.active != active:
            context.view_layer.objects.active = active
        seconds = time.perf_counter() - start
        self.report({"INFO"}, f"ovrad: {len(atlas):,} patches on {len(parts)} object(s) in {seconds:.2f} s")
        return {"FINISHED"}


class OVRAD_OT_set_display(bpy.types.Operator):
    bl_idname = "ovrad.set_display"
    bl_label = "Set Patch Display"
    bl_description = "Colour the patches of every atlas object in the scene by the chosen quantity"
    bl_options = {"REGISTER", "UNDO"}

    quantity: EnumProperty(
        name="Quantity",
        items=[(q, q.title(), "") for q in display.QUANTITIES],
        default="OVERLAP",
    )

    def execute(self, context):
        attributes.keep_atlases_out_of_renders()  # atlases of older files rendered: mend them
        changed = sum(
            display.set_quantity(obj, self.quantity)
            for obj in context.scene.objects
            if attributes.is_atlas(obj)
        )
        # Assigning the scene setting keeps the panel in step (its update does the same for every atlas).
        context.scene.ovrad.display_quantity = self.quantity
        self.report({"INFO"}, f"ovrad: {changed} atlas object(s) coloured by {self.quantity.lower()}")
        return {"FINISHED"}


classes = (OVRAD_OT_generate_atlas, OVRAD_OT_set_display)
