"""The scene as plain arrays: triangles, objects, reflectance and emission (Surfaces), smooth
charts, albedo textures, and the ray backends (embree, or numpy giving the same answers)."""
