"""The "ovrad" sidebar panel in the 3D view: atlas settings, Generate Atlas, display, per-object overrides."""

from __future__ import annotations

import bpy

from ..operators import attributes
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


classes = (OVRAD_PT_main,)
