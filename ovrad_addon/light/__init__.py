"""Light sources: Blender lamps, the world (sky), emissive triangles sampled with a fixed rule and
a light tree, and the direct light of all of them at surface points by shadow rays."""
