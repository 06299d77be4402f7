"""ovrad's Blender properties (scene settings, per-object overrides) and their conversion to AtlasSettings."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, FloatProperty, IntProperty

from ..ovrad_addon.settings import AtlasSettings, ObjectSettings
from . import attributes, display


def _update_display(self, context) -> None:
    # Runs when the user picks another quantity: every atlas object in the scene follows.
    for obj in context.scene.objects:
        if attributes.is_atlas(obj):
            display.set_quantity(obj, self.display_quantity)


class OVRAD_PG_settings(bpy.types.PropertyGroup):
    """Scene-wide atlas settings (bpy.types.Scene.ovrad)."""

    size_mode: EnumProperty(
        name="Patch Size",
        description="How the patch size is chosen",
        items=(
            ("COUNT", "By Count", "Choose the size so the selected meshes get about this many patches"),
            ("SIZE", "By Size", "Use a fixed patch size (grid spacing) in scene units"),
        ),
        default="COUNT",
    )
    patch_count: IntProperty(
        name="Patch Count",
        description="Target number of patches over all selected meshes",
        default=2000,
        min=1,
        soft_max=100_000,
    )
    patch_size: FloatProperty(
        name="Size",
        description="Grid spacing of patch centres, in scene units",
        default=0.1,
        min=1e-6,
        soft_min=1e-3,
        subtype="DISTANCE",
        unit="LENGTH",
    )
    overlap: FloatProperty(
        name="Overlap",
        description="Patch radius over the smallest radius that covers its grid cell (1: just covering)",
        default=1.3,
        min=1.0,
        max=4.0,
    )
    beta: EnumProperty(
        name="Beta",
        description="Weight of a patch across its support",
        items=(
            ("smooth", "Smooth", "1 at the centre falling continuously to 0 at the rim: smooth blends"),
            ("box", "Box", "Constant over the patch: uniform averages where patches overlap"),
        ),
        default="smooth",
    )
    shapes: EnumProperty(
        name="Shapes",
        description="Patch shapes",
        items=(
            ("AUTO", "Auto", "Disks inside faces, squares on cells cut by an edge"),
            ("DISKS", "Disks", "Disks everywhere"),
            ("SQUARES", "Squares", "Squares everywhere"),
        ),
        default="AUTO",
    )
    max_patches: IntProperty(
        name="Patch Limit",
        description="Refuse to make more patches than this (memory and time grow with the count)",
        default=200_000,
        min=1,
    )
    display_quantity: EnumProperty(
        name="Display",
        description="What the patches of atlas objects are coloured by",
        items=(
            ("OVERLAP", "Overlap Count", "How many other patches overlap each patch"),
            ("RANDOM", "Random", "A random colour per patch"),
            ("BETA", "Beta", "The beta profile across each patch"),
            ("RADIOSITY", "Radiosity", "Solved radiosity (black until solved)"),
        ),
        default="OVERLAP",
        update=_update_display,
    )


class OVRAD_PG_object(bpy.types.PropertyGroup):
    """Per-object overrides (bpy.types.Object.ovrad)."""

    density: FloatProperty(
        name="Density",
        description="Patch density multiplier on this object (2: patches half the size)",
        default=1.0,
        min=1e-3,
        max=999.0,
        soft_min=0.1,
        soft_max=10.0,
    )
    sides: EnumProperty(
        name="Sides",
        description="Which sides of the faces get patches",
        items=(
            (
                "AUTO",
                "Auto",
                "Front only on closed meshes; open meshes also on the back when it sees the scene",
            ),
            ("FRONT", "Front", "Only the side the normals point to"),
            ("BOTH", "Both", "Both sides (a two-sided card or wall)"),
        ),
        default="AUTO",
    )


def atlas_settings(props: OVRAD_PG_settings, objects) -> AtlasSettings:
    """The frozen engine settings for `objects` (in the order of the surfaces' object index)."""
    per_object = tuple(
        ObjectSettings(density=o.ovrad.density, sides=o.ovrad.sides)
        if hasattr(o, "ovrad")
        else ObjectSettings()
        for o in objects
    )
    return AtlasSettings(
        patch_size=props.patch_size if props.size_mode == "SIZE" else None,
        patch_count=props.patch_count,
        overlap=props.overlap,
        beta=props.beta,
        shapes=props.shapes,
        max_patches=props.max_patches,
        objects=per_object,
    )


classes = (OVRAD_PG_settings, OVRAD_PG_object)
