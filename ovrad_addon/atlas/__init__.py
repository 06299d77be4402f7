"""The atlas: the patch arrays (Atlas), the surfaces indexed into charts and sheets (SurfaceIndex),
the beta profiles and alpha, the patch lookup grid, and clutter sheets with their ball patches."""
