"""ovrad engine: overlapping-radiosity atlases, transport and solving on plain numpy arrays (no bpy)."""

from .atlas import Atlas, build_atlas, index_surfaces
from .errors import OvradError
from .settings import AtlasSettings, ObjectSettings
from .surfaces import Surfaces

__all__ = [
    "Atlas",
    "AtlasSettings",
    "ObjectSettings",
    "OvradError",
    "Surfaces",
    "build_atlas",
    "index_surfaces",
]
