"""The "ovrad" sidebar panel in the 3D view: atlas settings, Generate Atlas, display, per-object overrides,
Solve (with live progress and Cancel), Bake and Preview."""

from __future__ import annotations

import bpy

from ..operators import attributes, preview, solve
from ..ovrad_addon import names


class OVRAD_PT_main(bpy.types.Panel):
    bl_idname = "OVRAD_PT_main"
    bl_label = "Overlapping Radiosity"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ovrad"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        props = context.scene.ovrad

        col = layout.column(heading="Atlas")
        col.prop(props, "size_mode", text="Patch Size")
        if props.size_mode == "SIZE":
            col.prop(props, "patch_size")
        else:
            col.prop(props, "patch_count")
        col.prop(props, "overlap")
        col.prop(props, "beta")
        col.prop(props, "shapes")
        col.prop(props, "max_patches")
        layout.operator("ovrad.generate_atlas", icon="MESH_CIRCLE")

        layout.separator()
        layout.prop(props, "display_quantity")

        obj = context.active_object
        if obj is not None and obj.type == "MESH" and not attributes.is_atlas(obj):
            box = layout.box()
            box.label(text=f"Object: {obj.name}", icon="OBJECT_DATA")
            box.prop(obj.ovrad, "density")
            box.prop(obj.ovrad, "sides")

        atlases = [o for o in context.scene.objects if attributes.is_atlas(o)]
        if atlases:
            box = layout.box()
            total = sum(attributes.patch_count(o) for o in atlases)
            box.label(text=f"{total:,} patches in {len(atlases)} atlas object(s)", icon="INFO")
            for o in context.selected_objects:
                if attributes.is_atlas(o):
                    beta = o.get(names.PROP_BETA, "?")
                    box.label(text=f"{o.name}: {attributes.patch_count(o):,} patches, beta {beta}")

        layout.separator()
        draw_solve(layout, props)
        layout.separator()
        draw_bake(layout, props)


def draw_solve(layout, props) -> None:
    """Solver settings and Solve; while a solve runs, its progress and Cancel instead."""
    col = layout.column(heading="Solve")
    col.prop(props, "solve_tolerance")
    col.prop(props, "solve_rule")
    col.prop(props, "rays_per_point")
    col.prop(props, "min_rays")
    job = solve.running()
    if job is None:
        layout.operator("ovrad.solve", icon="LIGHT_SUN")
        return
    p = job.status()
    box = layout.box()
    box.label(text=f"{'Cancelling' if p.cancelling else 'Solving'}: {100 * p.fraction:.0f}%", icon="TIME")
    box.label(text=p.stage)
    if p.unshot is not None:
        box.label(text=f"Unshot energy: {p.unshot:.2e}")
    remaining = "?" if p.remaining is None else f"{p.remaining:.0f} s"
    box.label(text=f"Elapsed {p.elapsed:.1f} s, remaining ~{remaining}")
    box.operator("ovrad.cancel_solve", icon="CANCEL")


def draw_bake(layout, props) -> None:
    """Bake settings, the Bake button of the chosen target, and the Preview toggle."""
    col = layout.column(heading="Bake")
    col.prop(props, "bake_target")
    col.prop(props, "bake_quantity")
    col.prop(props, "bake_direct")
    if props.bake_target == "VERTEX":
        col.prop(props, "bake_attribute")
        col.prop(props, "bake_domain")
        # Its unset options take these scene settings.
        layout.operator("ovrad.bake_vertex", icon="GROUP_VCOL")
        active = preview.is_active()
        layout.operator(
            "ovrad.preview", text="Preview (on)" if active else "Preview", icon="HIDE_OFF", depress=active
        )
    else:
        col.prop(props, "bake_uv_map")
        col.prop(props, "bake_image_size")
        col.prop(props, "bake_image_path")
        op = layout.operator("ovrad.bake_image", icon="IMAGE_DATA")
        op.uv_map, op.size = props.bake_uv_map, props.bake_image_size
        op.filepath, op.quantity = props.bake_image_path, props.bake_quantity


classes = (OVRAD_PT_main,)
