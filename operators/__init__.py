"""ovrad's Blender glue: read the scene, run the engine, write atlas objects and their display."""
