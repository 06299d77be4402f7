"""The "ovrad" sidebar panel in the 3D view, laid out like Blender's render panels: a main panel
with sub-panels for Atlas (with the active object's overrides), Solve (live progress and Cancel
while solving), Bake (and Preview), Display, and the expert settings under a collapsed Advanced."""

from __future__ import annotations

import bpy

from ..operators import attributes, preview, solve
from ..ovrad_addon import names


class _Sidebar:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ovrad"


def _split(layout):
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout


class OVRAD_PT_main(_Sidebar, bpy.types.Panel):
    bl_idname = "OVRAD_PT_main"
    bl_label = "Overlapping Radiosity"

    def draw(self, context):
        layout = self.layout
        atlases = [o for o in context.scene.objects if attributes.is_atlas(o)]
        if not atlases:
            layout.label(text="Select meshes and generate an atlas", icon="INFO")
            return
        total = sum(attributes.patch_count(o) for o in atlases)
        layout.label(text=f"{total:,} patches in {len(atlases)} atlas object(s)", icon="INFO")
        for o in context.selected_objects:
            if attributes.is_atlas(o):
                beta = o.get(names.PROP_BETA, "?")
                layout.label(text=f"{o.name}: {attributes.patch_count(o):,} patches, beta {beta}")


class _SubPanel(_Sidebar):
    bl_parent_id = "OVRAD_PT_main"


class OVRAD_PT_atlas(_SubPanel, bpy.types.Panel):
    bl_idname = "OVRAD_PT_atlas"
    bl_label = "Atlas"

    def draw(self, context):
        layout = _split(self.layout)
        props = context.scene.ovrad
        layout.prop(props, "quality")  # patch count here, gather rays under Bake, min rays under Advanced
        col = layout.column()
        col.prop(props, "size_mode", text="Patch Size")
        col.prop(props, "patch_size" if props.size_mode == "SIZE" else "patch_count")
        col.prop(props, "overlap")
        col.prop(props, "beta")
        col.prop(props, "shapes")
        layout.operator("ovrad.generate_atlas", icon="MESH_CIRCLE")
        obj = context.active_object
        if obj is not None and obj.type == "MESH" and not attributes.is_atlas(obj):
            box = layout.box()
            box.label(text=f"Object: {obj.name}", icon="OBJECT_DATA")
            box.prop(obj.ovrad, "density")
            box.prop(obj.ovrad, "sides")


class OVRAD_PT_solve(_SubPanel, bpy.types.Panel):
    bl_idname = "OVRAD_PT_solve"
    bl_label = "Solve"

    def draw(self, context):
        draw_solve(self.layout)


class OVRAD_PT_bake(_SubPanel, bpy.types.Panel):
    bl_idname = "OVRAD_PT_bake"
    bl_label = "Bake"

    def draw(self, context):
        draw_bake(_split(self.layout), context.scene.ovrad, context.active_object)


class OVRAD_PT_display(_SubPanel, bpy.types.Panel):
    bl_idname = "OVRAD_PT_display"
    bl_label = "Display"

    def draw(self, context):
        _split(self.layout).prop(context.scene.ovrad, "display_quantity")


class OVRAD_PT_advanced(_SubPanel, bpy.types.Panel):
    bl_idname = "OVRAD_PT_advanced"
    bl_label = "Advanced"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = _split(self.layout)
        props = context.scene.ovrad
        col = layout.column(heading="Solve")
        col.prop(props, "solve_tolerance")
        col.prop(props, "solve_rule")
        col.prop(props, "rays_per_point")
        col.prop(props, "min_rays")
        col.prop(props, "max_rays")
        col.prop(props, "cluster_angle")
        layout.column(heading="Atlas").prop(props, "max_patches")


def draw_solve(layout) -> None:
    """Solve; while a solve runs, its progress and Cancel instead."""
    job = solve.running()
    if job is None:
        row = layout.row(align=True)
        row.operator("ovrad.solve", icon="LIGHT_SUN")
        row.operator("ovrad.refine_atlas", text="Refine", icon="MOD_MULTIRES")
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


def draw_bake(layout, props, obj=None) -> None:
    """Bake settings, the Bake button of the chosen target, and the Preview toggle; for images also
    the active mesh's Lightmap Scale."""
    col = layout.column()
    col.prop(props, "bake_target")
    col.prop(props, "bake_quantity")
    col.prop(props, "bake_direct")
    row = col.row()
    row.active = props.bake_direct  # the gather brings the indirect light to the direct light's points
    row.prop(props, "gather_rays")
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
        row = col.row()
        row.active = props.bake_image_size == 0  # the density sets the size only when no size is given
        row.prop(props, "bake_texel_density")
        row = col.row()
        row.active = props.bake_image_size == 0
        row.prop(props, "bake_max_size")
        col.prop(props, "bake_atlas")
        col.prop(props, "bake_image_format")
        col.prop(props, "bake_image_path")
        op = layout.operator("ovrad.bake_image", icon="IMAGE_DATA")
        op.uv_map, op.size = props.bake_uv_map, props.bake_image_size
        op.texel_density, op.max_size = props.bake_texel_density, props.bake_max_size
        op.filepath, op.quantity = props.bake_image_path, props.bake_quantity
        op.file_format, op.atlas = props.bake_image_format, props.bake_atlas
        active = preview.is_active()
        op = layout.operator(
            "ovrad.preview", text="Preview (on)" if active else "Preview", icon="HIDE_OFF", depress=active
        )
        op.source = "IMAGE"
        if obj is not None and obj.type == "MESH" and not attributes.is_atlas(obj):
            box = layout.box()
            box.label(text=f"Object: {obj.name}", icon="OBJECT_DATA")
            box.prop(obj.ovrad, "lightmap_scale")


# Parents before their sub-panels; sub-panels show in this order.
classes = (OVRAD_PT_main, OVRAD_PT_atlas, OVRAD_PT_solve, OVRAD_PT_bake, OVRAD_PT_display, OVRAD_PT_advanced)
