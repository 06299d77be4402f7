"""ovrad: diffuse global illumination by overlapping radiosity, as a Blender extension (entry point)."""

import bpy
from bpy.props import PointerProperty

from .operators import bake_image, bake_vertex, cli, generate, preview, properties, refine, solve
from .ui import panel

# Registered in this order, unregistered in reverse (property groups before what uses them).
classes = (
    *properties.classes,
    *generate.classes,
    *solve.classes,
    *refine.classes,
    *bake_vertex.classes,
    *bake_image.classes,
    *preview.classes,
    *panel.classes,
)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.ovrad = PointerProperty(type=properties.OVRAD_PG_settings)
    bpy.types.Object.ovrad = PointerProperty(type=properties.OVRAD_PG_object)
    cli.register_cli()


def unregister():
    cli.unregister_cli()
    solve.unregister()
    del bpy.types.Object.ovrad
    del bpy.types.Scene.ovrad
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
