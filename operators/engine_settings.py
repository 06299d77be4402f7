"""The engine's frozen settings (AtlasSettings, SolveSettings) from ovrad's Blender properties
(properties.py: the scene's OVRAD_PG_settings, each object's OVRAD_PG_object)."""

from __future__ import annotations

from ..ovrad_addon import AtlasSettings, ObjectSettings, SolveSettings


def atlas_settings(props, objects) -> AtlasSettings:
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


def solve_settings(props) -> SolveSettings:
    """The frozen engine settings of a solve."""
    return SolveSettings(
        tolerance=props.solve_tolerance,
        rule=props.solve_rule,
        rays_per_point=props.rays_per_point,
        min_rays=props.min_rays,
        max_rays=props.max_rays,
        cluster_angle=props.cluster_angle,
        gather_rays=props.gather_rays,
    )
