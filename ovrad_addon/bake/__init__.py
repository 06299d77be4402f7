"""Light at bake points: direct light where the points are, the final gather for the indirect
light (read through a lattice of alpha per triangle), and the texel helpers of image bakes."""
